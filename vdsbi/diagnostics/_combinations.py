"""What a drive determines when single parameters are not identified: the combinations a vehicle
engineer reads, and the best-determined directions of the posterior.

A mild drive (small slip angles) fixes the steady-state yaw response of the linear single-track
model, not each stiffness: the understeer gradient

    K = (m/L)·(l_r/C_αf − l_f/C_αr)   [rad per m/s² of lateral acceleration]

and the steady-state yaw-rate gain r/δ = v/(L + K·v²) (Milliken & Milliken, *Race Car Vehicle
Dynamics*, ch. 5; Rajamani, *Vehicle Dynamics and Control*, §3.3). Both are evaluated on
posterior draws, so their intervals are the posterior's.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ..simulator import GRAVITY, Vehicle

#: A direction of log-parameters counts as determined when its posterior std is below this
#: fraction of its prior std (the identifiability rule's ratio).
DETERMINED_RATIO = 0.5


def _spread(x: np.ndarray) -> float:
    """The interquartile range over 1.349 (a normal's std): robust to the unbounded tails a
    combination takes where a draw nears a singularity."""
    q1, q3 = np.percentile(x, [25, 75])
    return float(q3 - q1) / 1.349


def _interval(x: np.ndarray) -> dict[str, float]:
    q = np.quantile(x, [0.025, 0.5, 0.975])
    return {"median": float(q[1]), "q025": float(q[0]), "q975": float(q[2]), "std": float(np.std(x))}


def vehicle_combinations(
    samples: np.ndarray,
    names: Sequence[str],
    vehicle: Vehicle,
    speed: float,
    prior_samples: np.ndarray | None = None,
    informed_samples: np.ndarray | None = None,
) -> dict[str, dict]:
    """Understeer gradient (deg/g) and steady-state yaw-rate gain at `speed` (1/s) over (N, P)
    posterior draws, with 95 % intervals; with `prior_samples` each also says whether the drive
    determines it (`identified`: robust spread at most `DETERMINED_RATIO` of the prior's and a
    95 % interval as narrow, the rule single
    parameters and directions follow), read from `informed_samples` where given (draws of what
    the drive's information alone allows, before model error widens the posterior)."""
    post = _combinations(samples, names, vehicle, speed)
    told = post if informed_samples is None else _combinations(informed_samples, names, vehicle, speed)
    prior = None if prior_samples is None else _combinations(prior_samples, names, vehicle, speed)
    out = {}
    kinds = (("understeer_gradient", "deg/g", None), ("yaw_rate_gain", "1/s", round(float(speed), 2)))
    for key, unit, at in kinds:
        out[key] = {"unit": unit, "at": at} | _interval(post[key])
        if prior is not None:
            ratio = float(_spread(told[key]) / _spread(prior[key]))
            # The interval too: a gain near the critical speed of an oversteering draw is unbounded,
            # and its tails must not pass for a determined value.
            width = out[key]["q975"] - out[key]["q025"]
            bounded = width <= DETERMINED_RATIO * 3.92 * _spread(prior[key])
            out[key] |= {
                "std_ratio_to_prior": ratio,
                "identified": bool(ratio <= DETERMINED_RATIO and bounded),
            }
    return out


def _combinations(samples: np.ndarray, names: Sequence[str], vehicle: Vehicle, speed: float) -> dict:
    idx = {n: names.index(n) for n in ("l_f", "C_alpha_f", "C_alpha_r")}
    lf, cf, cr = (samples[:, idx[n]] for n in ("l_f", "C_alpha_f", "C_alpha_r"))
    m, L = vehicle.mass, vehicle.wheelbase
    k = (m / L) * ((L - lf) / cf - lf / cr)  # rad / (m/s²)
    return {"understeer_gradient": np.degrees(k) * GRAVITY, "yaw_rate_gain": speed / (L + k * speed**2)}


def determined_directions(
    samples: np.ndarray, prior_samples: np.ndarray, names: Sequence[str], free: Sequence[str]
) -> list[dict]:
    """Directions in log-parameter space (of the `free` parameters with a positive prior) that
    the drive determines: eigenvectors of the posterior covariance of log θ whose std is below
    `DETERMINED_RATIO` of the prior's std along them, best first; each as {"weights": {name: w},
    "std", "ratio"} (|w| summing to 1, small weights dropped)."""
    positive = lambda i: np.all(samples[:, i] > 0) and np.all(prior_samples[:, i] > 0)
    idx = [names.index(n) for n in free if positive(names.index(n))]
    if not idx:
        return []
    logs = np.log(samples[:, idx])
    prior = np.log(prior_samples[:, idx])
    vals, vecs = np.linalg.eigh(np.cov(logs, rowvar=False).reshape(len(idx), len(idx)))
    out = []
    for v, w in zip(vals, vecs.T):
        prior_std = float(np.std(prior @ w))
        ratio = float(np.sqrt(max(v, 0.0)) / prior_std)
        if ratio > DETERMINED_RATIO:
            continue
        w = w / np.sum(np.abs(w)) * np.sign(w[np.argmax(np.abs(w))])
        out.append(
            {
                "weights": {names[i]: round(float(x), 3) for i, x in zip(idx, w) if abs(x) >= 0.05},
                "std": float(np.sqrt(max(v, 0.0))),
                "ratio": ratio,
            }
        )
    return sorted(out, key=lambda d: d["ratio"])
