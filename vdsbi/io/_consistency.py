"""The kinematic consistency checks of a recording: `kinematic_slopes` (d(vx)/dt against `ax`,
`ay` against vx·yaw_rate) and `steer_response` (the yaw rate against v·steer/L);
`consistency_warnings` raises on the unit and sign mistakes they reveal and returns softer
oddities as warning lines; `steer_problems` (with the vehicle's wheelbase) warns when the steer
looks like the steering-wheel angle."""

from __future__ import annotations

import numpy as np

from ._errors import InputError
from ._recording import Recording
from ._resample import running_mean
from ._speed import MIN_YAW_RATE, STEADY

#: Running-mean window, s, for the kinematic consistency checks below.
_KIN_WINDOW = 0.5


def kinematic_slopes(rec: Recording, min_speed: float = 3.0) -> dict[str, float]:
    """Least-squares slopes of two kinematic identities, after a 0.5-s running mean.

    - "dvx/dt~ax": d(vx)/dt against ax (1 for consistent units and time base; 3.6 if vx is in
      km/h; 1/k if the time stamps are stretched k-fold).
    - "ay~vx*yaw_rate": ay against vx·yaw_rate over the moving samples (≈ 1/57 if yaw_rate is
      in deg/s, ≈ 1/3.6 if vx is in km/h, < 0 if ay or yaw_rate has the wrong sign);
      "ay~vx*yaw_rate steady": the same over `STEADY_TURNING` s or more of steady turning, where
      ay = dv_y/dt + vx·r ≈ vx·r holds (≈ 1; a transient drive's dv_y/dt moves the first).

    Only samples with vx > `min_speed` are used; a slope is omitted where its regressor has
    too little variation (std < 0.3 m/s²) to tell.
    """
    ch = rec.channels
    if "vx" not in ch:
        return {}
    n = max(1, int(round(_KIN_WINDOW * rec.rate)))
    vx = running_mean(ch["vx"], n)
    moving = vx > min_speed
    moving[: n // 2 + 1] = moving[-(n // 2 + 1) :] = False  # edges of the running mean are biased
    if moving.sum() < n:
        return {}
    out = {}
    if "ax" in ch:
        ax = running_mean(ch["ax"], n)[moving]
        dv = np.gradient(vx, rec.dt)[moving]
        if ax.std() > 0.3:
            out["dvx/dt~ax"] = float(np.sum(dv * ax) / np.sum(ax * ax))
    if "ay" in ch and "yaw_rate" in ch:
        ay_all, vr_all = running_mean(ch["ay"], n), running_mean(ch["vx"] * ch["yaw_rate"], n)
        ay, vr = ay_all[moving], vr_all[moving]
        if vr.std() > 0.3:
            out["ay~vx*yaw_rate"] = float(np.sum(ay * vr) / np.sum(vr * vr))
        steady = moving & _steady_turning(running_mean(ch["yaw_rate"], n), rec.dt)
        if steady.sum() * rec.dt >= STEADY_TURNING:
            ay, vr = ay_all[steady], vr_all[steady]
            out["ay~vx*yaw_rate steady"] = float(np.sum(ay * vr) / np.sum(vr * vr))
    return out


#: Seconds of steady turning that the steady-cornering slope of ay against vx·r needs.
STEADY_TURNING = 1.0


def _steady_turning(r: np.ndarray, dt: float) -> np.ndarray:
    """Samples of a smoothed yaw rate `r` that turn clearly and steadily (as the speed estimate
    takes them: |r| ≥ `MIN_YAW_RATE`, |dr/dt| ≤ `STEADY`·|r|)."""
    return (np.abs(r) >= MIN_YAW_RATE) & (np.abs(np.gradient(r, dt)) <= STEADY * np.abs(r))


def consistency_warnings(rec: Recording) -> list[str]:
    """Raise on unit and sign mistakes the kinematics reveal; return softer oddities as warning
    lines.

    Raises:
        InputError: d(vx)/dt ≈ 3.6·ax (vx in km/h); ay ≈ vx·yaw_rate / 57 (yaw_rate in deg/s);
            ay, yaw_rate or steer with the wrong sign (`_signs`).
    """
    slopes = kinematic_slopes(rec)
    warnings = []
    s = slopes.get("dvx/dt~ax")
    if s is not None:
        if 2.8 < s < 4.6:
            raise InputError(rec.source, "vx", f"d(vx)/dt is {s:.2f} × ax: looks like km/h; expected m/s")
        if not 0.7 < s < 1.4:
            warnings.append(
                f"{rec.source}: t: d(vx)/dt is {s:.2f} × ax where 1 is expected: check the time base "
                f"(true rate {rec.original_rate / s:.4g} Hz?) or the units of vx and ax"
            )
    s = slopes.get("ay~vx*yaw_rate")
    if s is not None and 0.0 < s < 0.05:
        raise InputError(
            rec.source,
            "yaw_rate",
            f"ay is {s:.3g} × vx·yaw_rate: yaw_rate looks like deg/s; expected rad/s",
        )
    _signs(rec, s)
    if s is not None and -AY_MIN_SLOPE <= s <= 0.0:
        warnings.append(
            f"{rec.source}: ay: ay is {s:.2f} × vx·yaw_rate where ≈ 1 is expected: check the signs "
            "and units of ay, vx and yaw_rate"
        )
    s = slopes.get("ay~vx*yaw_rate steady")
    if s is not None and not 0.6 < s < 1.6:
        warnings.append(
            f"{rec.source}: ay: in steady cornering ay is {s:.2f} × vx·yaw_rate where ≈ 1 is "
            "expected: check the units of ay, vx and yaw_rate"
        )
    return warnings


def _signs(rec: Recording, ay_slope: float | None) -> None:
    """Raise when ay, yaw_rate or steer has the wrong sign, naming the one the others outvote:
    ay against vx·yaw_rate (`ay_slope`), and the yaw rate against v·steer (`steer_response`)."""
    speed = rec.speed(1.0)  # a wheel speed, proportional to it, is enough for a sign
    found = None if speed is None else steer_response(rec, 1.0, speed)
    steer_sign = 0 if found is None or abs(found[1]) < STEER_MIN_CORRELATION else np.sign(found[0])
    expected = "(ay > 0 to the left, yaw_rate > 0 counter-clockwise, steer > 0 turning left)"
    if ay_slope is not None and ay_slope < -AY_MIN_SLOPE:
        column = {1: "ay", -1: "yaw_rate"}.get(steer_sign, "ay")
        other = "steer and ay" if column == "yaw_rate" else "steer and yaw_rate"
        why = f"; {other} agree" if steer_sign else ""
        raise InputError(
            rec.source,
            column,
            f"ay is {ay_slope:.2f} × vx·yaw_rate: ay and yaw_rate have opposite signs{why}; expected "
            f"consistent signs {expected}: negate {column}",
        )
    if steer_sign < 0:
        gain, c, lag = found
        raise InputError(
            rec.source,
            "steer",
            f"yaw_rate follows v·steer with the opposite sign (correlation {c:.2f}, {lag:.2f} s later)"
            f"{', and ay agrees with yaw_rate' if ay_slope is not None else ''}: the steer sign is "
            f"reversed; expected {expected}: negate steer",
        )


#: The yaw rate is compared with v·steer/L up to this lag, s (steering actuators and tyre
#: relaxation delay the response by up to a few tenths of a second).
STEER_MAX_LAG = 0.5
#: The steer's sign and scale are judged only where the yaw rate follows v·steer/L this closely
#: (|correlation|): a reversed sign gives −0.9 to −1 on real drives; a straight drive, or one
#: whose slides are counter-steered, stays well inside.
STEER_MIN_CORRELATION = 0.8
#: ay against vx·yaw_rate below −this is a reversed sign (above it and below 0: a warning).
AY_MIN_SLOPE = 0.2
#: Steady-state yaw rate over v·δ/L is 1/(1 + K·v²/L): about 0.4–1.3 for understeer gradients of
#: −2 to 6 deg/g at highway speed. Below this the steer column is not the road-wheel angle (a
#: steering-wheel angle, 12–20 times larger, gives 0.02–0.1).
STEER_MIN_GAIN = 0.2


def steer_response(rec: Recording, wheelbase: float, speed: np.ndarray, min_speed: float = 3.0):
    """(gain, correlation, lag s) of the yaw rate against the kinematic yaw rate v·steer/L.

    Both are smoothed by a 0.5-s running mean and taken with their means removed (a steer offset
    or gyro bias does not matter), over samples with `speed` > `min_speed`; the lag in
    [0, `STEER_MAX_LAG`] with the largest |correlation| is used. None without a yaw rate, or
    with under a second of moving samples.
    """
    if "yaw_rate" not in rec.channels:
        return None
    n = max(1, int(round(_KIN_WINDOW * rec.rate)))
    v = running_mean(speed, n)
    r = running_mean(rec.channels["yaw_rate"], n)
    kin = running_mean(speed * rec.steer / wheelbase, n)
    moving = v > min_speed
    moving[: n // 2 + 1] = moving[-(n // 2 + 1) :] = False
    best = None
    for lag in range(0, int(STEER_MAX_LAG * rec.rate) + 1, max(1, int(round(0.02 * rec.rate)))):
        m = moving[lag:] & moving[: len(moving) - lag]
        if m.sum() < rec.rate:
            return None
        x, y = kin[: len(kin) - lag][m], r[lag:][m]
        x, y = x - x.mean(), y - y.mean()
        sxx, syy = float(np.sum(x * x)), float(np.sum(y * y))
        if sxx <= 0.0 or syy <= 0.0:
            return None
        c = float(np.sum(x * y)) / np.sqrt(sxx * syy)
        if best is None or abs(c) > abs(best[1]):
            best = (float(np.sum(x * y)) / sxx, c, lag / rec.rate)
    return best


def steer_problems(rec: Recording, wheelbase: float, speed: np.ndarray) -> list[str]:
    """A warning when the steer looks like the steering-wheel angle: the yaw rate follows
    v·steer/L (`steer_response`) with a gain below `STEER_MIN_GAIN`. (Its sign was checked when
    the recording was read.)"""
    found = steer_response(rec, wheelbase, speed)
    if found is None:
        return []
    gain, c, _ = found
    if abs(c) < STEER_MIN_CORRELATION or not 0.0 < gain < STEER_MIN_GAIN:
        return []
    return [
        f"{rec.source}: steer: yaw_rate is {gain:.3f} × vx·steer/L where ≈ 0.4–1.3 is expected: "
        "steer looks like the steering-wheel angle; expected the front road-wheel angle (the "
        "steering-wheel angle over the steering ratio)"
    ]
