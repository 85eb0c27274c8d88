"""The seed's bicycle model (eq. 1–13) as a vector field, with composable effects.

Conventions where the seed is ambiguous or wrong (each is also noted where it is used):
  * states: Vx, Vy, r, ω_f, ω_r, α̂_f, α̂_r, κ̂_f, κ̂_r, then the states of enabled effects;
  * l_r = L − l_f and I_z = m·l_f·l_r (seed: "approximated by I_z = m·l_r·l_f");
  * tire forces use the relaxed slips α̂, κ̂ (eq. 13 applied to κ with the same σ_l);
  * eq. 7 as printed (R_l = F_z/C_vert) is a deflection, not a radius: we use
    R_l = R_f − F_z/C_vert;
  * eq. 11's load transfer m·h·a_x/L uses the specific force a_x (tire and other
    non-gravitational forces / m), solved by fixed-point iteration since a_x depends on the
    loads through Dugoff's f(λ).

Two longitudinal models, final classes under `AbstractVehicleModel`:
  * `TorqueDriven` ("torque", the seed): the wheels are driven by the applied axle torques;
  * `SpeedDriven` ("speed", real logs without torques): Vx is the measured speed and a_x the
    measured specific force, both given in `Inputs`; the tires roll freely (κ = 0) and only
    the lateral and yaw dynamics are simulated. The state layout stays the same so that
    effects keep their state slots.
"""

from __future__ import annotations

from typing import ClassVar, Literal

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Float

from ._effects import AbstractEffect, Context
from ._inputs import Inputs
from ._model import V_FLOOR, AbstractVehicleModel, Args, Longitudinal
from ._tire import dugoff_demand, dugoff_with_load
from ._vehicle import GRAVITY, Vehicle

#: Fixed-point iterations for the load-transfer/a_x loop (converges in ~2: f(λ) is flat).
LOAD_ITERATIONS = 3


class TorqueDriven(AbstractVehicleModel):
    """The seed's model: the wheels are driven by the applied axle torques `Inputs.torque_*`.

    Attributes:
        vehicle: known constants.
        effects: enabled effects, applied in this order.
    """

    vehicle: Vehicle
    effects: tuple[AbstractEffect, ...] = eqx.field(static=True, default=())
    longitudinal: ClassVar[str] = "torque"
    measured_inputs: ClassVar[tuple[str, ...]] = ()

    def _start(self, theta, effect_params, inputs: Inputs, v0) -> tuple:
        return (v0, *self.vertical_loads(theta, effect_params, v0))

    def _longitudinal(self, t, y, args: Args, cos_sin) -> Longitudinal:
        theta, effect_params, _ = args
        vx, vy, r, a_f_hat, a_r_hat, k_f_hat, k_r_hat = y[0], y[1], y[2], y[5], y[6], y[7], y[8]
        _, _, ckf, ckr, caf, car = (theta[i] for i in range(6))
        r_free = self.radius(effect_params)
        loads0 = self.vertical_loads(theta, effect_params, vx)
        zero = jnp.zeros_like(vx)
        ctx0 = self._context(y, r_free, *loads0, zero)
        fbx, fby, gx, gy = zero, zero, zero, zero
        for e, p in zip(self.effects, effect_params):
            bx, by = e.body_force(p, ctx0)
            ax_g, ay_g = e.gravity_accel(p, ctx0)
            fbx, fby, gx, gy = fbx + bx, fby + by, gx + ax_g, gy + ay_g
        demands = (dugoff_demand(ckf, caf, k_f_hat, a_f_hat), dugoff_demand(ckr, car, k_r_hat, a_r_hat))
        mu = self.friction(effect_params)
        forces = self._loaded_tire_forces(theta, loads0, demands, mu, cos_sin, fbx)
        fz_f, fz_r, fx_f, fy_f, fx_r, fy_r = forces
        cos_d, sin_d = cos_sin
        a_x = (fx_f * cos_d - fy_f * sin_d + fx_r + fbx) / self.vehicle.mass
        ctx = self._context(y, r_free, fz_f, fz_r, zero)._replace(ax=a_x)
        # Eq. 1 in body axes; gravity along x (grade) adds to the motion only.
        return Longitudinal(ctx, (fx_f, fy_f, fx_r, fy_r), fby, gy, a_x + gx + vy * r)

    def _wheel_rates(self, y, args: Args, u, lon: Longitudinal, rate) -> tuple:
        vx, wf, wr, k_f_hat, k_r_hat = y[0], y[3], y[4], y[7], y[8]
        ctx = lon.ctx
        fx_f, _, fx_r, _ = lon.forces
        # Eq. 3, each wheel's longitudinal speed taken as Vx (seed: V_xf = V_xr = V_x).
        rw_f = ctx.r_eff_front * wf
        rw_r = ctx.r_eff_rear * wr
        kappa_f = (rw_f - vx) / jnp.maximum(jnp.maximum(rw_f, vx), V_FLOOR)
        kappa_r = (rw_r - vx) / jnp.maximum(jnp.maximum(rw_r, vx), V_FLOOR)
        tq_f, tq_r = u[1], u[2]
        for e, p in zip(self.effects, args.effect_params):
            ef, er = e.wheel_torque(p, ctx)
            tq_f, tq_r = tq_f + ef, tq_r + er
        # Eq. 12 per axle: I_w·ω̇ = T − F_x·R_eff, T the axle's total torque input.
        dwf = (tq_f - fx_f * ctx.r_eff_front) / self.vehicle.wheel_inertia
        dwr = (tq_r - fx_r * ctx.r_eff_rear) / self.vehicle.wheel_inertia
        return dwf, dwr, rate * (kappa_f - k_f_hat), rate * (kappa_r - k_r_hat)

    def _context(self, y, r_free, fz_f, fz_r, r_dot) -> Context:
        """What effects see: the base states with axle loads ``fz_*``."""
        vx, vy, r, wf, wr = (y[i] for i in range(5))
        return Context(
            vx=vx,
            vy=vy,
            r=r,
            r_dot=r_dot,
            fz_front=fz_f,
            fz_rear=fz_r,
            r_eff_front=self.effective_radius(r_free, fz_f),
            r_eff_rear=self.effective_radius(r_free, fz_r),
            omega_front=wf,
            omega_rear=wr,
            mass=jnp.asarray(self.vehicle.mass),
            gravity=GRAVITY,
        )

    def _loaded_tire_forces(self, theta, loads0, demands, mu, cos_sin, fbx):
        """Eq. 11 and the Dugoff forces solved together: ``(fz_f, fz_r, fx_f, fy_f, fx_r, fy_r)``.

        The loads `loads0` at a_x = 0 (`vertical_loads`) follow the specific force a_x (the
        seed's ± sign: load moves rearwards under acceleration), which the tire forces make: a
        fixed point, `LOAD_ITERATIONS` passes.
        """
        m, L, h = self.vehicle.mass, self.vehicle.wheelbase, theta[1]
        fz_f0, fz_r0 = loads0
        cos_d, sin_d = cos_sin

        def tire_forces(a_x):
            fz_f = fz_f0 - m * h * a_x / L
            fz_r = fz_r0 + m * h * a_x / L
            fx_f, fy_f = dugoff_with_load(demands[0], fz_f, mu[0])
            fx_r, fy_r = dugoff_with_load(demands[1], fz_r, mu[1])
            a_x_new = (fx_f * cos_d - fy_f * sin_d + fx_r + fbx) / m
            return a_x_new, (fz_f, fz_r, fx_f, fy_f, fx_r, fy_r)

        # A rolled loop on purpose: its outputs are materialised once. Unrolled, XLA's loop
        # fusion re-derives the whole load/Dugoff chain (tan included) inside each of the nine
        # derivative kernels, which made the batched RHS several times slower.
        _, forces = jax.lax.fori_loop(
            0, LOAD_ITERATIONS - 1, lambda _, c: tire_forces(c[0]), tire_forces(jnp.zeros_like(fbx))
        )
        return forces


class SpeedDriven(AbstractVehicleModel):
    """Vx is the measured speed and a_x the measured specific force (`Inputs.speed`,
    `Inputs.accel`); the tires roll freely (κ = 0) and only the lateral and yaw dynamics are
    simulated. For real logs without applied torques.

      * Vx is the measured speed interpolated at t wherever the model needs it; the Vx state
        integrates its slope and is otherwise unused. ω_f, ω_r integrate slope/R_eff; the
        omega readings are Vx/R_eff at the current load. κ̂ states stay 0.
      * the loads use m·h·a_x/L with the measured a_x; there are no longitudinal tire forces,
        so C_kappa_f, C_kappa_r have no effect at all and h_cog acts only through the loads.
      * readings: ax is the measured accel (an input, so inference should not condition on it)
        passed through the measurement effects; ay and yaw_rate are simulated; vx is the
        measured speed; omega_* as above.
      * effects: measurement, steering and gravity-along-y (bank) effects act as in
        `TorqueDriven`; wheel torques, torque inputs, longitudinal body forces and gravity
        along x (grade) cannot change Vx, which is measured.

    Attributes:
        vehicle: known constants.
        effects: enabled effects, applied in this order.
    """

    vehicle: Vehicle
    effects: tuple[AbstractEffect, ...] = eqx.field(static=True, default=())
    longitudinal: ClassVar[str] = "speed"
    measured_inputs: ClassVar[tuple[str, ...]] = ("speed", "accel")

    def _start(self, theta, effect_params, inputs: Inputs, v0) -> tuple:
        v0, _, a_x0 = inputs.longitudinal(inputs.t0)
        return (v0, *self.loads(theta, effect_params, v0, a_x0))

    def _longitudinal(self, t, y, args: Args, cos_sin) -> Longitudinal:
        theta, effect_params, inputs = args
        vy, r, a_f_hat, a_r_hat = y[1], y[2], y[5], y[6]
        vx, dvx, a_x = inputs.longitudinal(t)
        caf, car = theta[4], theta[5]
        r_free = self.radius(effect_params)
        # Eq. 11 with the measured specific force: no fixed point to solve.
        fz_f, fz_r = self.loads(theta, effect_params, vx, a_x)
        r_eff_f = self.effective_radius(r_free, fz_f)
        r_eff_r = self.effective_radius(r_free, fz_r)
        zero = jnp.zeros_like(vx)
        ctx = Context(
            vx=vx,
            vy=vy,
            r=r,
            r_dot=zero,
            fz_front=fz_f,
            fz_rear=fz_r,
            r_eff_front=r_eff_f,
            r_eff_rear=r_eff_r,
            # Free rolling: the wheels turn at Vx/R_eff whatever the ω states hold.
            omega_front=vx / r_eff_f,
            omega_rear=vx / r_eff_r,
            mass=jnp.asarray(self.vehicle.mass),
            gravity=GRAVITY,
        )
        fby, gy = zero, zero
        for e, p in zip(self.effects, effect_params):
            # The x components would change Vx, which is measured here: dropped.
            fby = fby + e.body_force(p, ctx)[1]
            gy = gy + e.gravity_accel(p, ctx)[1]
        mu_f, mu_r = self.friction(effect_params)
        # κ = 0 as a constant (not the κ̂ states), so C_kappa_* have an exactly zero gradient.
        fx_f, fy_f = dugoff_with_load(dugoff_demand(theta[2], caf, zero, a_f_hat), fz_f, mu_f)
        fx_r, fy_r = dugoff_with_load(dugoff_demand(theta[3], car, zero, a_r_hat), fz_r, mu_r)
        return Longitudinal(ctx._replace(ax=a_x), (fx_f, fy_f, fx_r, fy_r), fby, gy, dvx)

    def _wheel_rates(self, y, args: Args, u, lon: Longitudinal, rate) -> tuple:
        zero = jnp.zeros_like(lon.ctx.vx)
        # dR_eff/dt is left out: the ω states are bookkeeping, unused in this mode.
        return lon.dvx / lon.ctx.r_eff_front, lon.dvx / lon.ctx.r_eff_rear, zero, zero


#: The longitudinal models by their name at the public boundary (command lines, reports).
MODELS: dict[str, type[AbstractVehicleModel]] = {m.longitudinal: m for m in (TorqueDriven, SpeedDriven)}
LONGITUDINAL_MODES: tuple[str, ...] = tuple(MODELS)
#: How the longitudinal motion is driven: by the wheel torques, or following the measured speed.
LongitudinalMode = Literal["torque", "speed"]
#: A user's choice of it: "auto" takes torques where the recording has them.
LongitudinalChoice = Literal["auto", "torque", "speed"]


def model_class(longitudinal: LongitudinalMode | type[AbstractVehicleModel]) -> type[AbstractVehicleModel]:
    """The model class for a mode's name ("torque", "speed"), or the class itself.

    Raises:
        ValueError: an unknown name.
    """
    if isinstance(longitudinal, type) and issubclass(longitudinal, AbstractVehicleModel):
        return longitudinal
    if longitudinal not in MODELS:
        raise ValueError(f"longitudinal must be one of {list(LONGITUDINAL_MODES)}, got {longitudinal!r}")
    return MODELS[longitudinal]


def VehicleModel(
    vehicle: Vehicle, effects: tuple[AbstractEffect, ...] = (), longitudinal: LongitudinalMode = "torque"
) -> AbstractVehicleModel:
    """The model for effect modules and a mode's name: `TorqueDriven` or `SpeedDriven`."""
    return model_class(longitudinal)(vehicle=vehicle, effects=effects)


def steady_lateral_state(
    theta: Float[Array, "6"], vehicle: Vehicle, vx: Float[Array, "*B"], yaw_rate: Float[Array, "*B"]
) -> tuple[Float[Array, "*B"], Float[Array, "*B"]]:
    """Linear single-track steady state (Vy, r) that carries a measured yaw rate.

    In steady cornering a_y = vx·r and the rear axle carries F_yr = m·a_y·l_f/L, so its slip
    is α_r = m·vx·r·l_f/(L·C_αr) and Vy = l_r·r − vx·α_r (small angles). A θ-dependent,
    differentiable start for windows that begin mid-corner (`lateral0`).

    Args:
        theta: (6,) identified parameters (uses l_f and C_alpha_r).
        vehicle: vehicle constants.
        vx: longitudinal speed, m/s (any shape broadcasting with `yaw_rate`).
        yaw_rate: measured yaw rate, rad/s.

    Returns:
        (Vy m/s, r rad/s), broadcast to a common shape.
    """
    m, L = vehicle.mass, vehicle.wheelbase
    l_f, c_alpha_r = theta[0], theta[5]
    vx, r = jnp.broadcast_arrays(jnp.asarray(vx, dtype=float), jnp.asarray(yaw_rate, dtype=float))
    alpha_r = m * vx * r * l_f / (L * c_alpha_r)
    return (L - l_f) * r - vx * alpha_r, r
