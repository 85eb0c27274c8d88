"""The kinematic consistency checks of a recording: `kinematic_slopes` (d(vx)/dt against `ax`,
`ay` against vx·yaw_rate) and `consistency_warnings`, which raises on the unit mistakes those
slopes reveal and returns softer oddities (time base, signs) as warning lines."""

from __future__ import annotations

import numpy as np

from ._errors import InputError
from ._recording import Recording
from ._resample import running_mean

#: Running-mean window, s, for the kinematic consistency checks below.
_KIN_WINDOW = 0.5


def kinematic_slopes(rec: Recording, min_speed: float = 3.0) -> dict[str, float]:
    """Least-squares slopes of two kinematic identities, after a 0.5-s running mean.

    - "dvx/dt~ax": d(vx)/dt against ax (1 for consistent units and time base; 3.6 if vx is in
      km/h; 1/k if the time stamps are stretched k-fold).
    - "ay~vx*yaw_rate": ay against vx·yaw_rate (≈ 1 in steady cornering; ≈ 57 if yaw_rate is in
      deg/s, ≈ 1/3.6 if vx is in km/h).

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
        ay = running_mean(ch["ay"], n)[moving]
        vr = running_mean(ch["vx"] * ch["yaw_rate"], n)[moving]
        if vr.std() > 0.3:
            out["ay~vx*yaw_rate"] = float(np.sum(ay * vr) / np.sum(vr * vr))
    return out


def consistency_warnings(rec: Recording) -> list[str]:
    """Raise on unit mistakes the kinematics reveal; return softer oddities as warning lines.

    Raises:
        InputError: d(vx)/dt ≈ 3.6·ax (vx in km/h) or ay ≈ vx·yaw_rate / 57 (yaw_rate in deg/s).
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
    if s is not None:
        if s < 0.05:
            raise InputError(
                rec.source,
                "yaw_rate",
                f"ay is {s:.3g} × vx·yaw_rate: yaw_rate looks like deg/s; expected rad/s",
            )
        if not 0.6 < s < 1.6:
            warnings.append(
                f"{rec.source}: ay: ay is {s:.2f} × vx·yaw_rate where ≈ 1 is expected in steady "
                "cornering: check signs and units of ay, vx, yaw_rate"
            )
    return warnings
