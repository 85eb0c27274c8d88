"""Identifying θ by APT on a whole `Problem`: every training window of a drive, jointly."""

from __future__ import annotations

from collections.abc import Sequence

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, PRNGKeyArray

from ..problem import Problem, simulate_draws, windowed_model
from ..problem.points import split_parameters
from ..simulator.models import SpeedDriven
from ..simulator.solvers import Solver
from ._apt import Execution
from ._apt_state import APTState
from ._posterior import Posterior
from ._prior import BoxPrior
from ._vehicle import IdentifySettings, fit_posterior


def input_channels(problem: Problem) -> Float[Array, "W K I"]:
    """What drives each window, on the compared samples: steer and the torques (torque mode)
    or steer and the measured speed (speed mode), filtered like the measurement."""
    if issubclass(problem.model_class, SpeedDriven):
        u = jnp.stack([jnp.asarray(problem.u[..., 0]), jnp.asarray(problem.speed)], axis=-1)
    else:
        u = jnp.asarray(problem.u)
    if problem.decimator is not None:
        u = jax.vmap(problem.decimator)(u)
    return u


def flatten_windows(ys: Float[Array, "N W K C"], mask: np.ndarray) -> Float[Array, "N L C"]:
    """Concatenate the windows along time, zeroing samples outside `mask` (fixed shapes)."""
    ys = jnp.where(jnp.asarray(mask)[None, :, :, None], ys, 0.0)
    return ys.reshape(ys.shape[0], -1, ys.shape[-1])


def identify_problem(
    key: PRNGKeyArray,
    problem: Problem,
    prior: BoxPrior,
    settings: IdentifySettings = IdentifySettings(),
    *,
    effects: Sequence[str] = (),
    solver: Solver = Solver(),
    execution: Execution = Execution(),
) -> tuple[Posterior, np.ndarray, APTState]:
    """Posterior over θ from the training part of `problem` (all its windows at once).

    With `effects`, their parameters join θ (after the six, in `parameter_names` order) and
    `prior` must span them too. `execution` holds the progress and checkpoint callbacks, a
    checkpoint to resume from and the device mesh (see `Execution`).

    Simulated draws get white sensor noise at the model rate and then the problem's filter,
    as the measurement does; in torque mode each window's initial speed is jittered by the
    uncertainty of its measured value. The held-out part is not seen.

    Returns:
        (posterior at the observation, (num_samples, 6 + P) samples, final APT state).
    """
    train = problem.select("train")
    wm = windowed_model(train, effects, solver)
    mask = train.train
    u = flatten_windows(input_channels(train)[None], mask)[0].astype(jnp.float32)
    to_x = jax.jit(jax.vmap(lambda r: settings.embedding(r, u)))
    x_o = to_x(flatten_windows(jnp.asarray(train.y)[None], mask).astype(jnp.float32))[0]
    jitter = 0.0 if issubclass(train.model_class, SpeedDriven) else 0.2 + 0.02 * float(np.mean(train.v0))

    def simulate(k, theta):
        th, ep = split_parameters(theta, effects)
        ys, ok = simulate_draws(k, wm, th, sigma_raw=train.sigma_raw, v0_jitter=jitter, effect_params=ep)
        return to_x(flatten_windows(ys, mask).astype(jnp.float32)), ok

    return fit_posterior(key, simulate, prior, x_o, settings, execution=execution)
