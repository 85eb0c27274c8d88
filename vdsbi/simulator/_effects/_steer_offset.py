from ._base import AbstractEffect, Param, promoted


class SteerOffset(AbstractEffect):
    """Constant offset δ₀ between the recorded and the acting road-wheel angle: δ = δ_rec + δ₀."""

    name = "steer_offset"
    # Road-wheel angle: a steering-wheel sensor's zero a degree or two off, over a ratio of ~15.
    params = (Param("offset", "rad", null=0.0, typical=(-0.005, 0.005), bounds=(-0.03, 0.03), start=0.0),)
    # identify adds it where a drive shows it (`default_effects`); as a discovery candidate it
    # would have to be told from road_bank, which also turns the car at a steer of zero.
    searched = False
    description = (
        "steer zero offset (the car yaws at a logged steer of zero: sensor zero, alignment, road crown)"
    )

    def inputs(self, p, z, u):
        return promoted(u, p).at[0].add(p[0]).astype(u.dtype)
