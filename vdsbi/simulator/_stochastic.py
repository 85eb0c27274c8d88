"""The simulator as SBI sees it: θ in, noisy trajectories out, many draws at once."""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float, PRNGKeyArray

from ._filter import Decimator
from ._inputs import Inputs
from ._model import AbstractVehicleModel
from ._sensors import SensorNoise, StiffnessMixtureNoise
from ._solve import solve_batch
from ._solver import RK4, AbstractSolver
from ._vehicle import CHANNELS


class StochasticSimulator(eqx.Module):
    """p(x | θ): random initial speed, optional process noise, sensor noise.

    Attributes:
        model: vehicle model with its enabled effects.
        inputs: driver inputs (shared by all draws).
        channels: measured channels returned, in this order.
        v0_range: initial speed drawn uniformly from [low, high] m/s (seed: [10, 11]).
        sensor_noise: noise added to the readings.
        process_noise: optional stiffness perturbation (the seed's mixture).
        solver: the integrator.
        decimator: optional anti-alias filter and decimation, applied after the sensor noise
            so that the simulated noise is filtered exactly as the measurement's; the output
            then has `decimator.num_out(T)` samples.
        lateral0: optional initial (Vy m/s, r rad/s), (2,) for all draws or (N, 2) per draw;
            None starts straight. A call's `lateral0` argument overrides it.

    With a `SpeedDriven` model the drawn v0 is unused: Vx follows `inputs.speed`.
    """

    model: AbstractVehicleModel
    inputs: Inputs
    channels: tuple[str, ...] = eqx.field(static=True)
    v0_range: tuple[float, float] = eqx.field(static=True)
    sensor_noise: SensorNoise
    process_noise: StiffnessMixtureNoise | None = None
    solver: AbstractSolver = RK4()
    decimator: Decimator | None = None
    lateral0: Float[Array, "*N 2"] | None = None

    def __check_init__(self):
        bad = [c for c in self.channels if c not in CHANNELS]
        if bad:
            raise ValueError(f"simulator: unknown channel(s) {bad} (known: {CHANNELS})")
        if not self.v0_range[0] <= self.v0_range[1]:
            raise ValueError(f"simulator: v0_range {self.v0_range} needs low <= high")

    @property
    def channel_index(self) -> tuple[int, ...]:
        return tuple(CHANNELS.index(c) for c in self.channels)

    def __call__(
        self,
        key: PRNGKeyArray,
        theta: Float[Array, "N 6"],
        effect_params: tuple = (),
        lateral0: Float[Array, "*N 2"] | None = None,
    ) -> tuple[Float[Array, "N T C"], Bool[Array, " N"]]:
        """N noisy simulations (T is `decimator.num_out` of the input length if decimating).

        Args:
            key: PRNG key, split once here.
            theta: (N, 6) parameters, one row per draw.
            effect_params: one (N, P_e) array per enabled effect.
            lateral0: optional initial (Vy, r), (2,) or (N, 2); overrides the field.

        Returns:
            (N, T, C) readings of `channels`, and the (N,) success mask.
        """
        n = theta.shape[0]
        lateral0 = self.lateral0 if lateral0 is None else lateral0
        k_v, k_p, k_s = jax.random.split(key, 3)
        v0 = jax.random.uniform(
            k_v, (n,), minval=self.v0_range[0], maxval=self.v0_range[1], dtype=theta.dtype
        )
        theta_sim = theta
        if self.process_noise is not None:
            theta_sim = jax.vmap(self.process_noise)(jax.random.split(k_p, n), theta)
        ys, ok = solve_batch(self.model, theta_sim, self.inputs, v0, effect_params, self.solver, lateral0)
        ys = _add_noise(self.sensor_noise, k_s, ys)
        ys = ys[..., jnp.array(self.channel_index)]
        if self.decimator is not None:
            ys = _decimate(self.decimator, ys)
        ok = ok & jnp.all(jnp.isfinite(ys), axis=(1, 2))
        return ys, ok


@eqx.filter_jit
def _add_noise(noise, key, ys):
    return jax.vmap(noise)(jax.random.split(key, ys.shape[0]), ys)


@eqx.filter_jit
def _decimate(decimator, ys):
    return jax.vmap(decimator)(ys)
