"""Where a likelihood fit starts: the prior's mode, the best of several candidate points, and
the parameters the drive's channels depend on there."""

from __future__ import annotations

from collections.abc import Sequence

import jax
import jax.numpy as jnp
import numpy as np

from ..problem import Box, Problem, simulate_draws
from ..problem.points import split_parameters
from ..simulator import PARAM_NAMES

#: The prior's mode stays this far inside the box (a share of its width), so its logit is finite.
MODE_MARGIN = 0.05


def prior_mean(box: Box, effects: Sequence) -> np.ndarray:
    """(P,) the prior's mode in logit coordinates: θ at its box's centre; an effect's parameter
    at the effect's `start` (what a car has unless the drive says otherwise: friction factors of
    1, little downforce), moved `MODE_MARGIN` inside the box where the box excludes it (a grip
    floor, a range a diagnosis measured): the least effect the box allows. A parameter the drive
    does not inform then stays where the car most likely is, not at the middle of what any car
    could have."""
    starts = np.concatenate(
        [np.full(len(PARAM_NAMES), np.nan), *[np.asarray(e.start, float) for e in effects]]
    )
    if len(starts) != len(box.names):
        raise ValueError(f"{len(starts)} starts for a box over {len(box.names)} parameters")
    low, width = np.asarray(box.low, float), np.asarray(box.width, float)
    u = np.where(np.isfinite(starts), np.clip((starts - low) / width, MODE_MARGIN, 1.0 - MODE_MARGIN), 0.5)
    return np.asarray(box.to_unbounded(low + u * width), float)


#: Step, in logit coordinates, of the test for which parameters the channels depend on.
INFORMED_STEP = 0.1


def informed_parameters(wm, data: Problem, box: Box, z0: np.ndarray, effects, batch: int) -> tuple[str, ...]:
    """Parameters the compared channels depend on at z0 (C_κ without torques: none): those whose
    logit step of `INFORMED_STEP` changes a valid sample. One batch of `batch` (or more) draws, so
    that the program `best_start` compiled for its candidates serves it."""
    steps = z0 + INFORMED_STEP * np.eye(len(z0))
    draws = np.concatenate([z0[None], steps, np.repeat(z0[None], max(0, batch - len(z0) - 1), 0)])
    theta, effect_params = split_parameters(jax.vmap(box.from_unbounded)(jnp.asarray(draws)), effects)
    pred, ok = simulate_draws(None, wm, theta, effect_params=effect_params)
    pred, ok = np.asarray(pred)[: len(z0) + 1], np.asarray(ok)[: len(z0) + 1]
    valid = np.asarray(data.valid)[..., None]
    moved = [
        not (ok[0] and ok[i + 1]) or np.any(np.where(valid, pred[i + 1] != pred[0], False))
        for i in range(len(z0))
    ]
    return tuple(n for n, m in zip(box.names, moved) if m)


def best_start(wm, data: Problem, mask, starts: np.ndarray, effects, scale: np.ndarray) -> np.ndarray:
    """The candidate with the least scaled squared misfit (a failed simulation is infinitely bad)."""
    if len(starts) == 1:
        return starts[0]
    theta, effect_params = split_parameters(jnp.asarray(starts), effects)
    pred, ok = simulate_draws(None, wm, theta, effect_params=effect_params)
    err = np.where(mask[..., None], (np.asarray(pred) - data.y) / scale, 0.0)
    cost = np.where(np.asarray(ok), np.sum(err**2, axis=(1, 2, 3)), np.inf)
    return starts[int(np.argmin(np.nan_to_num(cost, nan=np.inf)))]
