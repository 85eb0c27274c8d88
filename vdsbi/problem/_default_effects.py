"""The effects `identify` adds to θ unless told which: what a drive of its kind needs."""

from __future__ import annotations

from ..simulator.models import SpeedDriven
from ._problem import Problem, grip_used, top_speed, yaw_at_zero_steer

#: A drive is fast where a tenth of it runs above this, m/s: downforce of a typical race car
#: (0.3–2 × its weight at 50 m/s) adds 7–50 % to the tyres' load here.
FAST = 25.0
#: Grip used (a share of μ·g) that asks for more load than the car's weight: past `BEYOND_GRIP`
#: anywhere (the weight's whole limit), past `FAST_GRIP` above `FAST` (where a typical
#: downforce is worth the rest).
BEYOND_GRIP, FAST_GRIP = 1.0, 0.8


def default_effects(prob: Problem) -> tuple[tuple[str, str], ...]:
    """The effects every drive of this kind needs, each as (name, the reason).

    `tyre_friction` where the drive uses more than half the grip (Dugoff leaves its linear range);
    `downforce` where it is fast (a tenth of it above `FAST`) and uses more grip than the car's
    weight gives (over `BEYOND_GRIP` × μ·g, or `FAST_GRIP` × μ·g above `FAST`, where downforce
    would add to it);
    following the measured speed with a yaw rate (a real car's log): `yaw_inertia` (a real I_z is
    not m·l_f·l_r; left at it, the fit bends l_f to match the yaw transient), `signal_delay`
    (every real log has latency between the steer signal and the motion it causes: bus, sensor
    filters, the steering's own lag); and `steer_offset` where the car keeps a yaw rate at a
    logged steer of zero worth more than a tenth of the yaw rate's spread (`yaw_at_zero_steer`:
    a steer sensor's zero, alignment or road crown).
    """
    chosen = []
    used = grip_used(prob)
    if used is not None and used > 0.5:
        chosen.append(("tyre_friction", f"the drive uses {used:.0%} of the grip μ·g"))
    fast = top_speed(prob)
    if used is not None and fast is not None and fast > FAST:
        used_fast = grip_used(prob, min_speed=FAST)
        if used > BEYOND_GRIP or used_fast > FAST_GRIP:
            chosen.append(
                (
                    "downforce",
                    f"the drive uses {used:.0%} of the grip μ·g ({used_fast:.0%} above {FAST:.0f} m/s) "
                    f"and a tenth of it is faster than {fast:.0f} m/s",
                )
            )
    if issubclass(prob.model_class, SpeedDriven) and "yaw_rate" in prob.channels:
        chosen.append(("yaw_inertia", "a real car's yaw inertia is not m·l_f·l_r"))
        chosen.append(("signal_delay", "a real log's steer leads the motion it causes by its latency"))
        offset = yaw_at_zero_steer(prob)
        if offset is not None and abs(offset[1]) > 0.1:
            chosen.append(
                (
                    "steer_offset",
                    f"at a logged steer of zero the car yaws {offset[0]:+.4f} rad/s "
                    f"({abs(offset[1]):.0%} of the yaw rate's spread)",
                )
            )
    return tuple(chosen)
