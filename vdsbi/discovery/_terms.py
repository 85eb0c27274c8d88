"""A formula for what the library does not explain: sparse selection of candidate terms.

When the chosen library effects leave the residual inconsistent with noise, the remaining
mismatch is described as a sparse sum of candidate terms c·f(signals) (`simulator.effects.TERMS`:
missing forces, input and measurement terms built from the model's own signals), entering
through the differentiable simulator:

1. linearise: at the library fit, the Jacobian of the whitened residual with respect to θ, the
   initial speeds, the chosen effects' parameters (always re-fitted) and every term's
   coefficient (at 0), by forward-mode autodiff through the simulator;
2. select: forward selection on that linear model — add the term that lowers χ² most, keep it
   if its BIC log Bayes factor ½·Δχ² − ½·ln N is ≥ `STRONG`, up to `max_terms`;
3. refit: the nonlinear MAP fit (`Fitter.fit`, Levenberg–Marquardt) with the selected terms,
   warm-started at the library fit; the terms are kept only if their evidence there is strong
   too. Their coefficients come with Laplace standard deviations, and each term's magnitude is
   the RMS change it makes to each fitted channel.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ..problem.points import Point, gather, scatter
from ..simulator.effects import TERMS, term_effect, term_formula
from ._candidates import effect_space
from ._fit import Fitter, whitened
from ._rank import STRONG, bic_score, claim_limit, worst_channel
from ._results import DiscoveryFit, TermDiscovery

TERM_EFFECT = "discovered_terms"


@eqx.filter_jit
def _jacobian(space, target, z: Point, active, free):
    """The whitened residual at z and its derivative by z's flattened entries `free`."""
    fn = lambda y: whitened(space, target, scatter(z, free, y), active)
    y0 = gather(z, free)
    return fn(y0), jax.jacfwd(fn)(y0)


def _transfer(z_from: Point, src: Fitter, dst: Fitter, effects: Sequence[str]) -> Point:
    """z in `dst`'s effect space: θ, start speeds and the `effects`' entries copied from `src`;
    every other effect at its starting value."""
    z = dst.initial_z()
    for e in effects:
        z.effects[dst.effects.slices[e]] = z_from.effects[src.effects.slices[e]]
    return Point(z_from.theta, z_from.v0, z.effects).numpy()


def _chi2_after(r: np.ndarray, cols: np.ndarray) -> float:
    if cols.shape[1] == 0:
        return float(r @ r)
    coef, *_ = np.linalg.lstsq(cols, -r, rcond=None)
    e = r + cols @ coef
    return float(e @ e)


def select_terms(r: np.ndarray, base_cols: np.ndarray, term_cols: np.ndarray, keys, max_terms: int):
    """Forward selection on the linearised model: returns ([(key, gain)], {key: first-step gain})."""
    n = max(r.size, 2)
    penalty = 0.5 * np.log(n)
    chosen: list[int] = []
    out, screened = [], {}
    current = _chi2_after(r, base_cols)
    usable = [k for k in range(len(keys)) if np.linalg.norm(term_cols[:, k]) > 0]
    while len(chosen) < max_terms:
        gains = {}
        for k in usable:
            if k in chosen:
                continue
            cols = np.concatenate([base_cols, term_cols[:, chosen + [k]]], axis=1)
            gains[k] = 0.5 * (current - _chi2_after(r, cols)) - penalty
        if not gains:
            break
        if not chosen:
            screened = {keys[k]: float(g) for k, g in gains.items()}
        best = max(gains, key=gains.get)
        if gains[best] < STRONG:
            break
        chosen.append(best)
        current -= 2 * (gains[best] + penalty)
        out.append((keys[best], float(gains[best])))
    return out, screened


def _rms_change(fitter: Fitter, fit: DiscoveryFit, effects, keys) -> dict:
    """Per term: RMS change of every fitted channel when its coefficient is set to 0."""
    problem = fitter.problem
    with_all = fitter.predict(fit.z, effects)
    idx = np.arange(fitter.effects.num_params)[fitter.effects.slices[TERM_EFFECT]]
    mask = problem.train
    out = {}
    for j, key in enumerate(keys):
        z = fit.z.numpy()
        z.effects[idx[j]] = 0.0  # the sigmoid's midpoint: c = 0 (symmetric bounds)
        diff = with_all - fitter.predict(z, effects)
        out[key] = {
            ch: float(np.sqrt(np.mean(diff[..., c][mask] ** 2))) for c, ch in enumerate(problem.channels)
        }
    return out


def discover_terms(
    library_fit: DiscoveryFit,
    library_fitter: Fitter,
    chosen: Sequence[str],
    *,
    max_terms: int = 3,
    max_iter: int = 20,
    candidates: Sequence[str] | None = None,
) -> TermDiscovery:
    """Describe the mismatch the library fit leaves by a few candidate terms (module docstring).

    Args:
        library_fit: the fit of the chosen library effects (or the base fit).
        library_fitter: the `Fitter` that made it (its problem's training part is fitted).
        chosen: the library effects in that fit.
        max_terms: most terms kept.
        max_iter: LM iteration cap of the refit.
        candidates: the term names searched (default: all of `TERMS`).

    Returns:
        `TermDiscovery` (no terms when none has strong evidence).
    """
    chosen = tuple(chosen)
    keys = tuple(TERMS if candidates is None else candidates)
    effects = chosen + (TERM_EFFECT,)
    problem, dt = library_fitter.problem, library_fitter.dt
    screen = Fitter(problem, dt=dt, effects=effect_space(chosen, extra=(term_effect(keys),)))
    z0 = _transfer(library_fit.z, library_fitter, screen, chosen)
    base_free = screen.free_index(chosen)
    free = np.concatenate([base_free, screen.effect_positions(TERM_EFFECT)])
    act = jnp.asarray(screen.active_mask(effects))
    r, jac = _jacobian(screen.space, screen.target, z0.jax(), act, jnp.asarray(free))
    r, jac = np.asarray(r), np.asarray(jac)
    nb = len(base_free)
    picked, screened = select_terms(r, jac[:, :nb], jac[:, nb:], keys, max_terms)
    if not picked:
        return TermDiscovery([], None, None, effects, screened, None)
    sel = tuple(k for k, _ in picked)
    space = effect_space(chosen, extra=(term_effect(sel),))
    fitter = Fitter(problem, dt=dt, effects=space, free_effects=space.num_params)
    fit = fitter.fit(effects, _transfer(library_fit.z, library_fitter, fitter, chosen), max_iter=max_iter)
    gain = float(bic_score(fit, library_fit))
    if gain < STRONG:
        return TermDiscovery([], None, None, effects, screened, gain)
    fit, dropped = _drop_stand_ins(fitter, fit, chosen, max_iter)
    effects = fit.effects
    gain = float(bic_score(fit, library_fit))
    terms = _term_rows(fit, picked, _rms_change(fitter, fit, effects, sel))
    return TermDiscovery(terms, fit, fitter, effects, screened, gain, dropped)


def _term_rows(fit: DiscoveryFit, picked, rms: dict) -> list[dict]:
    """One row per kept term: its formula, coefficient ± std, and what it changes."""
    rows = []
    for key, lin_gain in picked:
        c = fit.effect_params[TERM_EFFECT][key]
        rows.append(
            {
                "key": key,
                "formula": term_formula(key, c),
                "coefficient": c,
                "std": fit.effect_std[TERM_EFFECT][key],
                "unit": TERMS[key].unit,
                "target": TERMS[key].target,
                "linear_gain": lin_gain,
                "rms_change": rms[key],
            }
        )
    return rows


def _drop_stand_ins(fitter: Fitter, fit: DiscoveryFit, chosen, max_iter: int):
    """Backward step beside the terms: a library effect that adds no strong evidence once the
    terms are in was standing in for them; it is dropped (same compiled kernel: inactive
    effects sit at their null values)."""
    dropped = []
    for e in chosen:
        trial = fitter.fit(tuple(x for x in fit.effects if x != e), fit.z, max_iter=max_iter)
        if bic_score(fit, trial) < STRONG:
            fit = trial
            dropped.append(e)
    return fit, dropped


@dataclasses.dataclass(frozen=True)
class HeldOutScores:
    """The held-out part's scores per channel that `terms_section` weighs.

    Attributes:
        after: scores after the library fix ({channel: {"chi2_dof": …}}).
        terms: scores with the discovered terms (None: no refit with terms).
        n: held-out samples per channel.
        tau: each channel's residual autocorrelation time (default 1: white).
    """

    after: dict
    terms: dict | None
    n: int
    tau: Mapping[str, float] | None = None


def terms_section(
    *,
    p_before: float,
    p_after: float,
    chosen: Sequence[str],
    terms: TermDiscovery | None,
    p_terms: float | None,
    held: HeldOutScores,
    alpha: float,
) -> dict:
    """The discovered terms, their held-out fit and test, and what explained the mismatch:
    "discovered term" (kept terms that also predict the held-out part better: held-out
    log-likelihood gain ½·Σ_c (N/τ_c)·ln(χ²_library,c / χ²_terms,c) ≥ `STRONG`, each channel's
    N held-out samples counted by its residual's autocorrelation time τ_c, as the evidence is),
    "library" (the chosen effects leave p ≥ α/10 and a held-out χ²/dof ≤ `claim_limit` in every
    channel), "unexplained", or "none" (no mismatch).

    `p_before`, `p_after`, `p_terms`: the residual tests of the base fit, the chosen effects'
    fit and the refit with the terms; `held` the held-out scores (`HeldOutScores`)."""
    held_after, held_terms, n_held, tau = held.after, held.terms, held.n, held.tau
    detected = bool(p_before < alpha)
    worst = worst_channel(held_after)
    held_ok = worst[1] <= claim_limit(worst[2])
    library = detected and bool(chosen) and p_after >= alpha / 10 and held_ok
    out: dict = {"discovered_terms": [], "p_value_after_terms": None, "terms_replace": []}
    td = terms
    if not detected:
        return {**out, "explanation": "none"}
    out["explanation"] = "library" if library else "unexplained"
    if td is None:
        return out
    out["term_search"] = {"screened_gain": td.screened, "refit_gain": td.gain}
    if td.fit is None:
        if not library:
            out["sentence"] = "no candidate term has strong evidence either: left unexplained"
        return out
    out["discovered_terms"], out["terms_replace"] = td.terms, list(td.dropped)
    out["p_value_after_terms"] = float(p_terms)
    out["fit"] = held_terms
    tau = tau or {}
    gain = 0.5 * sum(
        n_held / tau.get(c, 1.0) * np.log(held_after[c]["chi2_dof"] / held_terms[c]["chi2_dof"])
        for c in held_terms
    )
    out["held_out_gain"] = float(gain)
    mean = lambda d: float(np.mean([v["chi2_dof"] for v in d.values()]))
    formulas = "; ".join(t["formula"] for t in td.terms)
    if td.dropped:
        formulas += f" (which makes {', '.join(td.dropped)} unnecessary)"
    if gain < STRONG:
        out["sentence"] = (
            f"a term fits the training part ({formulas}) but does not predict the held-out part "
            f"better (held-out log-likelihood gain {gain:.1f} < {STRONG:g})"
        )
        return out
    out["explanation"] = "discovered term"
    rest = "" if out["p_value_after_terms"] >= alpha / 10 else "; something still remains"
    out["sentence"] = (
        f"outside the library the remaining mismatch is described by {formulas} (held-out mean "
        f"χ²/dof {mean(held_after):.3g} → {mean(held_terms):.3g}, held-out log-likelihood gain "
        f"{gain:.1f}, p after = {out['p_value_after_terms']:.3g}{rest})"
    )
    return out
