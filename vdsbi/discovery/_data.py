"""What discovery reads off a `vdsbi.problem.Problem` beyond the fit: the inputs at the compared
samples, where each window is held out from, and the held-out scores."""

from __future__ import annotations

import numpy as np

from ..problem import Problem
from ..problem.validation import channel_scores


def compared_inputs(problem: Problem) -> np.ndarray:
    """(W, K, 3) steer and axle torques at the compared samples (for locating a mismatch)."""
    return problem.u[:, :: problem.factor][:, : problem.y.shape[1]]


def held_out_from(problem: Problem) -> list[float]:
    """Per window, the time from which it is held out, s (a held window: its start)."""
    out = []
    for w in problem.windows:
        out.append(w.t0 if w.role == "held" else (w.split if w.split is not None else w.t1))
    return out


def held_out_scores(
    problem: Problem, pred: np.ndarray, var: np.ndarray | None = None, block: int = 0
) -> dict:
    """`vdsbi.problem.validation.channel_scores` of the (W, K, C) prediction `pred` on the held-out
    samples of `problem` (no parameters were fitted on these). With `block` > 0, also each run of
    `block` consecutive held-out samples' χ²/dof (`chi2_blocks`, in the same blocks for every
    channel and every prediction of `problem`: a paired comparison of two fits reads them). With
    `var` (W, K, C), the variance of the prediction that the fit's parameter uncertainty
    carries, also `chi2_dof_predictive`: the squared error over σ² + var, the check of the
    held-out data against the fit's own predictive distribution."""
    out = channel_scores(problem, pred, problem.held)
    m = problem.held
    if block > 0:
        blocks = _blocks(m, block)
        for c, name in enumerate(problem.channels):
            z2 = ((pred[..., c] - problem.y[..., c]) / problem.sigma[c]) ** 2
            out[name]["chi2_blocks"] = [float(np.mean(z2[w, k])) for w, k in blocks]
    if var is not None:
        for c, name in enumerate(problem.channels):
            err = (pred[..., c] - problem.y[..., c])[m]
            out[name]["chi2_dof_predictive"] = float(
                np.mean(err**2 / (problem.sigma[c] ** 2 + var[..., c][m]))
            )
    return out


def _blocks(held: np.ndarray, block: int) -> list[tuple[int, np.ndarray]]:
    """(window, sample indices) of each run of `block` consecutive held-out samples of each window;
    a window's last, shorter run joins the one before it (or stands alone if it is the only one)."""
    out = []
    for w in range(held.shape[0]):
        k = np.flatnonzero(held[w])
        runs = [k[i : i + block] for i in range(0, len(k), block)]
        if len(runs) > 1 and len(runs[-1]) < block:
            last = runs.pop()
            runs[-1] = np.concatenate([runs[-1], last])
        out += [(w, r) for r in runs]
    return out
