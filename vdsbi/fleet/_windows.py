"""A platform's pool of recorded windows, what the amortized estimator sees of one window, and
simulated windows driven by the pool's recorded inputs with the model-error noise family.

The estimator answers one window at a time, from statistics that relate the window's response to
its own inputs, so that one estimator serves windows of any drive, of any length up to the fixed
one, at any place in a drive: per channel, the least-squares coefficients of an ARX model (the
channel on its two previous samples and on the steer at `LAGS` lags times the speed and the
speed squared, the steady-state gains of yaw rate and lateral acceleration in the single-track
model), its residual's log-RMS and the two static gains; then the window's mean speed, steer
spread and length. Speed-driven drives only: the regressors need the measured speed.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float, PRNGKeyArray

from ..inference import input_channels
from ..problem import Problem, windowed_model
from ..problem.points import split_parameters
from ..simulator import solve
from ..simulator.models import steady_lateral_state


@dataclasses.dataclass(frozen=True)
class NoiseFamily:
    """The noise added to simulated windows: per channel, an AR(1) process of integrated
    autocorrelation time τ (compared samples) and std m·σ (σ the window's sensor noise after the
    filter), m and τ log-uniform per draw and channel. This is the family the likelihood fit's
    model-error noise model measures on real drives (`vdsbi.estimation.NoiseModel`: a scale above
    the sensor's, coloured), so the estimator has seen residuals like a real drive's.

    Attributes:
        scale: (low, high) of m.
        tau: (low, high) of τ.
    """

    scale: tuple[float, float] = (1.0, 6.0)
    tau: tuple[float, float] = (1.0, 8.0)

    def __post_init__(self):
        for name, (lo, hi) in (("scale", self.scale), ("tau", self.tau)):
            if not 0 < lo <= hi:
                raise ValueError(f"NoiseFamily.{name} must be 0 < low <= high, got {(lo, hi)}")
        if self.tau[0] < 1.0:
            raise ValueError(f"NoiseFamily.tau must be >= 1 (white), got {self.tau}")


#: Steer lags of the ARX regressors (compared samples: 0–0.32 s at 25 Hz, past the slowest
#: steer lag the signal_delay prior allows to show in the coefficients' shape).
LAGS = 9
#: Reference steer (rad) and speed (m/s) the regressors are scaled by.
STEER_REF, SPEED_REF = 0.05, 15.0


def window_inputs(problem: Problem) -> np.ndarray:
    """(W, K, 2) steer and measured speed at the compared samples, filtered like the channels."""
    return np.asarray(input_channels(problem), np.float32)


def _shift(a: Float[Array, " K"], j: int) -> Float[Array, " K"]:
    return a if j == 0 else jnp.concatenate([jnp.zeros((j,), a.dtype), a[:-j]])


def _solve(g: Float[Array, "n n"], b: Float[Array, " n"]) -> Float[Array, " n"]:
    """x with g·x = b for a small g: Gaussian elimination with partial pivoting, written out.

    Not `jnp.linalg.solve`: vmapped, that is jaxlib's batched CPU LU, which hands its batch to
    the thread pool it is itself running on and waits, so a worker with one XLA thread (a fleet
    worker) can hang for ever in it. Pivoting as LAPACK's getrf does keeps it as robust on a
    nearly singular g."""
    n = g.shape[0]
    a = jnp.concatenate([g, b[:, None]], axis=1)
    rows = jnp.arange(n)
    for j in range(n):
        p = jnp.argmax(jnp.where(rows >= j, jnp.abs(a[:, j]), -1.0))
        swapped = jnp.where((rows == j)[:, None], a[p], jnp.where((rows == p)[:, None], a[j], a))
        factor = jnp.where(rows > j, swapped[:, j] / swapped[j, j], 0.0)
        a = swapped - factor[:, None] * swapped[j][None, :]
    x = jnp.zeros_like(b)
    for i in reversed(range(n)):
        x = x.at[i].set((a[i, n] - a[i, i + 1 : n] @ x[i + 1 :]) / a[i, i])
    return x


def window_x(y: Float[Array, "K C"], u: Float[Array, "K 2"], mask: Bool[Array, " K"]) -> Float[Array, " F"]:
    """One window's statistics (module docstring); samples outside `mask` never enter."""
    d, v = u[:, 0] / STEER_REF, u[:, 1] / SPEED_REF
    ok = mask
    for j in range(1, LAGS):
        ok = ok & _shift(mask, j)
    m = ok.astype(y.dtype)
    n = jnp.maximum(m.sum(), 1.0)
    excitation = [_shift(d, j) * v**p for p in (1, 2) for j in range(LAGS)]
    feats = []
    for c in range(y.shape[1]):
        yc = y[:, c]
        a = jnp.stack([_shift(yc, 1), _shift(yc, 2), *excitation], axis=1)
        gram = a.T @ (a * m[:, None])
        ridge = 1e-6 * jnp.trace(gram) / a.shape[1] + 1e-12
        coef = _solve(gram + ridge * jnp.eye(a.shape[1]), a.T @ (yc * m))
        resid = (yc - a @ coef) * m
        gains = [jnp.sum(yc * e * m) / (jnp.sum(e * e * m) + 1e-9) for e in (d * v, d * v**2)]
        feats += [coef, jnp.stack([0.5 * jnp.log(jnp.sum(resid**2) / n + 1e-12), *gains])]
    mean_v = jnp.sum(v * m) / n
    spread = jnp.sqrt(jnp.sum((d - jnp.sum(d * m) / n) ** 2 * m) / n)
    feats.append(jnp.stack([mean_v, jnp.log(spread + 1e-6), jnp.log(n)]))
    return jnp.concatenate(feats)


#: `window_x` over a drive's windows, jitted once at module level: a worker compiles it once per
#: padded shape, not once per drive (a jit of a fresh `vmap` is a new function each time).
_windows_x = jax.jit(jax.vmap(window_x))


def drive_x(problem: Problem) -> tuple[np.ndarray, np.ndarray]:
    """(W, F) statistics of a drive's windows and (W,) whether each has a fitted sample."""
    y = jnp.asarray(problem.y, jnp.float32)
    u = jnp.asarray(window_inputs(problem))
    mask = jnp.asarray(problem.train)
    return np.asarray(_windows_x(y, u, mask)), np.asarray(problem.train.any(1))


class WindowPool(eqx.Module):
    """Recorded windows of a platform's drives, each simulated from its own start.

    Attributes:
        wm: the pooled windows' model (`vdsbi.problem.WindowedModel`).
        u: (W, K, 2) their steer and speed as the estimator sees them.
        mask: (W, K) their fitted samples.
        sigma: (W, C) their sensor noise after the filter.
        effects: the enabled effects (their parameters follow θ).
    """

    wm: eqx.Module
    u: Float[Array, "W K I"]
    mask: Bool[Array, "W K"]
    sigma: Float[Array, "W C"]
    effects: tuple[str, ...] = eqx.field(static=True)

    @property
    def size(self) -> int:
        return int(self.mask.shape[0])

    def simulate(
        self, key: PRNGKeyArray, theta: Float[Array, " P"], index, noise: NoiseFamily
    ) -> tuple[Float[Array, " F"], Bool[Array, ""]]:
        """One draw: window `index` simulated at θ (and effect parameters) with noise from
        `noise`; its observation and whether the simulation stayed in the model's domain."""
        wm = self.wm
        th, ep = split_parameters(theta, self.effects)
        inputs = jax.tree.map(lambda a: a[index], wm.inputs)
        v0, r0 = wm.v0[index], wm.r0[index]
        lateral0 = jnp.stack(steady_lateral_state(th, wm.model.vehicle, v0, r0))
        ys, ok = solve(wm.model, th, inputs, v0, ep, wm.solver, lateral0=lateral0)
        y = wm.compare(ys[None])[0]
        y = y + self.sigma[index] * _coloured(key, y.shape, noise)
        return window_x(y, self.u[index], self.mask[index]), ok & jnp.all(jnp.isfinite(y))


def _coloured(key: PRNGKeyArray, shape: tuple[int, int], noise: NoiseFamily) -> Float[Array, "K C"]:
    """Unit-σ AR(1) noise per channel times the draw's scale m (log-uniform), each channel's τ
    (log-uniform) giving its coefficient φ = (τ − 1)/(τ + 1)."""
    k_m, k_t, k_e = jax.random.split(key, 3)
    c = shape[1]
    log_u = lambda k, lo, hi: jnp.exp(jax.random.uniform(k, (c,), minval=jnp.log(lo), maxval=jnp.log(hi)))
    m, tau = log_u(k_m, *noise.scale), log_u(k_t, *noise.tau)
    phi = (tau - 1.0) / (tau + 1.0)
    eps = jax.random.normal(k_e, shape)

    def step(prev, e):
        now = phi * prev + jnp.sqrt(1.0 - phi**2) * e
        return now, now

    _, series = jax.lax.scan(step, eps[0], eps[1:])
    return m * jnp.concatenate([eps[:1], series])


def window_pool(problems: Sequence[Problem], effects: Sequence[str]) -> WindowPool:
    """The windows holding fitted samples of `problems` (already on one fixed shape) as one pool."""
    keep = [np.flatnonzero(p.train.any(1)) for p in problems]
    parts = [dataclasses.replace(p, windows=tuple(p.windows[i] for i in k)) for p, k in zip(problems, keep)]
    cut = lambda a, k: None if a is None else a[k]
    joined = dataclasses.replace(
        problems[0],
        windows=tuple(w for p in parts for w in p.windows),
        **{
            name: None
            if getattr(problems[0], name) is None
            else np.concatenate([cut(getattr(p, name), k) for p, k in zip(problems, keep)])
            for name in ("t", "u", "speed", "accel", "t_out", "y", "valid", "train", "held", "v0", "r0")
        },
    )
    sigma = np.concatenate([np.repeat(np.asarray(p.sigma)[None], len(k), 0) for p, k in zip(problems, keep)])
    return WindowPool(
        windowed_model(joined, effects),
        jnp.asarray(window_inputs(joined)),
        jnp.asarray(joined.train),
        jnp.asarray(sigma, jnp.float32),
        tuple(effects),
    )


@eqx.filter_jit
def simulate_batch(pool: WindowPool, keys, theta, index, noise: NoiseFamily):
    """`WindowPool.simulate` vmapped over draws (one compiled program per batch size)."""
    return jax.vmap(lambda k, th, i: pool.simulate(k, th, i, noise))(keys, theta, index)
