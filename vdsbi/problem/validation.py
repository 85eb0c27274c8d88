"""How well a parameter set predicts driving (`channel_scores`, `predict`, `validate`, the
`predictive_band` and its `band_coverage`), and the driving envelope a fit saw (`envelope`, in
`ENVELOPE_UNITS`) with the windows of other driving that go beyond it (`beyond_envelope`)."""

from ._envelope import (
    ENVELOPE_UNITS as ENVELOPE_UNITS,
    beyond_envelope as beyond_envelope,
    envelope as envelope,
)
from ._validate import (
    band_coverage as band_coverage,
    channel_scores as channel_scores,
    predict as predict,
    predictive_band as predictive_band,
    validate as validate,
)
