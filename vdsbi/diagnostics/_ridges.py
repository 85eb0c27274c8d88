"""Pairs (and larger groups) of parameters that trade along a ridge of the likelihood: the drive
determines a combination of them, not each alone.

A steering lag and the yaw-inertia index both slow the yaw response; a friction factor and a
cornering stiffness both set the lateral force near the limit. Where the data fix only their
combination, the posterior of the pair is a long, thin ellipse: the two are strongly correlated,
and each one's std given the other is a small part of its own std (σ_i·√(1 − ρ²): below 0.44·σ_i
at |ρ| ≥ 0.9). The ridge matters only where it is long: two parameters pinned to a few per cent of
their prior each (l_f and C_αr on a clean drive often correlate at 0.9) are determined one by
one, and only share their error. Three or more can trade where no two do (two friction factors
and the downforce all set the grip of a fast corner): a parameter each of whose std given the
others is below that 0.44 of its own, while no single partner explains it, is reported with the
fewest partners that do (two at most).

Coordinates: the box's logit coordinates (`vdsbi.problem.Box`), in which the likelihood
posterior is Gaussian and a bound does not squeeze the ridge (an inertia index held at the top
of its box still moves far along it in z).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from jaxtyping import Float

from ..estimation import PRIOR_Z_STD

#: |ρ| at or above which two parameters move along one ridge.
RIDGE_CORRELATION = 0.9
#: Each member's std over its prior std at or above which the ridge is long enough to leave it
#: undetermined alone.
RIDGE_MIN_RATIO = 0.2
#: Most members of a group that trades: a parameter that only many others together explain is
#: left to the determined combinations (`combinations`), not named as a ridge.
GROUP_SIZE = 3
WHAT = (
    "the two move together along this step (each by its std) with the fit barely changed: the drive "
    "determines their combination, not each alone"
)


def trading_pairs(
    cov: Float[np.ndarray, "P P"],
    names: Sequence[str],
    step: Float[np.ndarray, " P"],
    prior_std: float | Float[np.ndarray, " P"] = PRIOR_Z_STD,
) -> list[dict]:
    """The pairs of parameters that trade along a ridge of the posterior, most correlated first.

    Args:
        cov: posterior covariance in coordinates that map each parameter on its own (default:
            the box's logit coordinates, e.g. `LikelihoodPosterior.cov_information`).
        names: parameter names, `cov`'s order.
        step: each parameter's posterior std in its own units, for the step along the ridge.
        prior_std: each parameter's prior std in `cov`'s coordinates.

    Returns:
        [{"pair": [a, b], "correlation": ρ, "direction": {a: step_a, b: ±step_b}, "what"}]: a
        pair trades when |ρ| ≥ `RIDGE_CORRELATION` and each member's std is at least
        `RIDGE_MIN_RATIO` of its prior std. "direction" is one step along the ridge in parameter
        units: each member by its std, b's sign that of ρ; the fit barely changes along it.
        Then the groups of three or more (`_groups`): "pair" lists every member, "correlation"
        is the multiple correlation of the member the others explain, "direction" one std of
        the posterior along the group's longest axis.
    """
    cov = np.asarray(cov, float)
    step = np.asarray(step, float)
    sd = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    long = (sd > 0) & (sd >= RIDGE_MIN_RATIO * np.broadcast_to(prior_std, sd.shape))
    out = []
    for i in range(len(names)):
        for j in range(i + 1, len(names)):
            if not (long[i] and long[j]):
                continue
            rho = float(cov[i, j] / (sd[i] * sd[j]))
            if abs(rho) < RIDGE_CORRELATION:
                continue
            a, b = names[i], names[j]
            direction = {a: float(step[i]), b: float(np.sign(rho) * step[j])}
            out.append({"pair": [a, b], "correlation": round(rho, 3), "direction": direction, "what": WHAT})
    out = sorted(out, key=lambda p: -abs(p["correlation"]))
    return out + _groups(cov, names, step, np.flatnonzero(long), {n for p in out for n in p["pair"]})


def _groups(cov, names, step, long: np.ndarray, paired: set) -> list[dict]:
    """Groups of three or more long parameters that trade where no two do (see the module)."""
    corr = cov / np.sqrt(np.outer(np.diag(cov), np.diag(cov)))
    limit = 1.0 - RIDGE_CORRELATION**2  # the conditional variance's share at the pair's |ρ|
    out, seen = [], set()
    for i in long:
        if names[i] in paired:
            continue
        chosen: list[int] = []
        while _conditional(corr, i, chosen) > limit and len(chosen) < min(GROUP_SIZE - 1, len(long) - 1):
            rest = [j for j in long if j != i and j not in chosen]
            chosen.append(min(rest, key=lambda j: _conditional(corr, i, [*chosen, j])))
        members = sorted([i, *chosen])
        if len(members) < 3 or _conditional(corr, i, chosen) > limit or tuple(members) in seen:
            continue
        seen.add(tuple(members))
        # The ridge: the block's longest axis (in stds), one std of the posterior along it.
        lam, vec = np.linalg.eigh(corr[np.ix_(members, members)])
        axis = vec[:, -1] * np.sqrt(lam[-1]) * np.sign(vec[members.index(i), -1])
        out.append(
            {
                "pair": [names[j] for j in members],
                "correlation": round(float(np.sqrt(1.0 - _conditional(corr, i, chosen))), 3),
                "direction": {names[j]: float(a * step[j]) for j, a in zip(members, axis)},
                "what": WHAT.replace("the two move", "they move"),
            }
        )
    return out


def _conditional(corr, i: int, given: list[int]) -> float:
    """Var(x_i | x_given) / Var(x_i) from a correlation matrix."""
    if not given:
        return 1.0
    c = corr[np.ix_(given, given)]
    v = corr[given, i]
    return float(max(0.0, 1.0 - v @ np.linalg.solve(c, v)))


def ridge_sentence(pair: dict) -> str:
    """ "a and b trade along a ridge (ρ = …)" or "a, b and c trade along a ridge (R = …)"."""
    members = pair["pair"]
    who = " and ".join([", ".join(members[:-1]), members[-1]])
    mark = "ρ" if len(members) == 2 else "R"
    return f"{who} trade along a ridge ({mark} = {pair['correlation']:+.2f})"
