"""A problem's parameters as one pytree: `Point` (θ, the start speeds, every effect's parameters),
`Space` (the one map from a point's unbounded coordinates to the simulator's values), masks of free
entries and the flattened vectors fits step along; `split_parameters` takes a flat parameter vector
(a file's, a neural posterior's draws) to θ and one vector per effect."""

from ._parameters import split_parameters as split_parameters
from ._point import (
    Point as Point,
    Space as Space,
    free_positions as free_positions,
    gather as gather,
    mask_of as mask_of,
    padded as padded,
    positions as positions,
    ravel as ravel,
    scatter as scatter,
)
