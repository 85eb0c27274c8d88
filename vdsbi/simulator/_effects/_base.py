"""The interface every physics effect implements; all hooks default to 'no effect'.

(No `from __future__ import annotations` here: equinox needs `AbstractClassVar` unstringified.)
"""

from typing import ClassVar, NamedTuple

import equinox as eqx
import jax.numpy as jnp
from equinox import AbstractClassVar
from jaxtyping import Array, Float


class Context(NamedTuple):
    """Vehicle state seen by effect hooks (all scalars, SI units)."""

    vx: Float[Array, ""]
    vy: Float[Array, ""]
    r: Float[Array, ""]
    r_dot: Float[Array, ""]
    fz_front: Float[Array, ""]
    fz_rear: Float[Array, ""]
    r_eff_front: Float[Array, ""]
    r_eff_rear: Float[Array, ""]
    omega_front: Float[Array, ""]
    omega_rear: Float[Array, ""]
    mass: Float[Array, ""]
    gravity: float
    # Body accelerations (specific forces), where the hook is called after they are known
    # (`yaw_moment`, `measure`); 0 elsewhere.
    ax: Float[Array, ""] | float = 0.0
    ay: Float[Array, ""] | float = 0.0


class Param(NamedTuple):
    """One parameter of an effect.

    Attributes:
        name: its name within the effect (``tau``); files name it ``effect.name``.
        unit: its unit.
        null: the value at which the effect vanishes (the base model exactly).
        typical: (low, high) magnitudes met on real cars, used to simulate the effect and as the
            parameter's scale in Fisher information.
        bounds: (low, high) box inside which discovery fits it, wider than `typical` so an
            estimate is not pinned by the bound (physical sign constraints where they exist).
        start: where a fit starts when the effect is switched on, strictly inside `bounds`.
    """

    name: str
    unit: str
    null: float
    typical: tuple[float, float]
    bounds: tuple[float, float]
    start: float


def promoted(u: Array, *values) -> Array:
    """`u` in the dtype it and `values` promote to: an effect's `inputs` writes its parameters or
    states into it there and casts the result back to `u`'s dtype (what JAX does implicitly, with
    a warning that it will become an error)."""
    return u.astype(jnp.result_type(u, *values))


def _check_params(cls) -> None:
    """An effect's parameter records are consistent: checked when its class is defined."""
    where = f"effects: {cls.__name__}"
    for p in cls.params:
        if not isinstance(p, Param):
            raise ValueError(f"{where}: params must be Param records, got {p!r}")
        (lo, hi), (t_lo, t_hi) = p.bounds, p.typical
        # A start on the edge of the box has no finite unbounded coordinate in the fit.
        if not lo < p.start < hi:
            raise ValueError(
                f"{where}: start of '{p.name}' ({p.start}) must lie strictly inside bounds ({lo}, {hi})"
            )
        if not lo <= t_lo <= t_hi <= hi:
            raise ValueError(f"{where}: typical range of '{p.name}' must lie inside its bounds")
    names = [p.name for p in cls.params]
    if len(set(names)) != len(names):
        raise ValueError(f"{where}: parameter names {names} repeat")
    unknown = [p for p in cls.steer_lag if p not in names]
    if unknown:
        raise ValueError(f"{where}: steer_lag names {unknown}, not among its params")


class AbstractEffect(eqx.Module):
    """A physics effect left out of the base model.

    Class attributes describe the effect:

    - `name` and a one-line `description`;
    - `params`: one `Param` record per parameter (name, unit, null, typical, bounds, start),
      checked when the class is defined; `param_names`, `units`, `null`, `typical`, `bounds` and
      `start` are their columns, one entry per parameter;
    - `searched`: whether discovery's search includes it (default True).
    - `adds_load`: whether `vertical_load` can load the tyres beyond the car's weight
      (default False): the grip a drive used then bounds no friction factor from below.
    - `prior_bounds`: a drive's prior box (default: `bounds` widened to hold `null`).
    - `steer_lag`: the names of its parameters that are a lag of the car's response behind the
      logged steer, s (default none): a fit starts them at the lag the recording shows.

    Hooks receive `p`, the effect's parameter vector in `params`' order.
    """

    name: AbstractClassVar[str]
    params: AbstractClassVar[tuple[Param, ...]]
    description: AbstractClassVar[str]
    num_states: ClassVar[int] = 0
    searched: ClassVar[bool] = True
    adds_load: ClassVar[bool] = False
    steer_lag: ClassVar[tuple[str, ...]] = ()
    # The records' columns, set from `params` when a class is defined.
    param_names: ClassVar[tuple[str, ...]]
    units: ClassVar[tuple[str, ...]]
    null: ClassVar[tuple[float, ...]]
    typical: ClassVar[tuple[tuple[float, float], ...]]
    bounds: ClassVar[tuple[tuple[float, float], ...]]
    start: ClassVar[tuple[float, ...]]

    def __init_subclass__(cls, **kwargs):
        super().__init_subclass__(**kwargs)
        if "params" not in cls.__dict__ and "steer_lag" not in cls.__dict__:
            return
        if not hasattr(cls, "params"):
            raise ValueError(f"effects: {cls.__name__} names steer_lag but has no params")
        _check_params(cls)
        ps = cls.params
        cls.param_names = tuple(p.name for p in ps)
        cls.units = tuple(p.unit for p in ps)
        cls.null = tuple(float(p.null) for p in ps)
        cls.typical = tuple(tuple(map(float, p.typical)) for p in ps)
        cls.bounds = tuple(tuple(map(float, p.bounds)) for p in ps)
        cls.start = tuple(float(p.start) for p in ps)

    @classmethod
    def prior_bounds(cls, grip: float | None, extra_load: bool = False) -> tuple[tuple[float, float], ...]:
        """The prior box of a drive that uses `grip` × vehicle.json's μ·g (None: not known):
        `bounds` widened to hold `null` (what any car could have, not only a typical one). An
        effect whose range depends on the grip says so here; `extra_load`: another enabled
        effect loads the tyres beyond the car's weight (`adds_load`)."""
        return tuple((min(lo, n), max(hi, n)) for (lo, hi), n in zip(cls.bounds, cls.null))

    def init_state(self, p, u0: Float[Array, "3"]) -> Float[Array, " S"]:
        return jnp.zeros(self.num_states)

    def state_rhs(self, p, z, u_cmd) -> Float[Array, " S"]:
        return jnp.zeros(self.num_states)

    def inputs(self, p, z, u: Float[Array, "3"]) -> Float[Array, "3"]:
        """Effective (steer, torque_front, torque_rear) acting on the vehicle, in `u`'s dtype (a
        float64 fit may drive float32 inputs: write into `promoted(u, p)`, then cast back)."""
        return u

    def friction_scale(self, p) -> tuple[Float[Array, ""], Float[Array, ""]]:
        """Factors on the friction coefficient μ of the front and rear tyres."""
        return jnp.asarray(1.0), jnp.asarray(1.0)

    def vertical_load(self, p, vx, weight: float) -> tuple[Float[Array, ""], Float[Array, ""]]:
        """Extra vertical load on the front and rear axle at speed `vx` (m/s), N, beside the
        car's weight `weight` = m·g (N): it loads the tyres (their limit μ·F_z and loaded
        radius), not the IMU."""
        return jnp.asarray(0.0), jnp.asarray(0.0)

    def yaw_inertia_scale(self, p) -> Float[Array, ""]:
        """Factor on the yaw inertia I_z = m·l_f·l_r."""
        return jnp.asarray(1.0)

    def radius_scale(self, p) -> Float[Array, ""]:
        """Factor on the free tire radius."""
        return jnp.asarray(1.0)

    def wheel_torque(self, p, ctx: Context) -> tuple[Float[Array, ""], Float[Array, ""]]:
        """Extra torque on the front and rear axle, N·m."""
        return jnp.asarray(0.0), jnp.asarray(0.0)

    def body_force(self, p, ctx: Context) -> tuple[Float[Array, ""], Float[Array, ""]]:
        """Non-gravitational force on the body (felt by the IMU), N, body axes."""
        return jnp.asarray(0.0), jnp.asarray(0.0)

    def yaw_moment(self, p, ctx: Context) -> Float[Array, ""]:
        """Extra yaw moment about the centre of gravity, N·m (ctx carries a_x and a_y)."""
        return jnp.asarray(0.0)

    def gravity_accel(self, p, ctx: Context) -> tuple[Float[Array, ""], Float[Array, ""]]:
        """Gravity component in the road plane, m/s²: accelerates the car, unseen by the IMU."""
        return jnp.asarray(0.0), jnp.asarray(0.0)

    def measure(self, p, y: dict, ctx: Context) -> dict:
        """Transform the ideal sensor readings {channel: value}."""
        return y
