"""Observability by autodiff: Fisher information and Cramér–Rao bounds.

Measurement model (the Gaussian approximation the seed uses for its scores): the readings are
x_t = μ_t(θ) + ε_t with ε_t ~ N(0, diag(σ_t²)) independent over samples t, and σ_t evaluated at
the true θ and treated as known. Then

    F = Σ_t J_tᵀ diag(σ_t⁻²) J_t,    J_t = ∂μ_t/∂θ  (from `jax.jacfwd` through the simulator).

With the seed's relative noise (σ = rel·|y|) the variance itself depends on θ; the extra
information that term would carry is an artifact of knowing the noise law exactly and is
deliberately left out (σ is held fixed at its value at θ*), so F is the information in the
mean response only.

Relative noise makes σ vanish where a channel crosses zero, which would mean infinite
information there. `noise_std` floors the relative part at `floor_fraction · rel · RMS(channel)`
(default 0.1: one tenth of the channel's typical noise level over the maneuver).

Everything is computed in a scaled parametrisation z = θ / scale (scale = the Table I nominal
values for the six vehicle parameters, and max(|value|, half the typical range) for effect
parameters), so eigenvalues are dimensionless and comparable; bounds are reported in
physical units.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence
from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float, Int, PRNGKeyArray

from ..problem import parameter_names
from ..simulator import CHANNELS, NOMINAL_THETA, PARAM_NAMES, SEED_CHANNELS, Inputs, solve
from ..simulator.measurement import SensorNoise
from ..simulator.models import AbstractVehicleModel
from ..simulator.solvers import RK4, AbstractSolver

#: Default relative floor on the relative-noise std (see module docstring).
FLOOR_FRACTION = 0.1
#: Numerical-rank rule: eigenvalues of the scaled F below this fraction of the largest are
#: treated as zero. F is assembled in float64 from a Jacobian accurate to ~1e-10 relative (it
#: matches central finite differences to 1e-6 or better in the tests), so 1e-9 sits above
#: round-off and far below any information a sensor provides.
RANK_RTOL = 1e-9
#: Practical identifiability: an eigen-direction counts as identified if its Cramér–Rao std,
#: in scaled units (fractions of the nominal value), is at most this.
MAX_RELATIVE_STD = 0.5


# --------------------------------------------------------------------------- core


def fisher_from_jacobian(jac: Float[Array, "T C P"], std: Float[Array, "T C"]) -> Float[Array, "P P"]:
    """F = Σ_t J_tᵀ diag(σ_t⁻²) J_t for independent Gaussian noise.

    Args:
        jac: ∂μ/∂θ, (T, C, P).
        std: noise std per sample and channel, (T, C), in channel units, > 0.
    """
    w = jac / std[..., None]
    return jnp.einsum("tcp,tcq->pq", w, w)


def fisher_information(
    mean_fn: Callable[[Float[Array, " P"]], Float[Array, "T C"]],
    params: Float[Array, " P"],
    std: Float[Array, "T C"],
) -> Float[Array, "P P"]:
    """Fisher information of `params` for x ~ N(mean_fn(params), diag(std²)).

    Args:
        mean_fn: noise-free model output for one parameter vector, (T, C).
        params: where to evaluate, (P,).
        std: noise std, (T, C), held fixed.
    """
    return fisher_from_jacobian(jax.jacfwd(mean_fn)(params), std)


def noise_std(
    ys: Float[Array, "T C"],
    relative: Float[Array, " C"],
    additive: Float[Array, " C"],
    floor_fraction: float = FLOOR_FRACTION,
) -> Float[Array, "T C"]:
    """σ = max(rel·|y|, floor_fraction·rel·RMS(y)) + additive, per sample and channel.

    Args:
        ys: noise-free readings, (T, C).
        relative: relative std per channel, (C,).
        additive: additive std per channel, (C,), channel units.
        floor_fraction: floor of the relative part as a fraction of its channel RMS level.
    """
    rms = jnp.sqrt(jnp.mean(ys**2, axis=0))
    rel = jnp.maximum(relative * jnp.abs(ys), floor_fraction * relative * rms)
    return rel + additive


def score_fisher_mc(
    key: PRNGKeyArray,
    jac: Float[Array, "T C P"],
    std: Float[Array, "T C"],
    num_samples: int,
    chunk: int = 256,
) -> Float[Array, "P P"]:
    """The seed's estimator: covariance of simulated scores under the Gaussian approximation.

    Draws x = μ + σ·ε at θ*, forms the score s = Jᵀ diag(σ⁻²)(x − μ) (the gradient of the
    Gaussian log-likelihood at θ*) and returns the mean of s sᵀ (E[s] = 0). Unbiased for F;
    its error falls as 1/√num_samples.

    Args:
        key: PRNG key.
        jac: (T, C, P) at θ*.
        std: (T, C) noise std used both to simulate and to score.
        num_samples: number of simulated data sets (rounded up to a multiple of `chunk`).
        chunk: data sets scored per scan step (bounds memory).
    """
    chunk = max(1, min(chunk, num_samples))
    n_chunks = -(-num_samples // chunk)
    w = jac / std[..., None]  # score = Σ_tc w_tcp · ε_tc

    def body(acc, k):
        eps = jax.random.normal(k, (chunk, *std.shape), dtype=jac.dtype)
        s = jnp.einsum("ntc,tcp->np", eps, w)
        return acc + s.T @ s, None

    acc, _ = jax.lax.scan(body, jnp.zeros((jac.shape[-1],) * 2, jac.dtype), jax.random.split(key, n_chunks))
    return acc / (n_chunks * chunk)


# --------------------------------------------------------------------------- vehicle model


def param_names(model: AbstractVehicleModel) -> tuple[str, ...]:
    """θ names then `effect.param` for every enabled effect, in the flat-vector order."""
    return parameter_names(model.effects)


def param_scale(model: AbstractVehicleModel, values: Float[Array, " P"]) -> np.ndarray:
    """Scale of the flat parameter vector: Table I nominal for θ; for an effect parameter
    max(|value|, half its typical range), so a null (zero) value still has a unit."""
    scale = [NOMINAL_THETA[n] for n in PARAM_NAMES]
    values = np.asarray(values, dtype=float)
    i = len(PARAM_NAMES)
    for e in model.effects:
        for lo_hi in e.typical:
            half = 0.5 * (lo_hi[1] - lo_hi[0])
            scale.append(max(abs(values[i]), half, 1e-12))
            i += 1
    return np.asarray(scale, dtype=float)


def _split(model: AbstractVehicleModel, flat):
    theta = flat[: len(PARAM_NAMES)]
    out, i = [], len(PARAM_NAMES)
    for e in model.effects:
        n = len(e.param_names)
        out.append(flat[i : i + n])
        i += n
    return theta, tuple(out)


def channel_noise(noise: SensorNoise | None, channels: Sequence[str]) -> tuple[np.ndarray, np.ndarray]:
    """(relative, additive) stds of `noise` (None: `SensorNoise.seed()`) for `channels`. A channel
    with zero noise in both is rejected: it would carry infinite information."""
    noise = SensorNoise.seed() if noise is None else noise
    idx = [CHANNELS.index(c) for c in channels]
    rel, add = np.asarray(noise.relative, float)[idx], np.asarray(noise.additive, float)[idx]
    silent = [c for c, r, s in zip(channels, rel, add) if not (r > 0 or s > 0)]
    if silent:
        raise ValueError(
            f"noise: no noise on channel(s) {silent} (they would carry infinite information); "
            "give them a noise_std in vehicle.json or leave them out of the channels"
        )
    return rel, add


class Fisher(eqx.Module):
    """Fisher information of one maneuver at one operating point.

    Attributes:
        names: parameter names (θ, then `effect.param`), static.
        channels: channels the information comes from, static.
        values: parameter values where F was evaluated, physical units, (P,).
        scale: the scaling z = θ/scale, (P,).
        fim_scaled: F in scaled units (information about z), (P, P).
        readings: noise-free readings of the used channels, (T, C).
        std: noise std used, (T, C).
        jac: ∂readings/∂z in scaled units, (T, C, P).
    """

    names: tuple[str, ...] = eqx.field(static=True)
    channels: tuple[str, ...] = eqx.field(static=True)
    values: Float[Array, " P"]
    scale: Float[Array, " P"]
    fim_scaled: Float[Array, "P P"]
    readings: Float[Array, "T C"]
    std: Float[Array, "T C"]
    jac: Float[Array, "T C P"]

    @property
    def fim(self) -> Float[Array, "P P"]:
        """F in physical units: F_θ = D⁻¹ F_z D⁻¹, D = diag(scale)."""
        return self.fim_scaled / jnp.outer(self.scale, self.scale)

    def crb_std(self) -> Float[Array, " P"]:
        """Cramér–Rao bound (std, physical units) of each parameter, all others unknown."""
        return self.scale * jnp.sqrt(jnp.diag(_inv_psd(self.fim_scaled)))


def _inv_psd(a):
    w, v = jnp.linalg.eigh(a)
    w = jnp.where(w > RANK_RTOL * w[-1], w, jnp.inf)
    return (v / w) @ v.T


@dataclasses.dataclass(frozen=True, kw_only=True)
class MeasurementModel:
    """What `model_fisher` measures the maneuver through: the channels and their noise.

    Attributes:
        channels: measured channels (CHANNELS names).
        noise: the sensor noise (None: the seed's relative noise, `SensorNoise.seed`).
        floor_fraction: floor of the relative noise as a fraction of its channel's RMS level
            (see `noise_std`).
    """

    channels: Sequence[str] = SEED_CHANNELS
    noise: SensorNoise | None = None
    floor_fraction: float = FLOOR_FRACTION


def model_fisher(
    model: AbstractVehicleModel,
    theta: Float[Array, "6"],
    inputs: Inputs,
    v0: float,
    effect_params: tuple = (),
    *,
    measurement: MeasurementModel = MeasurementModel(),
    solver: AbstractSolver = RK4(),
) -> Fisher:
    """Fisher information of θ and the enabled effects' parameters for one maneuver.

    Run it under `jax.enable_x64(True)`; it warns nothing but float32 loses ~4 digits of F.

    Args:
        model: vehicle model (its effects' parameters join θ).
        theta: (6,) in PARAM_NAMES order, physical units.
        inputs: the maneuver.
        v0: initial speed, m/s.
        effect_params: one (P_e,) vector per enabled effect.
        measurement: the measured channels, their noise and its floor (`MeasurementModel`).
        solver: integration settings.
    """
    channels, floor_fraction = measurement.channels, measurement.floor_fraction
    idx = jnp.asarray([CHANNELS.index(c) for c in channels])
    rel, add = channel_noise(measurement.noise, channels)
    flat = jnp.concatenate(
        [jnp.asarray(theta, dtype=float)] + [jnp.asarray(p, dtype=float) for p in effect_params]
    )
    scale = jnp.asarray(param_scale(model, flat))
    fisher_z, ys, std, jac = _model_fisher_scaled(
        model,
        flat / scale,
        scale,
        inputs,
        jnp.asarray(v0, dtype=float),
        MeasuredNoise(idx, jnp.asarray(rel), jnp.asarray(add), floor_fraction),
        solver,
    )
    return Fisher(
        names=param_names(model),
        channels=tuple(channels),
        values=flat,
        scale=scale,
        fim_scaled=fisher_z,
        readings=ys,
        std=std,
        jac=jac,
    )


def scaled_mean_fn(model, scale, inputs, v0, idx, solver=RK4()):
    """z ↦ noise-free readings (T, C) of the channels `idx`, with θ = z·scale."""

    def mean(z):
        theta, eps = _split(model, z * scale)
        ys, _ = solve(model, theta, inputs, v0, eps, solver)
        return ys[:, idx]

    return mean


class ScaledFisher(NamedTuple):
    """Fisher information of z = θ/scale and what it was assembled from.

    Attributes:
        fim: (P, P) F in scaled units.
        readings: (T, 6) noise-free readings, all channels.
        ok: the solve's success flag.
        std: (T, C) noise std of the used channels.
        jac: (T, C, P) ∂readings/∂z of the used channels.
    """

    fim: Float[Array, "P P"]
    readings: Float[Array, "T 6"]
    ok: Bool[Array, ""]
    std: Float[Array, "T C"]
    jac: Float[Array, "T C P"]


class MeasuredNoise(eqx.Module):
    """The measured channels and their noise model (see `noise_std`).

    Attributes:
        idx: indices of the measured channels in CHANNELS.
        relative, additive: noise std per measured channel.
        floor_fraction: relative-noise floor.
    """

    idx: Int[Array, " C"]
    relative: Float[Array, " C"]
    additive: Float[Array, " C"]
    floor_fraction: float = eqx.field(static=True, default=FLOOR_FRACTION)


def scaled_fisher(
    model: AbstractVehicleModel,
    z: Float[Array, " P"],
    scale: Float[Array, " P"],
    inputs: Inputs,
    v0: Float[Array, ""],
    noise: MeasuredNoise,
    solver: AbstractSolver = RK4(),
) -> ScaledFisher:
    """F of the flat parameters (θ, then the model's effects') in scaled units, from one
    forward-mode pass through `solve`: the Fisher assembly behind `model_fisher` and the
    excitation-design objective. Traceable (differentiable in `inputs` and `v0`).

    Args:
        model: vehicle model.
        z: (P,) parameters over `scale`.
        scale: (P,) scaling, physical units.
        inputs: the maneuver.
        v0: initial speed, m/s.
        noise: the measured channels and their noise.
        solver: integration settings.
    """
    idx = noise.idx

    def run(z_):
        theta, eps = _split(model, z_ * scale)
        ys, ok = solve(model, theta, inputs, v0, eps, solver)
        return ys[:, idx], (ys, ok)

    jac, (ys, ok) = jax.jacfwd(run, has_aux=True)(z)
    std = noise_std(ys[:, idx], noise.relative, noise.additive, noise.floor_fraction)
    return ScaledFisher(fisher_from_jacobian(jac, std), ys, ok, std, jac)


@eqx.filter_jit
def _model_fisher_scaled(model, z, scale, inputs, v0, noise: MeasuredNoise, solver):
    f = scaled_fisher(model, z, scale, inputs, v0, noise, solver)
    return f.fim, f.readings[:, noise.idx], f.std, f.jac
