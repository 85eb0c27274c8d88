"""The lag of a car's response behind its logged steer, and the effect parameters it starts."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ..io import Recording, steer_response
from ..simulator import Vehicle
from ..simulator.effects import EFFECTS


def measured_steer_lag(recording: Recording, vehicle: Vehicle) -> float | None:
    """The lag, s, at which the yaw rate follows v·steer/L best (what `vdsbi check` reports), or
    None (no yaw rate, no speed, too little moving). It holds the tyres' and the body's own lag
    beside any actuator lag or delay, so a fit starts a lag parameter at a share of it."""
    speed = recording.speed(vehicle.wheel_radius)
    found = None if speed is None else steer_response(recording, vehicle.wheelbase, speed)
    return None if found is None else float(found[2])


def steer_lag_index(names: Sequence[str]) -> np.ndarray:
    """Indices of the flat `effect.param` names that an effect declares a steer lag
    (`AbstractEffect.steer_lag`)."""
    out = []
    for i, name in enumerate(names):
        effect, _, param = name.partition(".")
        if effect in EFFECTS and param in EFFECTS[effect].steer_lag:
            out.append(i)
    return np.asarray(out, dtype=int)
