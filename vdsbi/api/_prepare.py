"""Problem preparation: a recording's segment, channels, noise model and initial-speed range.

Self-contained on purpose: the problem package that replaces it will swap this module whole.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from ..io import InputError


@dataclasses.dataclass
class Problem:
    """A recording prepared for identification (the chosen segment and its noise model)."""

    rec: Any  # vdsbi.io.Recording, sliced to the segment
    vehicle: Any
    channels: tuple[str, ...]
    segment: dict[str, Any]
    noise_std: dict[str, float]
    noise_source: dict[str, str]
    v0_range: tuple[float, float]

    def simulator(self):
        import jax.numpy as jnp

        from ..simulator import CHANNELS, SensorNoise, StochasticSimulator, make_model

        add = jnp.array([self.noise_std.get(c, 0.0) for c in CHANNELS])
        noise = SensorNoise(jnp.zeros(len(CHANNELS)), add)
        return StochasticSimulator(
            make_model(self.vehicle), self.rec.inputs(), self.channels, self.v0_range, noise
        )

    def prior(self):
        from ..inference import BoxPrior
        from ..simulator import PARAM_NAMES

        box = self.vehicle.default_prior()
        return BoxPrior([box[n][0] for n in PARAM_NAMES], [box[n][1] for n in PARAM_NAMES], names=PARAM_NAMES)


def _excitation_score(rec) -> float:
    # Same normalisation as find_segments' thresholds: 0.005 rad steer std, 100 N·m torque std.
    return float(np.std(rec.steer) / 0.005 + np.std(rec.torque_front + rec.torque_rear) / 100.0)


def _quiet_start(rec, a: float, b: float, search: float = 3.0) -> float:
    """Move the window start to where the car is laterally near rest.

    The simulator starts with V_y = r = 0 (the contract: "assumed at rest laterally"), so a
    window that begins mid-corner starts with a built-in mismatch. Within the first
    `search` s, take the first sample with small yaw rate and steer if there is one.
    """
    if "yaw_rate" not in rec.channels:
        return a
    t = rec.t
    sel = (t >= a) & (t <= min(a + search, b - 5.0))
    ok = sel & (np.abs(rec.channels["yaw_rate"]) < 0.03) & (np.abs(rec.steer) < 0.02)
    return float(t[np.argmax(ok)]) if ok.any() else a


def choose_segment(
    rec, vehicle, *, segment: tuple[float, float] | None = None, max_duration: float = 20.0
) -> tuple[Any, dict[str, Any]]:
    """The stretch of `rec` to identify from, and a description of the choice.

    With `segment` the user's [t0, t1] is taken as is. Otherwise the usable stretches from
    `vdsbi.io.find_segments` are considered, and the window of at most `max_duration` s (1 s steps)
    with the most input excitation is taken.

    Raises:
        InputError: no usable stretch, or a `segment` outside the recording.
    """
    from ..io import find_segments

    if segment is not None:
        t0, t1 = segment
        if not (rec.t[0] - 1e-9 <= t0 < t1 <= rec.t[-1] + 1e-9):
            raise InputError(
                rec.source,
                "--segment",
                f"[{t0}, {t1}] s is not inside the recording [{rec.t[0]:.3f}, {rec.t[-1]:.3f}] s",
            )
        return rec.slice(t0, t1), {"t0": t0, "t1": t1, "how": "given by the user", "usable": None}
    min_dur = min(5.0, 0.9 * rec.duration)
    segs = find_segments(rec, wheel_radius=vehicle.wheel_radius, min_duration=min_dur)
    usable = [s for s in segs if s.usable]
    described = {
        "usable": [[round(s.t0, 3), round(s.t1, 3)] for s in usable],
        "rejected": [[round(s.t0, 3), round(s.t1, 3), s.reason] for s in segs if not s.usable],
    }
    if not usable:
        reasons = "; ".join(f"{s.t0:.1f}-{s.t1:.1f} s: {s.reason}" for s in segs[:4])
        raise InputError(rec.source, "segment", f"no usable stretch for the model ({reasons})")
    best, best_score = None, -np.inf
    for s in usable:
        if s.duration <= max_duration:
            starts = [s.t0]
        else:
            starts = list(np.arange(s.t0, s.t1 - max_duration + 1e-9, 1.0))
        for a in starts:
            b = min(a + max_duration, s.t1)
            score = _excitation_score(rec.slice(a, b)) * (b - a)
            if score > best_score:
                best, best_score = (float(a), float(b)), score
    a, b = best
    a = _quiet_start(rec, a, b)
    how = (
        "whole recording"
        if (a <= rec.t[0] + 1e-6 and b >= rec.t[-1] - 1e-6)
        else (f"most excited window of <= {max_duration:g} s among {len(usable)} usable stretch(es)")
    )
    return rec.slice(a, b), {"t0": a, "t1": b, "how": how, **described}


def prepare(
    rec, vehicle, *, segment: tuple[float, float] | None = None, max_duration: float = 20.0
) -> Problem:
    """Segment, channels (all measured, >= 2), additive noise and initial-speed range."""
    from ..io import estimate_noise_std

    seg_rec, seg = choose_segment(rec, vehicle, segment=segment, max_duration=max_duration)
    from ..simulator import CHANNELS

    channels = tuple(c for c in CHANNELS if c in seg_rec.channels)
    if len(channels) < 2:
        raise InputError(rec.source, "channels", f"need at least 2 measured channels, found {list(channels)}")
    est = estimate_noise_std(seg_rec)
    noise, source = {}, {}
    for c in channels:
        if c in vehicle.noise_std:
            noise[c], source[c] = float(vehicle.noise_std[c]), "vehicle file"
        else:
            noise[c], source[c] = float(est[c]), "estimated from the recording"
    speed = seg_rec.speed(vehicle.wheel_radius)
    n0 = max(1, int(round(0.1 * seg_rec.rate)))
    v0 = float(np.mean(speed[:n0]))
    margin = 0.2 + 0.02 * v0
    return Problem(seg_rec, vehicle, channels, seg, noise, source, (max(0.5, v0 - margin), v0 + margin))
