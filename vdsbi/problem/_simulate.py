"""Simulating a problem's windows: θ in, the compared samples out, for one draw or many."""

from __future__ import annotations

from collections.abc import Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float, PRNGKeyArray

from ..simulator import Inputs, make_model, shard_draws, solve
from ..simulator.measurement import Decimator
from ..simulator.models import VehicleModel, steady_lateral_state
from ..simulator.solvers import Solver
from ._problem import Problem


class WindowedModel(eqx.Module):
    """A problem's W windows as one simulation (one draw; vmap over draws outside).

    Each window starts from the measured speed and yaw rate at its start, with the side speed
    of the linear single-track steady state for that yaw rate under θ: the initial lateral state
    is estimated, not assumed zero, so a window may start mid-corner.

    Attributes:
        model: vehicle model (its longitudinal mode and enabled effects).
        inputs: the windows' inputs, leaves stacked over windows (W, T).
        v0: (W,) initial speeds, m/s.
        r0: (W,) initial yaw rates, rad/s.
        decimator: the filter shared with the measurement, or None.
        channel_index: compared channels' indices in `CHANNELS`.
        solver: integration settings.
    """

    model: VehicleModel
    inputs: Inputs
    v0: Float[Array, " W"]
    r0: Float[Array, " W"]
    decimator: Decimator | None
    channel_index: tuple[int, ...] = eqx.field(static=True)
    solver: Solver = Solver()

    def lateral0(self, theta: Float[Array, "6"]) -> Float[Array, "W 2"]:
        state = lambda v, r: jnp.stack(steady_lateral_state(theta, self.model.vehicle, v, r))
        return jax.vmap(state)(self.v0, self.r0)

    def readings(
        self, theta: Float[Array, "6"], effect_params: tuple = (), v0=None
    ) -> tuple[Float[Array, "W T 6"], Bool[Array, " W"]]:
        """Noise-free model-rate readings of every window, and per-window success flags."""
        v0 = self.v0 if v0 is None else v0
        one = lambda inp, v, lat: solve(self.model, theta, inp, v, effect_params, self.solver, lateral0=lat)
        return jax.vmap(one)(self.inputs, v0, self.lateral0(theta))

    def compare(self, readings: Float[Array, "W T 6"]) -> Float[Array, "W K C"]:
        ys = readings[..., jnp.array(self.channel_index)]
        return ys if self.decimator is None else jax.vmap(self.decimator)(ys)

    def __call__(
        self, theta, effect_params: tuple = (), v0=None
    ) -> tuple[Float[Array, "W K C"], Bool[Array, ""]]:
        ys, ok = self.readings(theta, effect_params, v0)
        return self.compare(ys), jnp.all(ok)

    def noisy(
        self,
        key: PRNGKeyArray,
        theta: Float[Array, "6"],
        sigma_raw: Float[Array, " C"],
        v0_jitter: Float[Array, ""],
        effect_params: tuple = (),
    ) -> tuple[Float[Array, "W K C"], Bool[Array, ""]]:
        """One noisy draw: white sensor noise of std `sigma_raw` at the model rate, then the
        shared filter, so simulated noise is coloured exactly as the measurement's; initial
        speeds jittered uniformly by ± `v0_jitter` (torque mode: v0 is measured, not known)."""
        k_v, k_n = jax.random.split(key)
        v0 = self.v0 + v0_jitter * jax.random.uniform(k_v, self.v0.shape, minval=-1.0, maxval=1.0)
        ys, ok = self.readings(theta, effect_params, v0)
        ys = ys[..., jnp.array(self.channel_index)]
        ys = ys + sigma_raw * jax.random.normal(k_n, ys.shape, ys.dtype)
        ys = ys if self.decimator is None else jax.vmap(self.decimator)(ys)
        return ys, jnp.all(ok) & jnp.all(jnp.isfinite(ys))


def windowed_model(
    problem: Problem,
    effects: Sequence[str] = (),
    solver: Solver = Solver(),
    *,
    model: VehicleModel | None = None,
) -> WindowedModel:
    """The `WindowedModel` of a problem with the named effects enabled, or around `model` (a
    model built elsewhere, e.g. with unregistered effects; `effects` is then ignored)."""
    if model is None:
        model = make_model(problem.vehicle, effects, longitudinal=problem.longitudinal)
    return WindowedModel(
        model=model,
        inputs=problem.inputs(),
        v0=jnp.asarray(problem.v0),
        r0=jnp.asarray(problem.r0),
        decimator=problem.decimator,
        channel_index=problem.channel_index,
        solver=solver,
    )


@eqx.filter_jit
def _noisy_batch(wm, keys, theta, sigma_raw, v0_jitter, effect_params):
    fn = lambda k, th, ep: wm.noisy(k, th, sigma_raw, v0_jitter, ep)
    return jax.vmap(fn)(keys, theta, effect_params)


@eqx.filter_jit
def _clean_batch(wm, theta, effect_params):
    return jax.vmap(lambda th, ep: wm(th, ep))(theta, effect_params)


#: Noise-free batches of fewer draws are padded to this many.
CLEAN_BATCH = 128
#: Bytes of model-rate readings one batched call may hold, counting the copies the noise and
#: the filter make (`_bytes_per_draw`); more draws are simulated in equal chunks. A 100-s drive's
#: 1000 simulations fit in one call; a 10-min drive's then need a few, not 10 GB at once.
BATCH_BYTES = 4 * 2**30


def _bytes_per_draw(wm: WindowedModel) -> int:
    # W·T readings of 6 states in float32, about four live copies of them (the readings, the
    # noise, the filter's input and output).
    return 4 * 6 * 4 * int(wm.inputs.steer.size)


def simulate_draws(
    key: PRNGKeyArray | None,
    wm: WindowedModel,
    theta: Float[Array, "N 6"],
    *,
    sigma_raw: Float[Array, " C"] | None = None,
    v0_jitter: float = 0.0,
    effect_params: tuple = (),
    max_batch: int | None = None,
) -> tuple[Float[Array, "N W K C"], Bool[Array, " N"]]:
    """Many draws at once, vmapped and split over all devices along N (noise-free if `key` is
    None). `effect_params` holds one (N, P_e) array per enabled effect. Failures are flagged.
    More draws than `max_batch` (default: what `BATCH_BYTES` holds) go in equal chunks, with the
    same draws as in one call."""
    theta = jnp.asarray(theta)
    n = theta.shape[0]
    effect_params = tuple(
        jnp.broadcast_to(jnp.asarray(p, theta.dtype), (n, len(e.param_names)))
        for e, p in zip(wm.model.effects, effect_params)
    )
    keys = None if key is None else jax.random.split(key, n)
    most = max(1, BATCH_BYTES // _bytes_per_draw(wm)) if max_batch is None else int(max_batch)
    if max(n, CLEAN_BATCH if key is None else 1) <= most:
        minimum = CLEAN_BATCH if key is None else 1
        return _simulate_batch(keys, wm, theta, sigma_raw, v0_jitter, effect_params, minimum)
    parts = -(-n // most)
    size = -(-n // parts)
    outs = [
        _simulate_batch(
            None if keys is None else keys[i : i + size],
            wm,
            theta[i : i + size],
            sigma_raw,
            v0_jitter,
            tuple(p[i : i + size] for p in effect_params),
            size,
        )
        for i in range(0, n, size)
    ]
    return jnp.concatenate([o[0] for o in outs])[:n], jnp.concatenate([o[1] for o in outs])[:n]


def _simulate_batch(keys, wm, theta, sigma_raw, v0_jitter, effect_params, minimum: int):
    """One vmapped call over the draws, padded to `minimum` (noise-free ones to `CLEAN_BATCH`
    unless chunked: the fit's checks, the validation and the predictive band then share one
    compiled program; chunks to their common size)."""
    n = theta.shape[0]
    if keys is None:
        theta_s, ep_s = shard_draws((theta, effect_params), n, minimum=minimum)
        ys, ok = _clean_batch(wm, theta_s, ep_s)
    else:
        keys_s, theta_s, ep_s = shard_draws((keys, theta, effect_params), n, minimum=minimum)
        sig = jnp.asarray(sigma_raw, theta.dtype)
        ys, ok = _noisy_batch(wm, keys_s, theta_s, sig, jnp.asarray(v0_jitter, theta.dtype), ep_s)
    return ys[:n], ok[:n]
