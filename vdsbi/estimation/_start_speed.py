"""A torque-driven window's start speed, corrected by the likelihood fit: the window starts from the
measured speed, which carries the speed sensor's error (a wheel radius's, or
`vdsbi.io.estimate_speed`'s from a_y ≈ v·r), and its simulation keeps that offset for the whole
window. The fit corrects each window's start speed under a N(0, `V0_STD`²) prior and
marginalises the corrections out of the covariance. Window w's residual depends on its own
correction only, which makes both the Jacobian (`residual_and_jacobian`) and the
marginalisation (`profiled`) cheap."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from ..problem import Problem
from ..simulator.models import TorqueDriven

#: Prior std of a torque-driven window's start-speed correction, m/s.
V0_STD = 1.0


def corrected_windows(problem: Problem) -> int:
    """How many start speeds the fit corrects: every window's where the torques drive the
    speed, none where the problem follows the measured speed."""
    return len(problem.v0) if issubclass(problem.model_class, TorqueDriven) else 0


def own_columns(jac_v: np.ndarray) -> np.ndarray:
    """(W, K, C) each window's derivative by its own start-speed correction, from the
    (W, K, C, W') Jacobian of all of them (none: zeros)."""
    if jac_v.shape[-1] == 0:
        return np.zeros(jac_v.shape[:-1])
    return np.einsum("wkcw->wkc", jac_v)


def profiled(jac: np.ndarray, jac_v: np.ndarray) -> np.ndarray:
    """(W, K, C, P) Jacobian of the θ coordinates with each window's start-speed correction
    (derivative `jac_v`, (W, K, C), prior precision 1/`V0_STD`²) marginalised: window w's rows
    become J_w − c_w·u_w(u_wᵀJ_w), u_w = j_w/|j_w|, c_w = 1 − √(p/(|j_w|² + p)), so that
    J̃ᵀJ̃ = Σ_w J_wᵀJ_w − J_wᵀj_w j_wᵀJ_w/(|j_w|² + p): the Schur complement of the joint
    information, i.e. the θ block of its inverse. Shape-preserving, so the widening rules read
    it as they read any Jacobian."""
    p = V0_STD**-2
    n2 = np.sum(jac_v**2, axis=(1, 2))
    u = jac_v / np.sqrt(np.maximum(n2, 1e-300))[:, None, None]
    c = 1.0 - np.sqrt(p / (n2 + p))
    along = np.einsum("wkc,wkcp->wp", u, jac)
    return jac - c[:, None, None, None] * u[..., None] * along[:, None, None, :]


def residual_and_jacobian(fn, k: int, p):
    """fn(p) and its Jacobian. Window w's residual depends on its own start-speed correction
    only, so one tangent that moves them all, split by window, gives their W columns: k + 1
    forward tangents instead of k + W (W ≥ 1)."""
    n_v = p.shape[0] - k

    def at(q):
        r = fn(jnp.concatenate([q[:k], p[k:] + q[k:]]))
        return r, r

    jac, r = jax.jacfwd(at, has_aux=True)(jnp.concatenate([p[:k], jnp.zeros(1, p.dtype)]))
    per_window = jac[:, k].reshape(n_v, -1)
    jac_v = (per_window[:, :, None] * jnp.eye(n_v, dtype=p.dtype)[:, None, :]).reshape(-1, n_v)
    return r, jnp.concatenate([jac[:, :k], jac_v], axis=1)
