"""The effects `identify` adds to θ unless told which: what a drive of its kind needs."""

from __future__ import annotations

from ..problem import Problem, grip_used, yaw_at_zero_steer
from ..simulator import SpeedDriven


def default_effects(prob: Problem) -> tuple[tuple[str, str], ...]:
    """The effects every drive of this kind needs, each as (name, the reason).

    `tyre_friction` where the drive uses more than half the grip (Dugoff leaves its linear range);
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
