"""A window's start, corrected by the likelihood fit: each window starts from the measured (smoothed)
yaw rate with the steady side speed for it, and a torque-driven one from the measured speed; the
fit corrects each start with Gaussian priors (`START_STD`) and marginalises the corrections out of
the covariance. Window w's residual depends on its own corrections only, which makes both the
Jacobian (`residual_and_jacobian`) and the marginalisation (`profiled`) cheap."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from ..problem import Problem
from ..simulator import TorqueDriven

#: Prior std of each window's start corrections: speed (torque-driven windows), m/s; side
#: speed, m/s; yaw rate, rad/s.
START_STD = {"v0": 1.0, "vy0": 0.5, "r0": 0.05}


def start_kinds(problem: Problem) -> tuple[str, ...]:
    """The start corrections a problem's windows get (`START_STD`'s names): the speed only where
    it is simulated from the torques."""
    lateral = ("vy0", "r0")
    return ("v0", *lateral) if issubclass(problem.model_class, TorqueDriven) else lateral


def own_columns(jac_s: np.ndarray, m: int) -> np.ndarray:
    """(W, K, C, m) each window's derivatives by its own m start corrections, from the
    (W, K, C, W·m) Jacobian of all of them."""
    return np.einsum("wkcwm->wkcm", jac_s.reshape(*jac_s.shape[:-1], -1, m))


def profiled(jac: np.ndarray, jac_s: np.ndarray, prior_std: np.ndarray) -> np.ndarray:
    """(W, K, C, P) Jacobian of the θ coordinates with each window's start corrections
    (derivatives `jac_s`, (W, K, C, m), Gaussian priors of std `prior_std`) marginalised.

    With A_w = j_w·diag(prior_std) = U S Vᵀ (thin SVD), window w's rows become
    J_w − U·diag(1 − 1/√(1 + s²))·UᵀJ_w, so that J̃ᵀJ̃ = Σ_w J_wᵀ(I − A_w(A_wᵀA_w + I)⁻¹A_wᵀ)J_w:
    the Schur complement of the joint information, i.e. the θ block of the joint inverse.
    Shape-preserving, so the widening rules read it as they read any Jacobian."""
    W, P = jac.shape[0], jac.shape[-1]
    a = (jac_s * prior_std).reshape(W, -1, len(prior_std))
    u, s, _ = np.linalg.svd(a, full_matrices=False)
    c = 1.0 - 1.0 / np.sqrt(1.0 + s**2)
    flat = jac.reshape(W, -1, P)
    along = np.einsum("wnm,wnp->wmp", u, flat)
    return (flat - np.einsum("wnm,wm,wmp->wnp", u, c, along)).reshape(jac.shape)


def residual_and_jacobian(fn, k: int, m: int, p):
    """fn(p) and its Jacobian, for p = [k shared coordinates, W windows × m start corrections]
    and a residual whose rows are grouped by window. Window w's rows depend on its own
    corrections only, so m tangents that move every window's alike, split by window, give their
    W·m columns: k + m forward tangents instead of k + W·m."""
    n_w = (p.shape[0] - k) // m

    def at(q):
        r = fn(jnp.concatenate([q[:k], p[k:] + jnp.tile(q[k:], n_w)]))
        return r, r

    jac, r = jax.jacfwd(at, has_aux=True)(jnp.concatenate([p[:k], jnp.zeros(m, p.dtype)]))
    per_window = jac[:, k:].reshape(n_w, -1, m)
    own = jnp.eye(n_w, dtype=p.dtype)[:, None, :, None]
    jac_s = (per_window[:, :, None, :] * own).reshape(-1, n_w * m)
    return r, jnp.concatenate([jac[:, :k], jac_s], axis=1)
