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

Two longitudinal modes (`VehicleModel.longitudinal`):
  * "torque" (the seed): the wheels are driven by the applied axle torques;
  * "speed" (real logs without torques): Vx is the measured speed and a_x the measured
    specific force, both given in `Inputs`; the tires roll freely (κ = 0) and only the
    lateral and yaw dynamics are simulated. The state layout stays the same so that effects
    keep their state slots.
"""

from __future__ import annotations

from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Float

from ._effects import AbstractEffect, Context
from ._fastmath import arctan
from ._inputs import Inputs
from ._tire import dugoff_demand, dugoff_with_load
from ._vehicle import CHANNELS, GRAVITY, Vehicle

NUM_BASE_STATES = 9
#: Below this speed slips are regularised (eq. 2–3 are singular at standstill).
V_FLOOR = 0.5
#: Fixed-point iterations for the load-transfer/a_x loop (converges in ~2: f(λ) is flat).
LOAD_ITERATIONS = 3


class Args(NamedTuple):
    theta: Float[Array, "6"]
    effect_params: tuple
    inputs: Inputs


LONGITUDINAL_MODES: tuple[str, ...] = ("torque", "speed")


class VehicleModel(eqx.Module):
    """Vehicle constants plus the enabled effects (in application order).

    Attributes:
        vehicle: known constants.
        effects: enabled effects, applied in this order.
        longitudinal: "torque" (wheels driven by `Inputs.torque_*`, the seed's model) or
            "speed" (Vx follows `Inputs.speed`, load transfer from `Inputs.accel`, free-rolling
            tires; for logs without applied torques).

    In speed mode:
      * Vx is the measured speed interpolated at t wherever the model needs it; the Vx state
        integrates its slope and is otherwise unused. ω_f, ω_r integrate slope/R_eff; the
        omega readings are Vx/R_eff at the current load. κ̂ states stay 0.
      * the loads use m·h·a_x/L with the measured a_x; there are no longitudinal tire forces,
        so C_kappa_f, C_kappa_r have no effect at all and h_cog acts only through the loads.
      * readings: ax is the measured accel (an input, so inference should not condition on it)
        passed through the measurement effects; ay and yaw_rate are simulated; vx is the
        measured speed; omega_* as above.
      * effects: measurement, steering and gravity-along-y (bank) effects act as in torque
        mode; wheel torques, torque inputs, longitudinal body forces and gravity along x
        (grade) cannot change Vx, which is measured.
    """

    vehicle: Vehicle
    effects: tuple[AbstractEffect, ...] = eqx.field(static=True, default=())
    longitudinal: str = eqx.field(static=True, default="torque")

    def __check_init__(self):
        if self.longitudinal not in LONGITUDINAL_MODES:
            raise ValueError(
                f"model: longitudinal must be one of {LONGITUDINAL_MODES}, got {self.longitudinal!r}"
            )

    @property
    def num_states(self) -> int:
        return NUM_BASE_STATES + sum(e.num_states for e in self.effects)

    def _effect_states(self, y):
        out, i = [], NUM_BASE_STATES
        for e in self.effects:
            out.append(y[i : i + e.num_states])
            i += e.num_states
        return out

    def friction(self, effect_params) -> tuple[Float[Array, ""], Float[Array, ""]]:
        """Friction μ of the front and rear tyres: vehicle.json's μ times the effects' factors."""
        front, rear = jnp.asarray(1.0), jnp.asarray(1.0)
        for e, p in zip(self.effects, effect_params):
            f, r = e.friction_scale(p)
            front, rear = front * f, rear * r
        return self.vehicle.friction * front, self.vehicle.friction * rear

    def yaw_inertia(self, theta, effect_params) -> Float[Array, ""]:
        """I_z = m·l_f·l_r (the seed's approximation) times the effects' factors."""
        scale = jnp.asarray(1.0)
        for e, p in zip(self.effects, effect_params):
            scale = scale * e.yaw_inertia_scale(p)
        l_f = theta[0]
        return self.vehicle.mass * l_f * (self.vehicle.wheelbase - l_f) * scale

    def yaw_moment(self, effect_params, ctx: Context) -> Float[Array, ""]:
        """The effects' extra yaw moment about the centre of gravity, N·m."""
        total = jnp.zeros_like(ctx.vx)
        for e, p in zip(self.effects, effect_params):
            total = total + e.yaw_moment(p, ctx)
        return total

    def radius(self, effect_params) -> Float[Array, ""]:
        scale = jnp.asarray(1.0)
        for e, p in zip(self.effects, effect_params):
            scale = scale * e.radius_scale(p)
        return self.vehicle.wheel_radius * scale

    def static_loads(self, theta):
        L, m = self.vehicle.wheelbase, self.vehicle.mass
        l_f = theta[0]
        return m * GRAVITY * (L - l_f) / L, m * GRAVITY * l_f / L

    def effective_radius(self, r_free, fz):
        # Eq. 6 with R_l = R_f − F_z/C_vert: R_eff = R_f − F_z/(3·C_vert).
        return r_free - fz / (3.0 * self.vehicle.tire_vertical_stiffness)

    def initial_state(self, theta, effect_params, inputs: Inputs, v0, lateral0=None) -> Float[Array, " S"]:
        """State at `inputs.t0`.

        Args:
            theta: (6,) identified parameters.
            effect_params: one parameter vector per enabled effect.
            inputs: driver inputs.
            v0: initial speed, m/s (torque mode; speed mode takes the measured speed at t0).
            lateral0: optional (2,) (Vy0 m/s, r0 rad/s). None: Vy = r = 0 and relaxed slips 0
                (the seed's start from straight running). Given: the relaxed slips start at
                the kinematic slip angles, so a window started mid-corner has no start-up
                transient.

        Returns:
            (S,): Vx, Vy, r, ω_f, ω_r (Vx/R_eff at static load in torque mode, at the measured
            a_x's load in speed mode), α̂_f, α̂_r, κ̂ = 0, then the effect states at rest.
        """
        r_free = self.radius(effect_params)
        u0 = inputs(inputs.t0)
        if self.longitudinal == "speed":
            v0, _, a_x0 = inputs.longitudinal(inputs.t0)
            fzf, fzr = self.loads(theta, a_x0)
        else:
            fzf, fzr = self.static_loads(theta)
        v0 = jnp.asarray(v0, dtype=float)
        zero = jnp.zeros_like(v0)
        extra = [e.init_state(p, u0) for e, p in zip(self.effects, effect_params)]
        if lateral0 is None:
            vy0, r0, a_f0, a_r0 = zero, zero, zero, zero
        else:
            lateral0 = jnp.asarray(lateral0, dtype=v0.dtype)
            vy0, r0 = lateral0[0], lateral0[1]
            # The acting steer at t0: the recorded one after input effects (e.g. a lag
            # starting from its own initial state).
            u = u0
            for e, p, z in zip(self.effects, effect_params, extra):
                u = e.inputs(p, z, u)
            l_f = theta[0]
            l_r = self.vehicle.wheelbase - l_f
            vx_pos = jnp.maximum(v0, V_FLOOR)
            a_f0 = u[0] - arctan((vy0 + l_f * r0) / vx_pos)
            a_r0 = -arctan((vy0 - l_r * r0) / vx_pos)
        base = jnp.stack(
            [
                v0,
                vy0,
                r0,
                v0 / self.effective_radius(r_free, fzf),
                v0 / self.effective_radius(r_free, fzr),
                a_f0,
                a_r0,
            ]
            + [zero] * 2
        )
        return jnp.concatenate([base, *extra]) if extra else base

    def loads(self, theta, a_x):
        """Axle loads (N) under the specific force a_x (m/s²), eq. 11."""
        fz_f0, fz_r0 = self.static_loads(theta)
        shift = self.vehicle.mass * theta[1] * a_x / self.vehicle.wheelbase
        return fz_f0 - shift, fz_r0 + shift

    def evaluate(self, t, y, args: Args):
        """Returns (dy/dt (S,), sensor readings (6,) in CHANNELS order)."""
        if self.longitudinal == "speed":
            return self._evaluate_speed(t, y, args)
        theta, effect_params, inputs = args
        veh = self.vehicle
        m, L = veh.mass, veh.wheelbase
        mu_f, mu_r = self.friction(effect_params)
        vx, vy, r, wf, wr, a_f_hat, a_r_hat, k_f_hat, k_r_hat = (y[i] for i in range(9))
        zs = self._effect_states(y)
        u_cmd = inputs(t)
        u = self._received_inputs(effect_params, zs, u_cmd)
        delta, torque_f, torque_r = u[0], u[1], u[2]
        l_f, _, ckf, ckr, caf, car = (theta[i] for i in range(6))
        l_r = L - l_f
        r_free = self.radius(effect_params)
        fz_f0, fz_r0 = self.static_loads(theta)
        zero = jnp.zeros_like(vx)
        ctx0 = self._context(y, r_free, fz_f0, fz_r0, zero)
        fbx, fby, gx, gy = zero, zero, zero, zero
        for e, p in zip(self.effects, effect_params):
            bx, by = e.body_force(p, ctx0)
            ax_g, ay_g = e.gravity_accel(p, ctx0)
            fbx, fby, gx, gy = fbx + bx, fby + by, gx + ax_g, gy + ay_g

        cos_d, sin_d = jnp.cos(delta), jnp.sin(delta)
        demands = (dugoff_demand(ckf, caf, k_f_hat, a_f_hat), dugoff_demand(ckr, car, k_r_hat, a_r_hat))
        forces = self._loaded_tire_forces(theta, demands, (mu_f, mu_r), (cos_d, sin_d), fbx)
        fz_f, fz_r, fx_f, fy_f, fx_r, fy_r = forces
        a_x = (fx_f * cos_d - fy_f * sin_d + fx_r + fbx) / m
        a_y = (fx_f * sin_d + fy_f * cos_d + fy_r + fby) / m

        alpha_f, alpha_r, rate = self._slip_angles(delta, vx, vy, r, l_f, l_r)
        # Eq. 3, each wheel's longitudinal speed taken as Vx (seed: V_xf = V_xr = V_x).
        ctx = self._context(y, r_free, fz_f, fz_r, zero)._replace(ax=a_x, ay=a_y)
        rw_f = ctx.r_eff_front * wf
        rw_r = ctx.r_eff_rear * wr
        kappa_f = (rw_f - vx) / jnp.maximum(jnp.maximum(rw_f, vx), V_FLOOR)
        kappa_r = (rw_r - vx) / jnp.maximum(jnp.maximum(rw_r, vx), V_FLOOR)

        tq_f, tq_r = torque_f, torque_r
        for e, p in zip(self.effects, effect_params):
            ef, er = e.wheel_torque(p, ctx)
            tq_f, tq_r = tq_f + ef, tq_r + er
        # Eq. 12 per axle: I_w·ω̇ = T − F_x·R_eff, T the axle's total torque input.
        dwf = (tq_f - fx_f * ctx.r_eff_front) / veh.wheel_inertia
        dwr = (tq_r - fx_r * ctx.r_eff_rear) / veh.wheel_inertia
        # Eq. 1 in body axes; gravity components of grade/bank add to the motion only.
        dvx = a_x + gx + vy * r
        dvy = a_y + gy - vx * r
        dr = self._yaw_acceleration(theta, effect_params, ctx, (fx_f, fy_f, fy_r), (cos_d, sin_d))
        d_base = jnp.stack(
            [
                dvx,
                dvy,
                dr,
                dwf,
                dwr,
                rate * (alpha_f - a_f_hat),
                rate * (alpha_r - a_r_hat),
                rate * (kappa_f - k_f_hat),
                rate * (kappa_r - k_r_hat),
            ]
        )
        return self._with_effects(d_base, effect_params, zs, u_cmd, ctx._replace(r_dot=dr))

    def _evaluate_speed(self, t, y, args: Args):
        # Speed mode (see the class docstring): Vx and a_x are measured, κ = 0, no wheel torques.
        theta, effect_params, inputs = args
        veh = self.vehicle
        m, L = veh.mass, veh.wheelbase
        mu_f, mu_r = self.friction(effect_params)
        vy, r, a_f_hat, a_r_hat = y[1], y[2], y[5], y[6]
        vx, dvx, a_x = inputs.longitudinal(t)
        zs = self._effect_states(y)
        u_cmd = inputs(t)
        u = self._received_inputs(effect_params, zs, u_cmd)
        delta = u[0]
        l_f, _, _, _, caf, car = (theta[i] for i in range(6))
        l_r = L - l_f
        r_free = self.radius(effect_params)
        # Eq. 11 with the measured specific force: no fixed point to solve.
        fz_f, fz_r = self.loads(theta, a_x)
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
            mass=jnp.asarray(m),
            gravity=GRAVITY,
        )
        fby, gy = zero, zero
        for e, p in zip(self.effects, effect_params):
            # The x components would change Vx, which is measured here: dropped.
            fby = fby + e.body_force(p, ctx)[1]
            gy = gy + e.gravity_accel(p, ctx)[1]

        cos_d, sin_d = jnp.cos(delta), jnp.sin(delta)
        # κ = 0 as a constant (not the κ̂ states), so C_kappa_* have an exactly zero gradient.
        fx_f, fy_f = dugoff_with_load(dugoff_demand(theta[2], caf, zero, a_f_hat), fz_f, mu_f)
        fx_r, fy_r = dugoff_with_load(dugoff_demand(theta[3], car, zero, a_r_hat), fz_r, mu_r)
        a_y = (fx_f * sin_d + fy_f * cos_d + fy_r + fby) / m

        alpha_f, alpha_r, rate = self._slip_angles(delta, vx, vy, r, l_f, l_r)

        dvy = a_y + gy - vx * r
        ctx = ctx._replace(ax=a_x, ay=a_y)
        dr = self._yaw_acceleration(theta, effect_params, ctx, (fx_f, fy_f, fy_r), (cos_d, sin_d))
        d_base = jnp.stack(
            [
                dvx,
                dvy,
                dr,
                # dR_eff/dt is left out: the ω states are bookkeeping, unused in this mode.
                dvx / r_eff_f,
                dvx / r_eff_r,
                rate * (alpha_f - a_f_hat),
                rate * (alpha_r - a_r_hat),
                zero,
                zero,
            ]
        )
        return self._with_effects(d_base, effect_params, zs, u_cmd, ctx._replace(r_dot=dr))

    def _context(self, y, r_free, fz_f, fz_r, r_dot) -> Context:
        """What effects see in torque mode: the base states with axle loads ``fz_*``."""
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

    def _loaded_tire_forces(self, theta, demands, mu, cos_sin, fbx):
        """Eq. 11 and the Dugoff forces solved together: ``(fz_f, fz_r, fx_f, fy_f, fx_r, fy_r)``.

        The loads follow the specific force a_x (the seed's ± sign: load moves rearwards under
        acceleration), which the tire forces make: a fixed point, `LOAD_ITERATIONS` passes.
        """
        m, L, h = self.vehicle.mass, self.vehicle.wheelbase, theta[1]
        fz_f0, fz_r0 = self.static_loads(theta)
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

    def _received_inputs(self, effect_params, zs, u_cmd):
        """The driver inputs as the vehicle receives them (after the effects' input transforms)."""
        u = u_cmd
        for e, p, z in zip(self.effects, effect_params, zs):
            u = e.inputs(p, z, u)
        return u

    def _slip_angles(self, delta, vx, vy, r, l_f, l_r):
        """Eq. 2, 4, 5: slip angles from contact-patch velocities, and eq. 13's relaxation rate
        Vx/σ_l (for α̂ and, by the seed's analogy, κ̂ with the same σ_l)."""
        # Vx floored at V_FLOOR because eq. 2–3 are singular at standstill.
        vx_pos = jnp.maximum(vx, V_FLOOR)
        alpha_f = delta - arctan((vy + l_f * r) / vx_pos)
        alpha_r = -arctan((vy - l_r * r) / vx_pos)
        return alpha_f, alpha_r, jnp.maximum(vx, 0.0) / self.vehicle.relaxation_length

    def _yaw_acceleration(self, theta, effect_params, ctx: Context, forces, cos_sin):
        """Eq. 1's yaw equation: axle lateral forces about the CoG plus the effects' moments."""
        fx_f, fy_f, fy_r = forces
        cos_d, sin_d = cos_sin
        l_f = theta[0]
        l_r = self.vehicle.wheelbase - l_f
        m_z = self.yaw_moment(effect_params, ctx)
        lateral_f = fx_f * sin_d + fy_f * cos_d
        return (l_f * lateral_f - l_r * fy_r + m_z) / self.yaw_inertia(theta, effect_params)

    def _with_effects(self, d_base, effect_params, zs, u_cmd, ctx: Context):
        """The effects' state derivatives appended to the base ones, and the sensor readings
        after the effects' measurement models, in CHANNELS order."""
        d_extra = [e.state_rhs(p, z, u_cmd) for e, p, z in zip(self.effects, effect_params, zs)]
        dy = jnp.concatenate([d_base, *d_extra]) if d_extra else d_base
        readings = {
            "ax": ctx.ax,
            "ay": ctx.ay,
            "yaw_rate": ctx.r,
            "omega_front": ctx.omega_front,
            "omega_rear": ctx.omega_rear,
            "vx": ctx.vx,
        }
        for e, p in zip(self.effects, effect_params):
            readings = e.measure(p, readings, ctx)
        return dy, jnp.stack([readings[c] for c in CHANNELS])

    def vector_field(self, t, y, args: Args):
        return self.evaluate(t, y, args)[0]

    def sensors(self, t, y, args: Args):
        return self.evaluate(t, y, args)[1]


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
