"""One amortized estimator per platform: trained once on windows simulated with the platform's own
recorded inputs, saved, and answering every later drive's windows in a forward pass; a drive's
windows are combined into its posterior (the proposal that `importance_check` then corrects).

Combining windows: each window's posterior q_w(z), in the prior box's logit coordinates, is
summarised by its mean and covariance; the windows' likelihood factors are Gaussian with precision
Λ_w − Λ₀ (Λ₀ the N(0, π²/3) stand-in for the uniform prior, `PRIOR_Z_STD`), projected onto the
positive semi-definite cone, and multiplied with the prior. The importance check corrects what
this Gaussian product misses.
"""

from __future__ import annotations

import dataclasses
import json
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import PRNGKeyArray

from ..estimation import PRIOR_Z_STD
from ..inference import (
    BoxPrior,
    ChannelStandardization,
    MLPEmbedding,
    NPEConfig,
    Posterior,
    SplineFlowSettings,
    TrainingSettings,
    npe,
)
from ..io import write_text_atomically
from ._platform import Platform
from ._windows import NoiseFamily, WindowPool, simulate_batch

#: Simulations per compiled batch of the training set.
BATCH = 500


@dataclasses.dataclass(frozen=True)
class AmortizedSettings:
    """How a platform's estimator is trained and asked.

    Attributes:
        simulations: windows simulated to train on (θ from the prior box, a window drawn from the
            pool, the noise from `noise`).
        noise: the model-error noise family of the simulated windows.
        training: the flow's training.
        embed_dim: size of the windows' statistics' embedding (an MLP).
        draws_per_window: draws from each window's posterior for its mean and covariance.
        pool_drives: most drives whose windows make the pool (spread over the platform's cars).
    """

    simulations: int = 20_000
    noise: NoiseFamily = NoiseFamily()
    training: TrainingSettings = TrainingSettings(
        batch_size=256, learning_rate=1e-3, max_epochs=100, patience=10, cosine_decay=True
    )
    embed_dim: int = 32
    draws_per_window: int = 400
    pool_drives: int = 40

    def __post_init__(self):
        if self.simulations < 100:
            raise ValueError(f"AmortizedSettings.simulations must be >= 100, got {self.simulations}")

    @property
    def config(self) -> NPEConfig:
        flow = SplineFlowSettings(tail_bound=4.0, x_standardize=ChannelStandardization())
        return NPEConfig(flow=flow, training=self.training)


@dataclasses.dataclass(frozen=True)
class PlatformEstimator:
    """A platform's trained window estimator and what it was trained on.

    Attributes:
        posterior: q(θ | one window's x).
        platform: the platform.
        info: training record (simulations, seconds, epochs, the pool's drives).
    """

    posterior: Posterior
    platform: Platform
    info: dict

    def save(self, folder: Path) -> None:
        """estimator.npz and estimator.json in `folder` (each written atomically; the json last,
        so its presence means the pair is whole)."""
        folder.mkdir(parents=True, exist_ok=True)
        self.posterior.save(folder / "estimator.npz")
        record = {"platform": self.platform.to_dict(), "training": self.info}
        write_text_atomically(folder / "estimator.json", json.dumps(record, indent=2) + "\n")

    @classmethod
    def load(cls, folder: Path, platform: Platform) -> PlatformEstimator:
        record = json.loads((folder / "estimator.json").read_text())
        if record["platform"]["id"] != platform.ident:
            raise ValueError(
                f"{folder}: estimator of platform {record['platform']['id']}, not {platform.ident}"
            )
        return cls(Posterior.load(folder / "estimator.npz"), platform, record["training"])


def train_estimator(
    key: PRNGKeyArray, pool: WindowPool, platform: Platform, settings: AmortizedSettings, *, log=None
) -> PlatformEstimator:
    """Simulate `settings.simulations` windows of `pool` and train q(θ | x) on them (NPE)."""
    say = log or (lambda s: None)
    k_sim, k_emb, k_fit = jax.random.split(key, 3)
    box = platform.box
    prior = BoxPrior(np.asarray(box.low), np.asarray(box.high), names=box.names)
    start = time.perf_counter()
    thetas, xs, dropped = [], [], 0
    for i in range(-(-settings.simulations // BATCH)):
        k_t, k_i, k_n = jax.random.split(jax.random.fold_in(k_sim, i), 3)
        theta = prior.sample(k_t, BATCH).astype(jnp.float32)
        index = jax.random.randint(k_i, (BATCH,), 0, pool.size)
        x, ok = simulate_batch(pool, jax.random.split(k_n, BATCH), theta, index, settings.noise)
        x = np.asarray(x)
        # A window the simulator finished can still give a non-finite statistic (a rare overflow in
        # float32); one such row would make the estimator's standardisation, and so all of it, NaN.
        ok = np.asarray(ok) & np.isfinite(x.reshape(len(x), -1)).all(axis=1)
        dropped += int(np.asarray(ok).size - ok.sum())
        thetas.append(np.asarray(theta)[ok])
        xs.append(x[ok])
    theta, x = np.concatenate(thetas)[: settings.simulations], np.concatenate(xs)[: settings.simulations]
    simulated = time.perf_counter() - start
    say(f"simulated {len(theta)} windows in {simulated:.0f} s; training the platform's estimator")
    embedding = MLPEmbedding(k_emb, x.shape[-1], settings.embed_dim, width=128, depth=2)
    flow, info = npe(k_fit, prior, theta, x, embedding=embedding, config=settings.config)
    seconds = time.perf_counter() - start
    record = {
        "simulations": int(len(theta)),
        "windows_dropped": dropped,
        "windows_in_pool": pool.size,
        "seconds": round(seconds, 1),
        "simulation_seconds": round(simulated, 1),
        "epochs": int(info.get("epochs", 0)) if isinstance(info, dict) else None,
        "best_val_loss": float(info.get("best_val_loss", np.nan)) if isinstance(info, dict) else None,
    }
    return PlatformEstimator(Posterior(flow), platform, record)


@dataclasses.dataclass(frozen=True)
class Proposal:
    """A drive's amortized posterior in the box's logit coordinates: N(mean, cov).

    Attributes:
        mean: (P,) in z.
        cov: (P, P) in z.
        windows: windows combined.
    """

    mean: np.ndarray
    cov: np.ndarray
    windows: int


def drive_proposal(
    key: PRNGKeyArray, estimator: PlatformEstimator, x: np.ndarray, has: np.ndarray, n: int
) -> Proposal:
    """The Gaussian product of the windows' amortized posteriors (module docstring), from `n`
    draws per window of the windows `has` marks."""
    box = estimator.platform.box
    prec0 = np.eye(box.dim) / PRIOR_Z_STD**2
    precision, shift = prec0.copy(), np.zeros(box.dim)
    used = np.flatnonzero(has)
    for i, w in enumerate(used):
        theta = estimator.posterior.sample(jax.random.fold_in(key, i), n, jnp.asarray(x[w]))
        z = np.asarray(jax.vmap(box.to_unbounded)(theta), float)
        lam = np.linalg.inv(np.cov(z, rowvar=False) + 1e-9 * np.eye(box.dim))
        values, vectors = np.linalg.eigh(lam - prec0)
        precision += (vectors * np.maximum(values, 0.0)) @ vectors.T
        shift += lam @ z.mean(0)
    cov = np.linalg.inv(precision)
    return Proposal(cov @ shift, 0.5 * (cov + cov.T), len(used))
