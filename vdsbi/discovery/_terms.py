"""A formula for what the library does not explain: sparse selection of candidate terms.

When the chosen library effects leave the residual inconsistent with noise, the remaining
mismatch is described as a sparse sum of candidate terms c·f(signals) (`simulator.TERMS`:
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
from collections.abc import Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ..simulator import CHANNELS, TERMS, Vehicle, term_effect, term_formula
from ._candidates import effect_space
from ._fit import FitData, FitResult, Fitter, _whitened
from ._rank import HELD_OUT_CLAIM, STRONG, bic_score, worst_channel

TERM_EFFECT = "discovered_terms"


@dataclasses.dataclass
class TermDiscovery:
    """The discovered terms (possibly none), their refit and where the search looked.

    Attributes:
        terms: one dict per kept term: key, formula, coefficient, std, unit, target,
            linear_gain (evidence at selection), rms_change {channel: RMS change of the fit}.
        fit: the refit with the chosen effects and the kept terms (None: no term kept).
        fitter: the `Fitter` of that refit (for predictions).
        effects: the effect names of the refit (the chosen ones and `TERM_EFFECT`).
        screened: linearised evidence gain of every candidate term at the first step.
        gain: log Bayes factor of the refit against the library fit (None: no refit).
        dropped: library effects removed beside the terms (they were standing in for them).
    """

    terms: list[dict]
    fit: FitResult | None
    fitter: Fitter | None
    effects: tuple[str, ...]
    screened: dict[str, float]
    gain: float | None
    dropped: list[str] = dataclasses.field(default_factory=list)


@eqx.filter_jit
def _jacobian(model, space, data, z, active, free, solver):
    fn = lambda y: _whitened(model, space, data, z.at[free].set(y), active, solver)
    y0 = z[free]
    return fn(y0), jax.jacfwd(fn)(y0)


def _transfer(z_from: np.ndarray, src: Fitter, dst: Fitter, effects: Sequence[str]) -> np.ndarray:
    """z in `dst`'s layout: θ, initial speeds and the `effects`' entries copied from `src`;
    everything else at its starting value."""
    z = dst.initial_z()
    w = src.data.num_windows
    z[: 6 + w] = z_from[: 6 + w]
    for e in effects:
        z[dst._effect_index(e)] = z_from[src._effect_index(e)]
    return z


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


def _rms_change(fitter: Fitter, fit: FitResult, effects, keys) -> dict:
    """Per term: RMS change of every fitted channel when its coefficient is set to 0."""
    data = fitter.data
    with_all = fitter.predict(fit.z, effects)
    idx = fitter._effect_index(TERM_EFFECT)
    mask = np.asarray(data.mask) > 0
    out = {}
    for j, key in enumerate(keys):
        z = fit.z.copy()
        z[idx[j]] = 0.0  # the sigmoid's midpoint: c = 0 (symmetric bounds)
        diff = with_all - fitter.predict(z, effects)
        out[key] = {
            ch: float(np.sqrt(np.mean(diff[:, :, CHANNELS.index(ch)][mask] ** 2))) for ch in data.channels
        }
    return out


def discover_terms(
    vehicle: Vehicle,
    data: FitData,
    library_fit: FitResult,
    library_fitter: Fitter,
    chosen: Sequence[str],
    *,
    max_terms: int = 3,
    max_iter: int = 20,
    candidates: Sequence[str] | None = None,
) -> TermDiscovery:
    """Describe the mismatch the library fit leaves by a few candidate terms (module docstring).

    Args:
        vehicle: vehicle constants.
        data: the fitted (training) windows.
        library_fit: the fit of the chosen library effects (or the base fit), on `data`.
        library_fitter: the `Fitter` that made it.
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
    dt = library_fitter.dt
    screen = Fitter(vehicle, data, dt=dt, effects=effect_space(chosen, extra=(term_effect(keys),)))
    z0 = _transfer(library_fit.z, library_fitter, screen, chosen)
    base_free = screen.free_index(chosen)
    free = np.concatenate([base_free, screen._effect_index(TERM_EFFECT)])
    act = jnp.asarray(screen.active_mask(effects))
    r, jac = _jacobian(
        screen.model, screen.space, data, jnp.asarray(z0), act, jnp.asarray(free), screen.solver
    )
    r, jac = np.asarray(r), np.asarray(jac)
    nb = len(base_free)
    picked, screened = select_terms(r, jac[:, :nb], jac[:, nb:], keys, max_terms)
    if not picked:
        return TermDiscovery([], None, None, effects, screened, None)
    sel = tuple(k for k, _ in picked)
    space = effect_space(chosen, extra=(term_effect(sel),))
    fitter = Fitter(vehicle, data, dt=dt, effects=space, free_effects=space.num_params)
    fit = fitter.fit(effects, _transfer(library_fit.z, library_fitter, fitter, chosen), max_iter=max_iter)
    gain = float(bic_score(fit, library_fit))
    if gain < STRONG:
        return TermDiscovery([], None, None, effects, screened, gain)
    fit, dropped = _drop_stand_ins(fitter, fit, chosen, max_iter)
    effects = fit.effects
    gain = float(bic_score(fit, library_fit))
    rms = _rms_change(fitter, fit, effects, sel)
    terms = []
    for key, lin_gain in picked:
        c = fit.effect_params[TERM_EFFECT][key]
        terms.append(
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
    return TermDiscovery(terms, fit, fitter, effects, screened, gain, dropped)


def _drop_stand_ins(fitter: Fitter, fit: FitResult, chosen, max_iter: int):
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


def terms_section(found, held_after: dict, held_terms: dict | None, n_held: int, alpha: float) -> dict:
    """The discovered terms, their held-out fit and test, and what explained the mismatch:
    "discovered term" (kept terms that also predict the held-out part better: held-out
    log-likelihood gain ½·Σ(χ²_library − χ²_terms) ≥ `STRONG`), "library" (the chosen effects
    leave p ≥ α/10 and a held-out χ²/dof ≤ `HELD_OUT_CLAIM` in every channel), "unexplained",
    or "none" (no mismatch).

    `found` is the `DiagnosisResult`; `held_after`, `held_terms` the held-out metrics per
    channel after the library fix and with the terms; `n_held` held-out samples per channel."""
    detected = bool(found.test_before.p_value < alpha)
    held_ok = worst_channel(held_after)[1] <= HELD_OUT_CLAIM
    library = detected and bool(found.final.effects) and found.test_after.p_value >= alpha / 10 and held_ok
    out: dict = {"discovered_terms": [], "p_value_after_terms": None, "terms_replace": []}
    td = found.terms
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
    out["p_value_after_terms"] = float(found.test_terms.p_value)
    out["fit"] = held_terms
    gain = 0.5 * n_held * sum(held_after[c]["chi2_dof"] - held_terms[c]["chi2_dof"] for c in held_terms)
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
