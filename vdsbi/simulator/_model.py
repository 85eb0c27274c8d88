"""What the two longitudinal models share: the state layout, the effects' hooks, the lateral and
yaw dynamics and the readings (the conventions are listed in `_dynamics`)."""

from __future__ import annotations

import abc
from typing import NamedTuple

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, Float

from ._effects import AbstractEffect, Context
from ._fastmath import arctan
from ._inputs import Inputs
from ._vehicle import CHANNELS, GRAVITY, Vehicle

NUM_BASE_STATES = 9
#: Below this speed slips are regularised (eq. 2–3 are singular at standstill).
V_FLOOR = 0.5


class Args(NamedTuple):
    theta: Float[Array, "6"]
    effect_params: tuple
    inputs: Inputs


class Longitudinal(NamedTuple):
    """What a longitudinal model hands the shared lateral/yaw dynamics."""

    ctx: Context  # loads, radii and wheel speeds, with `ax` set
    forces: tuple  # axle tire forces (fx_f, fy_f, fx_r, fy_r), N
    fby: Float[Array, ""]  # the effects' lateral body force, N
    gy: Float[Array, ""]  # gravity along y (bank), m/s²
    dvx: Float[Array, ""]  # dVx/dt, m/s²


class AbstractVehicleModel(eqx.Module):
    """Vehicle constants plus the enabled effects (in application order).

    Two final models differ in what drives the longitudinal motion: `TorqueDriven` (the
    seed's, the wheels driven by `Inputs.torque_*`) and `SpeedDriven` (Vx follows the
    measured `Inputs.speed`, for logs without applied torques). Everything else, the lateral
    and yaw dynamics, the effects' hooks and the readings, is shared here.

    Attributes:
        vehicle: known constants.
        effects: enabled effects, applied in this order.
        longitudinal: the mode's name at the public boundary ("torque" or "speed"), for
            command lines and reports.
        measured_inputs: `Inputs` series the model needs beyond steer and torques.
    """

    vehicle: eqx.AbstractVar[Vehicle]
    effects: eqx.AbstractVar[tuple[AbstractEffect, ...]]
    longitudinal: eqx.AbstractClassVar[str]
    measured_inputs: eqx.AbstractClassVar[tuple[str, ...]]

    @abc.abstractmethod
    def _start(self, theta, effect_params, inputs: Inputs, v0) -> tuple:
        """(Vx m/s, front load N, rear load N) at `inputs.t0`."""

    @abc.abstractmethod
    def _longitudinal(self, t, y, args: Args, cos_sin) -> Longitudinal:
        """Loads, tire forces, body forces and dVx/dt at (t, y) under the acting steer."""

    @abc.abstractmethod
    def _wheel_rates(self, y, args: Args, u, lon: Longitudinal, rate) -> tuple:
        """d/dt of (ω_f, ω_r, κ̂_f, κ̂_r); `u` the received inputs, `rate` Vx/σ_l."""

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

    def vertical_loads(self, theta, effect_params, vx):
        """Axle loads (N) at a_x = 0: the car's weight plus the effects' loads at Vx (m/s)."""
        fz_f, fz_r = self.static_loads(theta)
        weight = self.vehicle.mass * GRAVITY
        for e, p in zip(self.effects, effect_params):
            f, r = e.vertical_load(p, vx, weight)
            fz_f, fz_r = fz_f + f, fz_r + r
        return fz_f, fz_r

    def loads(self, theta, effect_params, vx, a_x):
        """Axle loads (N) at Vx (m/s) under the specific force a_x (m/s²), eq. 11."""
        fz_f0, fz_r0 = self.vertical_loads(theta, effect_params, vx)
        shift = self.vehicle.mass * theta[1] * a_x / self.vehicle.wheelbase
        return fz_f0 - shift, fz_r0 + shift

    def initial_state(self, theta, effect_params, inputs: Inputs, v0, lateral0=None) -> Float[Array, " S"]:
        """State at `inputs.t0`.

        Args:
            theta: (6,) identified parameters.
            effect_params: one parameter vector per enabled effect.
            inputs: driver inputs.
            v0: initial speed, m/s (`TorqueDriven`; `SpeedDriven` takes the measured speed at t0).
            lateral0: optional (2,) (Vy0 m/s, r0 rad/s). None: Vy = r = 0 and relaxed slips 0
                (the seed's start from straight running). Given: the relaxed slips start at
                the kinematic slip angles, so a window started mid-corner has no start-up
                transient.

        Returns:
            (S,): Vx, Vy, r, ω_f, ω_r (Vx/R_eff at the static load when torque-driven, at the
            measured a_x's load when speed-driven), α̂_f, α̂_r, κ̂ = 0, then the effect states
            at rest.
        """
        r_free = self.radius(effect_params)
        u0 = inputs(inputs.t0)
        v0, fzf, fzr = self._start(theta, effect_params, inputs, v0)
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
            u = self._received_inputs(effect_params, extra, u0)
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

    def evaluate(self, t, y, args: Args):
        """Returns (dy/dt (S,), sensor readings (6,) in CHANNELS order)."""
        theta, effect_params, inputs = args
        vy, r, a_f_hat, a_r_hat = y[1], y[2], y[5], y[6]
        zs = self._effect_states(y)
        u_cmd = inputs(t)
        u = self._received_inputs(effect_params, zs, u_cmd)
        delta = u[0]
        cos_sin = (jnp.cos(delta), jnp.sin(delta))
        lon = self._longitudinal(t, y, args, cos_sin)
        fx_f, fy_f, _, fy_r = lon.forces
        a_y = (fx_f * cos_sin[1] + fy_f * cos_sin[0] + fy_r + lon.fby) / self.vehicle.mass
        lon = lon._replace(ctx=lon.ctx._replace(ay=a_y))
        l_f = theta[0]
        l_r = self.vehicle.wheelbase - l_f
        vx = lon.ctx.vx
        alpha_f, alpha_r, rate = self._slip_angles(delta, vx, vy, r, l_f, l_r)
        dwf, dwr, dkf, dkr = self._wheel_rates(y, args, u, lon, rate)
        # Eq. 1 in body axes; gravity along y (bank) adds to the motion only.
        dvy = a_y + lon.gy - vx * r
        dr = self._yaw_acceleration(theta, effect_params, lon.ctx, (fx_f, fy_f, fy_r), cos_sin)
        d_base = jnp.stack(
            [
                lon.dvx,
                dvy,
                dr,
                dwf,
                dwr,
                rate * (alpha_f - a_f_hat),
                rate * (alpha_r - a_r_hat),
                dkf,
                dkr,
            ]
        )
        return self._with_effects(d_base, effect_params, zs, u_cmd, lon.ctx._replace(r_dot=dr))

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
