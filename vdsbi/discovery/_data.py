"""What discovery fits, from a `vdsbi.problem.Problem`: the fit's data and the compared grid."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from ..problem import Problem
from ..simulator import CHANNELS
from ._fit import FitData


def fit_data(problem: Problem, part: str = "train", *, truncate: bool = True) -> FitData:
    """`FitData` whose mask is `part` ("train", "held" or "valid") of `problem`.

    With `truncate`, every window is cut after the last masked sample of any window (the
    simulation need not run past it); all windows are kept, so window indices stay those of
    `problem`.
    """
    mask = problem.part(part)
    k_end = int(np.max(np.nonzero(mask.any(0))[0])) + 1 if truncate else mask.shape[1]
    n_end = problem.model_samples(k_end) if truncate else problem.t.shape[1]
    inputs = jax.tree.map(lambda a: a[:, :n_end] if a.ndim == 2 else a, problem.inputs())
    return FitData(
        inputs=inputs,
        measured=jnp.asarray(problem.y[:, :k_end]),
        sigma=jnp.asarray(problem.sigma),
        mask=jnp.asarray(mask[:, :k_end].astype(float)),
        v0_meas=jnp.asarray(problem.v0),
        r0=jnp.asarray(problem.r0),
        decimator=problem.decimator,
        channel_index=problem.channel_index,
        channels=problem.channels,
        longitudinal=problem.longitudinal,
    )


def compared_inputs(problem: Problem) -> np.ndarray:
    """(W, K, 3) steer and axle torques at the compared samples (for locating a mismatch)."""
    return problem.u[:, :: problem.factor][:, : problem.y.shape[1]]


def held_out_from(problem: Problem) -> list[float]:
    """Per window, the time from which it is held out, s (a held window: its start)."""
    out = []
    for w in problem.windows:
        out.append(w.t0 if w.role == "held" else (w.split if w.split is not None else w.t1))
    return out


def held_out_metrics(pred: np.ndarray, windows: Problem, var: np.ndarray | None = None) -> dict:
    """Per channel on the held-out samples: NRMSE (RMS error / std of the measurement) and
    χ²/dof (mean squared whitened error; no parameters were fitted on these samples). With
    `var` (W, T, 6), the variance of the prediction that the fit's parameter uncertainty
    carries, also `chi2_dof_predictive`: the squared error over σ² + var, the check of the
    held-out data against the fit's own predictive distribution."""
    out = {}
    m = windows.held
    for c, name in enumerate(windows.channels):
        k = CHANNELS.index(name)
        e = (pred[:, :, k] - windows.y[:, :, c])[m]
        y = windows.y[:, :, c][m]
        out[name] = {
            "nrmse": float(np.sqrt(np.mean(e**2)) / (np.std(y) + 1e-12)),
            "chi2_dof": float(np.mean((e / windows.sigma[c]) ** 2)),
        }
        if var is not None:
            total = windows.sigma[c] ** 2 + var[:, :, k][m]
            out[name]["chi2_dof_predictive"] = float(np.mean(e**2 / total))
    return out
