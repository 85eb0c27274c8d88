"""Ranking candidates by evidence, choosing among them, the verdict on the choice, and telling
look-alike effects apart (or saying why not).

Evidence is computed under the noise model identify uses (`vdsbi.estimation`): each channel's
unknown error scale profiled, and its N_c samples counted as N_c/τ_c independent ones (τ_c the
residual's autocorrelation time, the larger of the two fits'). The log marginal likelihood of a
candidate relative to another is then, in the BIC approximation,

    score = ½·Σ_c (N_c/τ_c)·ln(RSS_other,c / RSS_cand,c) − ½·k·ln N_eff,

with k the effect parameters added and N_eff = Σ_c N_c/τ_c: a log Bayes factor. Under white
sensor noise (τ = 1, the model right) this is the familiar χ² difference; on a real drive, whose
residual is model error correlated over tens of samples, a small gain is no longer decisive.
The ranking score adds the log prior odds: 0 for "none" and single effects, −3 for each effect
beyond the first (prior odds e⁻³ ≈ 1:20 against each pair — there are n(n−1)/2 pairs but n
singles, and a pair must earn its second effect; a triple its third), so a set ranks above its
subset only if the data favour the extra effect strongly (the forward search's rule). Scores > 3
(posterior odds > 20:1 against "none") count as strong. Ranking confidence: posterior
probabilities, exp(score) normalised over all fitted candidates.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import numpy as np

from ..problem.points import positions
from ..simulator import PARAM_NAMES
from ._candidates import LOOKALIKE_GROUPS, label
from ._results import DiscoveryFit, Ranked

#: Log Bayes factor counted as strong evidence (odds 20:1).
STRONG = 3.0
#: Log prior odds of a pair of effects against a single effect or "none".
PAIR_LOG_PRIOR = -STRONG
#: Largest held-out χ²/dof, in every channel, at which the chosen effects are claimed as the
#: explanation (the issue's rule; ~2 standard deviations of χ²/dof at 1000 held-out samples).
#: Measured against the predictive variance: a parameter the fitted part cannot pin down
#: (wide Laplace std) is not a missing effect.
HELD_OUT_CLAIM = 1.1


def bic_score(fit: DiscoveryFit, base: DiscoveryFit) -> float:
    """The log Bayes factor of `fit` against `base` (see the module docstring)."""
    k = fit.num_params - base.num_params
    tau = np.maximum(fit.noise.tau, base.noise.tau)
    n_eff = np.asarray(fit.noise.samples, float) / tau
    gain = np.log(np.maximum(base.rss, 1e-300) / np.maximum(fit.rss, 1e-300))
    return float(0.5 * np.sum(n_eff * gain) - 0.5 * k * np.log(max(n_eff.sum(), 2.0)))


def changes(effects, base_effects) -> int:
    """Effects added to or removed from the base set."""
    return len(set(effects) ^ set(base_effects))


def change_label(effects, base_effects) -> str:
    """A candidate named by its changes to the base set: "a+b", "a+no c", or "none"."""
    added = [e for e in effects if e not in base_effects]
    return label([*added, *(f"no {e}" for e in base_effects if e not in effects)])


def rank(fits: dict[tuple[str, ...], DiscoveryFit], base: DiscoveryFit) -> list[Ranked]:
    """Candidates sorted by score (log posterior odds vs "none"; best first), with posterior
    probabilities."""
    rows = []
    for effects, fit in fits.items():
        bf = 0.0 if effects == tuple(base.effects) else bic_score(fit, base)
        rows.append((effects, fit, bf, bf + PAIR_LOG_PRIOR * max(0, changes(effects, base.effects) - 1)))
    scores = np.array([s for *_, s in rows])
    p = np.exp(scores - scores.max())
    p /= p.sum()
    out = [
        Ranked(
            change_label(e, base.effects),
            tuple(e),
            float(s),
            float(bf),
            float(pi),
            f.chi2,
            f.num_params - base.num_params,
            f,
        )
        for (e, f, bf, s), pi in zip(rows, p)
    ]
    return sorted(out, key=lambda r: -r.score)


def merge(
    ranked: Sequence[Ranked], better: Sequence[Ranked], base_effects: Sequence[str] = ()
) -> list[Ranked]:
    """`ranked` with the rows of the same candidates replaced by `better` ones (e.g. re-fitted
    at a finer step, each scored against its own "none"), re-sorted, probabilities renormalised."""
    by = {r.effects: r for r in better if r.effects != tuple(base_effects)}
    rows = [by.get(r.effects, r) for r in ranked]
    scores = np.array([r.score for r in rows])
    p = np.exp(scores - scores.max())
    p /= p.sum()
    rows = [dataclasses.replace(r, probability=float(pi)) for r, pi in zip(rows, p)]
    return sorted(rows, key=lambda r: -r.score)


def choose(ranked: Sequence[Ranked], detected: bool, base_effects: Sequence[str] = ()) -> tuple[str, ...]:
    """The chosen explanation: the top candidate if the mismatch was detected and its posterior
    odds against the base set are strong (a pair's include its prior penalty, so it is chosen only
    if it beats the best single by log-evidence ≥ 3: parsimony); else the base set."""
    if not detected or not ranked or ranked[0].score < STRONG:
        return tuple(base_effects)
    return ranked[0].effects


def worst_channel(held: dict) -> tuple[str, float, int | None]:
    """The channel with the largest held-out χ²/dof, that value (against the predictive variance:
    noise and the fit's parameter uncertainty, where it was computed) and its sample count."""
    value = lambda c: held[c].get("chi2_dof_predictive", held[c]["chi2_dof"])
    ch = max(held, key=value)
    return ch, float(value(ch)), held[ch].get("samples")


def claim_limit(samples: int | None) -> float:
    """The held-out χ²/dof up to which a fix is claimed: `HELD_OUT_CLAIM`, or two standard
    deviations of χ²/dof above 1 (1 + 2·√(2/N)) where fewer held-out samples make it noisier."""
    return HELD_OUT_CLAIM if not samples else max(HELD_OUT_CLAIM, 1.0 + 2.0 * np.sqrt(2.0 / samples))


def verdict(
    detected: bool,
    chosen: Sequence[str],
    p_after: float,
    alpha: float,
    held_improved,
    held_worst: tuple | None = None,
) -> dict:
    """One-line conclusion, and whether the chosen effects account for the whole mismatch.

    `explained` needs a residual consistent with noise after the fix (p_after ≥ α), a better
    held-out fit, and the held-out χ²/dof after the fix (`held_worst`: its worst channel) at
    most `HELD_OUT_CLAIM` in every channel; otherwise physics outside the library remains (or
    the fix is absorbing it), and the report says so instead of claiming the effect as the
    answer.
    """
    if not detected:
        return {"explained": None, "text": "no mismatch detected: the base model fits within the noise"}
    if not chosen:
        return {
            "explained": False,
            "text": "mismatch detected, but no candidate effect has strong evidence: the missing "
            "physics is outside the library (see where it is located)",
        }
    names = " + ".join(chosen)
    if held_improved is False:
        return {
            "explained": False,
            "text": f"mismatch detected; {names} fits the fitted part but does not improve the "
            "held-out part: not claimed (it may stand in for physics outside the library)",
        }
    if p_after < alpha / 10:
        return {
            "explained": False,
            "text": f"mismatch detected; {names} explains part of it (p after the fix = {p_after:.3g} < "
            f"{alpha / 10:g}): physics outside the library remains",
        }
    if p_after < alpha:
        # at level α, one complete fix in 1/α still rejects by chance: say so, do not overclaim
        return {
            "explained": False,
            "text": f"mismatch detected; {names} explains most of it, but the residual test still "
            f"rejects weakly (p after the fix = {p_after:.3g} < {alpha:g}; about 1 in {1 / alpha:.0f} "
            "complete fixes does so by chance): something small may remain",
        }
    limit = None if held_worst is None else claim_limit(held_worst[2] if len(held_worst) > 2 else None)
    if held_worst is not None and held_worst[1] > limit:
        ch, v = held_worst[:2]
        return {
            "explained": False,
            "text": f"mismatch detected; {names} passes the residual test (p after the fix = "
            f"{p_after:.3g}) but the held-out χ²/dof (noise and parameter uncertainty) stays at "
            f"{v:.3g} > {limit:.3g} in {ch}: "
            "not claimed as the whole explanation",
        }
    return {"explained": True, "text": f"mismatch detected and explained by {names}"}


def _cos(a, b):
    na, nb = np.linalg.norm(a), np.linalg.norm(b)
    return float(a @ b / (na * nb)) if na > 0 and nb > 0 else 0.0


def separability(ranked: Sequence[Ranked], base: DiscoveryFit) -> list[dict]:
    """For each look-alike group: can its members be told apart on this recording?

    Signatures are the fitted changes of the whitened prediction, s_e = r_e − r_none. Two
    effects are separable when the better one's evidence exceeds the other's by `STRONG`;
    otherwise they are reported as not separable, with the signature correlation (how alike
    their fitted effects on the channels look) as the reason. steering_lag is compared with a
    cornering-stiffness change: the share of its signature inside the span of the C_alpha_f,
    C_alpha_r Jacobian columns of the base fit.
    """
    singles = {
        r.name: r
        for r in ranked
        if changes(r.effects, base.effects) == 1 and set(base.effects) <= set(r.effects)
    }
    out = []
    for group in LOOKALIKE_GROUPS:
        members = [g for g in group if g in singles]
        entry: dict = {"group": list(group), "pairs": []}
        if "cornering_stiffness" in group and "steering_lag" in singles:
            entry["pairs"].append(_lag_vs_stiffness(singles["steering_lag"], base))
        for i, a in enumerate(members):
            for b in members[i + 1 :]:
                entry["pairs"].append(_pair_verdict(a, b, singles[a], singles[b], base))
        out.append(entry)
    return out


def _lag_vs_stiffness(lag: Ranked, base: DiscoveryFit) -> dict:
    """steering_lag against a cornering-stiffness change: the share of the lag's signature in
    the span of the base fit's C_alpha_f, C_alpha_r Jacobian columns."""
    sig = lag.fit.residual - base.residual
    theta = positions(base.z).theta
    stiff = theta[[PARAM_NAMES.index("C_alpha_f"), PARAM_NAMES.index("C_alpha_r")]]
    cols = base.jacobian[:, np.isin(base.free, stiff)]
    if cols.size and np.linalg.norm(sig) > 0:
        coef, *_ = np.linalg.lstsq(cols, sig, rcond=None)
        share = float(np.linalg.norm(cols @ coef) ** 2 / np.linalg.norm(sig) ** 2)
    else:
        share = 0.0
    sep = lag.score >= STRONG or share < 0.9
    reason = (
        f"a steering lag adds log-evidence {lag.score:.1f} beyond re-fitting C_alpha; "
        f"{100 * share:.0f}% of its signature lies in the span of the cornering-stiffness "
        "directions"
    )
    if not sep:
        reason = "not separable on this recording: " + reason
    return {
        "a": "steering_lag",
        "b": "cornering_stiffness",
        "signature_share": share,
        "evidence_gap": lag.score,
        "separable": bool(sep),
        "verdict": reason,
    }


def _pair_verdict(a: str, b: str, ra: Ranked, rb: Ranked, base: DiscoveryFit) -> dict:
    """Whether single effects ``a`` and ``b`` can be told apart: by evidence, with the
    correlation of their fitted signatures as the reason when they cannot."""
    rho = _cos(ra.fit.residual - base.residual, rb.fit.residual - base.residual)
    gap = ra.score - rb.score
    best, other = (a, b) if gap >= 0 else (b, a)
    if max(ra.score, rb.score) < STRONG:
        verdict = f"neither {a} nor {b} is supported (evidence < {STRONG:g})"
        sep = True
    elif abs(gap) >= STRONG:
        verdict = (
            f"separable: {best} preferred over {other} by log-evidence {abs(gap):.1f} "
            f"(fitted signatures correlate {rho:+.2f})"
        )
        sep = True
    else:
        verdict = (
            f"not separable on this recording: fitted signatures correlate {rho:+.2f} "
            f"and the evidence gap is only {abs(gap):.1f} (< {STRONG:g})"
        )
        sep = False
    return {
        "a": a,
        "b": b,
        "signature_correlation": rho,
        "evidence_gap": abs(gap),
        "separable": bool(sep),
        "verdict": verdict,
    }
