"""The design variables of excitation design: `Limits` (what a test drive may do) and `Maneuver`
(unconstrained, differentiable parameters of a drive). `Maneuver.inputs(limits)` maps them onto
the sample grid inside the hard limits by construction:

  * steer(t) = max_steer · tanh(Σ_k a_k sin(2π f_k t + φ_k)), f_k ∈ [f_min, f_max] (the
    `vdsbi.problem.Box` `Limits.frequencies`);
  * a pedal level ℓ(t) ∈ [−1, 1]: M segments whose lengths are a softmax share of the
    duration and whose levels are tanh-bounded, joined by sigmoid edges of width
    `edge_time`; ℓ > 0 drives the front axle (ℓ·max_drive; front-wheel drive), ℓ < 0 brakes
    with the vehicle's fixed brake balance (front share ℓ·max_brake·front_share, rear the rest);
  * v0 ∈ [v0_min, v0_max] (`Limits.speeds`).
"""

from __future__ import annotations

import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from ..problem import Box
from ..simulator import GRAVITY, Inputs


class Limits(eqx.Module):
    """What a test drive may do. Units SI; all static (they fix the design problem).

    Attributes:
        duration: maneuver length, s.
        rate: sample rate, Hz.
        max_steer: |road-wheel angle|, rad.
        max_drive: front-axle drive torque, N·m.
        max_brake: total brake torque, N·m.
        brake_front_share: the vehicle's brake balance (not a design variable).
        ay_fraction: |ay| ≤ ay_fraction·μ·g.
        v_min, v_max: speed window for vx over the whole maneuver, m/s.
        v0_min, v0_max: range of the initial speed, m/s.
        f_min, f_max: steer frequency range, Hz.
        edge_time: pedal transition time (10 % to 90 %), s.
    """

    duration: float = eqx.field(static=True, default=5.0)
    rate: float = eqx.field(static=True, default=200.0)
    max_steer: float = eqx.field(static=True, default=0.1)
    max_drive: float = eqx.field(static=True, default=900.0)
    max_brake: float = eqx.field(static=True, default=1800.0)
    brake_front_share: float = eqx.field(static=True, default=0.65)
    ay_fraction: float = eqx.field(static=True, default=0.6)
    v_min: float = eqx.field(static=True, default=5.0)
    v_max: float = eqx.field(static=True, default=20.0)
    v0_min: float = eqx.field(static=True, default=5.0)
    v0_max: float = eqx.field(static=True, default=20.0)
    f_min: float = eqx.field(static=True, default=0.1)
    f_max: float = eqx.field(static=True, default=2.0)
    edge_time: float = eqx.field(static=True, default=0.1)

    def __check_init__(self):
        if not (0 < self.v_min <= self.v0_min < self.v0_max <= self.v_max):
            raise ValueError("limits: need 0 < v_min <= v0_min < v0_max <= v_max")
        if not (0 < self.f_min < self.f_max):
            raise ValueError("limits: need 0 < f_min < f_max")
        for name in ("duration", "rate", "max_steer", "max_drive", "max_brake", "ay_fraction", "edge_time"):
            if not getattr(self, name) > 0:
                raise ValueError(f"limits: '{name}' must be > 0")
        if not 0 <= self.brake_front_share <= 1:
            raise ValueError("limits: 'brake_front_share' must lie in [0, 1]")

    def frequencies(self, num: int) -> Box:
        """The box of `num` steer frequencies, [f_min, f_max] Hz each."""
        names = tuple(f"frequency_{k}" for k in range(num))
        return Box(np.full(num, float(self.f_min)), np.full(num, float(self.f_max)), names)

    def speeds(self) -> Box:
        """The box of the initial speed, [v0_min, v0_max] m/s."""
        return Box(np.array([float(self.v0_min)]), np.array([float(self.v0_max)]), ("v0",))

    @property
    def num_samples(self) -> int:
        return int(round(self.duration * self.rate)) + 1

    def ay_max(self, friction: float) -> float:
        return self.ay_fraction * friction * GRAVITY


class Maneuver(eqx.Module):
    """Unconstrained maneuver parameters (map them with `inputs` / `initial_speed`).

    Attributes:
        steer_amp: (K,) sine amplitudes before the tanh bound (units of max_steer).
        steer_freq: (K,) unconstrained frequencies (sigmoid into [f_min, f_max]).
        steer_phase: (K,) phases, rad.
        pedal_level: (M,) unconstrained levels (tanh into [−1, 1]).
        pedal_length: (M,) unconstrained segment lengths (softmax share of the duration).
        v0: unconstrained initial speed (sigmoid into [v0_min, v0_max]).
    """

    steer_amp: Float[Array, " K"]
    steer_freq: Float[Array, " K"]
    steer_phase: Float[Array, " K"]
    pedal_level: Float[Array, " M"]
    pedal_length: Float[Array, " M"]
    v0: Float[Array, ""]

    @classmethod
    def seed_like(cls, limits: Limits, num_sines: int = 3, num_segments: int = 4) -> Maneuver:
        """A start close to the seed's maneuver at 10.5 m/s: 0.05 rad steer at 0.25 Hz
        (small extra sines at 0.5 and 1 Hz), drive then brake at the seed's levels."""
        f = np.array([0.25, 0.5, 1.0, 1.5, 0.75, 0.35][:num_sines])
        amp = np.zeros(num_sines)
        amp[0] = math.atanh(min(0.05 / limits.max_steer, 0.99))
        amp[1:] = 0.05
        drive = min(600.0 / limits.max_drive, 0.99)
        brake = min(1200.0 / limits.max_brake, 0.99)
        levels = np.array([drive if i < num_segments // 2 else -brake for i in range(num_segments)])
        return cls(
            steer_amp=jnp.asarray(amp),
            steer_freq=limits.frequencies(num_sines).to_unbounded(f, edge=1e-6),
            steer_phase=jnp.zeros(num_sines),
            pedal_level=jnp.asarray(np.arctanh(levels)),
            pedal_length=jnp.zeros(num_segments),
            v0=limits.speeds().to_unbounded(jnp.array([10.5]), edge=1e-6)[0],
        )

    def initial_speed(self, limits: Limits) -> Float[Array, ""]:
        return limits.speeds().from_unbounded(self.v0[None])[0]

    def pedal(self, limits: Limits) -> Float[Array, " T"]:
        """ℓ(t) ∈ [−1, 1] on the sample grid."""
        t = jnp.arange(limits.num_samples) / limits.rate
        share = jax.nn.softmax(self.pedal_length)
        edges = limits.duration * jnp.concatenate([jnp.zeros(1), jnp.cumsum(share)])
        # Segment m weight: σ((t − e_m)/w) − σ((t − e_{m+1})/w), with the outer edges pushed
        # out so the first and last segments start and end at full weight.
        inner = edges[1:-1]
        w = limits.edge_time / 4.4  # σ rises 10 % → 90 % over 4.4·w = edge_time
        rise = jax.nn.sigmoid((t[None] - inner[:, None]) / w)  # (M−1, T)
        ones, zeros = jnp.ones_like(t)[None], jnp.zeros_like(t)[None]
        up = jnp.concatenate([ones, rise])
        down = jnp.concatenate([rise, zeros])
        return jnp.tanh(self.pedal_level) @ (up - down)

    def inputs(self, limits: Limits) -> Inputs:
        t = jnp.arange(limits.num_samples) / limits.rate
        freq = limits.frequencies(self.steer_freq.shape[0]).from_unbounded(self.steer_freq)
        s = jnp.sum(
            self.steer_amp[:, None] * jnp.sin(2 * jnp.pi * freq[:, None] * t + self.steer_phase[:, None]), 0
        )
        steer = limits.max_steer * jnp.tanh(s)
        lev = self.pedal(limits)
        drive, brake = jax.nn.relu(lev), jax.nn.relu(-lev)
        tf = limits.max_drive * drive - limits.max_brake * limits.brake_front_share * brake
        tr = -limits.max_brake * (1 - limits.brake_front_share) * brake
        return Inputs(0.0, 1.0 / limits.rate, steer, tf, tr)

    def describe(self, limits: Limits) -> dict:
        freq = limits.frequencies(self.steer_freq.shape[0]).from_unbounded(self.steer_freq)
        share = jax.nn.softmax(self.pedal_length)
        return {
            "v0": float(self.initial_speed(limits)),
            "steer_sines": [
                {"amplitude": float(a), "frequency_hz": float(f), "phase_rad": float(p)}
                for a, f, p in zip(self.steer_amp, freq, self.steer_phase)
            ],
            "steer_bound_rad": limits.max_steer,
            "pedal_segments": [
                {"level": float(lv), "length_s": float(s * limits.duration)}
                for lv, s in zip(jnp.tanh(self.pedal_level), share)
            ],
        }
