"""Limit handling the single-track model cannot follow: slides caught by counter-steer.

Where the rear tyres saturate the car yaws faster than the steer asks and the driver steers
against the yaw (counter-steer). The model, started from the state before, follows the steer
and turns the other way, and every sample after it in the window is lost. The signature needs
no model: steer and yaw rate of opposite sign, held for a while, in a corner hard enough to
matter. Such stretches (with margins for the build-up and the recovery) are taken out of the
driving that windows are cut from, and reported with the reason.
"""

from __future__ import annotations

import numpy as np

from ..io import Recording, forward_speed, label_runs, running_mean
from ..simulator import GRAVITY

#: Steer and yaw rate are smoothed over this long, s (vibration, sensor noise).
SMOOTHING = 0.2
#: Road-wheel angle below which the sign of the steer means nothing, rad.
MIN_STEER = 0.01
#: Cornering demand |v_x·r| above which a counter-steer is a slide, as a fraction of μ·g.
MIN_DEMAND = 0.3
#: Shortest counter-steer that counts, s (in a quick slalom the yaw lags the steer briefly).
MIN_DURATION = 0.2
#: Margins taken out before (build-up) and after (recovery) a slide, s.
BEFORE, AFTER = 1.0, 2.0


def slides(rec: Recording, *, wheel_radius: float, friction: float) -> list[tuple[float, float, str]]:
    """Stretches [t0, t1] of `rec` at the limit (a slide caught by counter-steer), with a reason.

    Args:
        rec: the recording (needs yaw_rate, else ay, and a speed: `forward_speed`).
        wheel_radius: for a speed from wheel speeds.
        friction: vehicle.json's μ (scales the cornering demand that counts).

    Returns:
        [(t0, t1, reason)] in time order, margins included, clipped to the recording.
    """
    speed = forward_speed(rec, wheel_radius)
    if speed is None:
        return []
    n = max(1, int(round(SMOOTHING * rec.rate)))
    steer = running_mean(rec.steer, n)
    if "yaw_rate" in rec.channels:
        r = running_mean(rec.channels["yaw_rate"], n)
    elif "ay" in rec.channels:
        r = running_mean(rec.channels["ay"], n) / np.maximum(speed, 1.0)
    else:
        return []
    demand = np.abs(speed * r)
    flag = (steer * r < 0) & (np.abs(steer) >= MIN_STEER) & (demand >= MIN_DEMAND * friction * GRAVITY)
    out = []
    for i0, i1 in (r for r in label_runs(flag) if flag[r[0]]):
        if rec.t[i1 - 1] - rec.t[i0] < MIN_DURATION:
            continue
        peak = float(demand[i0:i1].max())
        reason = (
            f"limit handling: counter-steer {rec.t[i0]:.1f}–{rec.t[i1 - 1]:.1f} s (steer against the "
            f"yaw rate at |v_x·r| up to {peak:.1f} m/s²): a slide the single-track tyre model does not "
            "follow; excluded with margins"
        )
        t0 = max(float(rec.t[0]), float(rec.t[i0]) - BEFORE)
        out.append((t0, min(float(rec.t[-1]), float(rec.t[i1 - 1]) + AFTER), reason))
    return _merged(out)


def _merged(stretches):
    out = []
    for a, b, why in stretches:
        if out and a <= out[-1][1]:
            out[-1] = (out[-1][0], max(out[-1][1], b), out[-1][2] + "; " + why)
        else:
            out.append((a, b, why))
    return out


def subtract(usable: list[tuple[float, float]], cut: list[tuple[float, float, str]], min_duration: float):
    """`usable` stretches with the `cut` ones taken out; pieces shorter than `min_duration` drop."""
    out = []
    for a, b in usable:
        pieces = [(a, b)]
        for c0, c1, _ in cut:
            pieces = [p for x, y in pieces for p in ((x, min(y, c0)), (max(x, c1), y)) if p[1] > p[0]]
        out += [(x, y) for x, y in pieces if y - x >= min_duration]
    return out
