"""What `identify` writes into posterior.json beside the run's settings: `run_summary` (the reported
posterior per parameter, the estimate, the noise model, what the drive cannot inform and the
combinations it determines), `npe_check` (the neural posterior against the likelihood one),
`validation_report` (held-out scores of the estimate, the neural mean and any reference values),
`ppc_summary` (the predictive band's coverage) and `run_warnings` (each pointing to `vdsbi
diagnose`). Each takes the fitted objects and returns plain JSON-ready dicts and lists."""

from __future__ import annotations

import os
from typing import Any

import numpy as np

from .. import __version__
from ..io import InputError
from ..problem import Box, Problem, parameter_names, parameter_units
from ..problem.points import split_parameters
from ..problem.validation import band_coverage, validate
from ..simulator.models import LongitudinalChoice
from ._commands import diagnose_command
from ._trust import model_error_warning, trust_warnings
from .outputs import summarise


def run_summary(full: Problem, samples, fit, state, run_info: dict, box: Box, effects, veh) -> dict[str, Any]:
    """posterior.json's core: the reported posterior (the likelihood one on all the driving), the
    estimate (its best fit), the noise model, what the drive cannot inform and what it does."""
    import jax

    from ..diagnostics import determined_directions, trading_pairs, vehicle_combinations

    names = box.names
    bounds = {n: (float(a), float(b)) for n, a, b in zip(names, box.low, box.high)}
    params = summarise(samples, bounds, names, parameter_units(effects))
    informed = np.asarray(fit.sample(jax.random.key(2), len(samples), information_only=True), float)
    informed_std = np.std(informed, axis=0)
    _flag(params, fit, box, informed_std)
    # The ridge is read where the identifiability rule reads: the drive's information alone.
    pairs = trading_pairs(fit.cov_information, names, informed_std)
    _flag_box_and_ridges(params, box, pairs)
    speed = full.speed if full.speed is not None else np.broadcast_to(full.v0[:, None], full.t.shape)
    rms_speed = float(np.sqrt(np.mean(np.asarray(speed)[:, :: full.factor][full.train] ** 2)))
    prior = np.random.default_rng(0).uniform(box.low, box.high, (4000, box.dim))
    return {
        "vdsbi_version": __version__,
        "recording": run_info["recording"],
        "parameters": params,
        "estimate": {
            "values": {n: float(v) for n, v in zip(names, fit.theta)},
            "method": "best fit of all the usable driving through the simulator (maximum a posteriori "
            "under the noise model below); the reported posterior is the Laplace approximation there",
            "converged": fit.converged,
            "start_speed_corrections": None
            if fit.v0_offset is None or not np.any(fit.v0_offset)
            else {
                "m_s": [float(v) for v in fit.v0_offset],
                "what": "each torque-driven window's start speed as fitted, minus the measured one",
            },
            "halves_disagree": None
            if fit.inconsistency is None
            else fit.inconsistency
            | {
                "what": "two halves of the data cannot share one θ (D² of their difference beyond "
                "χ²'s 95 % point): the model lacks something, and the data's information is divided by D²/P"
            },
        },
        "noise_model": fit.noise.to_dict(),
        "not_identified": [n for n in names if params[n]["identified"] is False],
        "combinations": vehicle_combinations(samples, names, veh, rms_speed, prior, informed)
        | {
            "determined_directions": determined_directions(samples, prior, names, fit.free),
            "trading_pairs": pairs,
        },
        "effects": list(effects),
        "problem": full.summary(),
        "channels": list(full.channels),
        "seed": run_info["seed"],
        "settings": run_info["settings"],
        "rounds": [{k: v for k, v in h.items() if isinstance(v, (int, float, str))} for h in state.history],
    }


def _flag(params: dict, fit, box: Box, informed_std) -> None:
    """Each parameter's estimate, `std_ratio_to_prior` (the information-only std over the prior's),
    `identified` and why not, and `model_error` where it applies, in `params` (`summarise`'s,
    whose std is the reported posterior's).

    Identified by what the drive informs (the information-only spread, before model error widens
    the interval): a parameter the data pin down stays identified, with an interval that says the
    model misses something, and is flagged as moved by model error when halves of the data
    disagree on it or that widened interval exceeds the rule."""
    from ..diagnostics import MAX_STD_RATIO

    for i, n in enumerate(box.names):
        prior_std = float(box.width[i]) / np.sqrt(12.0)
        p = params[n]
        ratio, widened = float(informed_std[i]) / prior_std, p["std"] / prior_std
        p["estimate"] = float(fit.theta[i])
        p["std_ratio_to_prior"] = ratio
        p["informed"] = n in fit.free
        p["identified"] = bool(n in fit.free and ratio <= MAX_STD_RATIO)
        if n not in fit.free:
            p["not_identified_because"] = "the channels do not depend on it in this mode"
        elif ratio > MAX_STD_RATIO:
            p["not_identified_because"] = f"the drive leaves {ratio:.0%} of its prior std"
        if n in fit.disagreement:
            d = fit.disagreement[n]
            p["model_error"] = (
                f"the data's halves ({d['split']}) disagree on it by {d['sigmas']:.1f} standard deviations: "
                "the model lacks something that moves it; its interval is widened by the disagreement"
            )
        elif p["identified"] and widened > MAX_STD_RATIO:
            p["model_error"] = (
                f"the model error the fit measured widens its interval to {widened:.0%} of its prior std: "
                "the model lacks something that moves it"
            )


def _flag_box_and_ridges(params: dict, box: Box, pairs) -> None:
    """Not identified, beyond what the information says: a parameter the prior box holds
    (`held_by_box`: its interval spans the box, or its estimate sits on a bound), and both
    members of a pair that trades along a ridge (`trading_pairs`), each naming its partner.
    The box's reasons are given only where the information had none (a parameter the drive does
    not inform spans its box by that alone); a ridge's partner is always named."""
    from ..diagnostics import held_by_box

    for i, n in enumerate(box.names):
        p = params[n]
        if p["identified"]:
            why = held_by_box(p["estimate"], p["q05"], p["q95"], float(box.low[i]), float(box.high[i]))
            _not_identified(p, why)
    for pair in pairs:
        members = pair["pair"]
        mark = "ρ" if len(members) == 2 else "R"
        for me in members:
            others = [n for n in members if n != me]
            params[me].setdefault("trades_with", []).extend(others)
            _not_identified(
                params[me],
                [f"trades with {' and '.join(others)} along a ridge ({mark} = {pair['correlation']:+.2f})"],
            )


def _not_identified(p: dict, reasons) -> None:
    if not reasons:
        return
    first = [p["not_identified_because"]] if "not_identified_because" in p else []
    p["identified"] = False
    p["not_identified_because"] = "; ".join(first + list(reasons))


def npe_check(npe_samples: np.ndarray, checked) -> dict[str, Any]:
    """The neural posterior against the likelihood posterior of the same (training) data: the
    squared Mahalanobis distance of its mean, in the likelihood posterior's logit coordinates
    (≤ χ²_P(0.5): inside its 50 % region), and each parameter's std ratio."""
    from scipy.stats import chi2

    d2 = float(checked.mahalanobis2(npe_samples.mean(0))[0])
    limit = float(chi2.ppf(0.5, len(checked.z)))
    import jax

    lik = np.asarray(checked.sample(jax.random.key(1), 2000), float)
    spread = np.std(npe_samples, axis=0) / (np.std(lik, axis=0) + 1e-300)
    ratio = {n: float(r) for n, r in zip(checked.names, spread)}
    agree = d2 <= limit and all(0.5 <= r <= 2.0 for n, r in ratio.items() if n in checked.free)
    return {
        "mahalanobis2_of_npe_mean": d2,
        "chi2_50pct": limit,
        "std_ratio_npe_to_likelihood": ratio,
        "agree": bool(agree),
        "reported": "likelihood",
        "why": "the neural posterior is trained on simulations with sensor noise only; the likelihood "
        "posterior carries the model error the fit measured, and its best fit is the estimate",
    }


def validation_report(prob: Problem, checked, npe_samples: np.ndarray, effects, compare) -> dict[str, Any]:
    """Held-out scores of the training fit (the estimate's validation) and of the neural
    posterior's mean; the user's reference values beside them (parameters a reference does not
    give are taken from the fit)."""
    if not prob.held.any():
        return {}
    names = parameter_names(effects)
    out = {
        "estimate": _score(prob, checked.theta, effects),
        "npe_mean": _score(prob, npe_samples.mean(0), effects),
        "what": "fitted on the training part, scored on the held-out part; the exported estimate "
        "is then refit on all the driving",
        "split": prob.summary().get("how", ""),
    }
    if compare:
        unknown = [k for k in compare if k not in names]
        if unknown:
            raise InputError(
                "settings", "--compare", f"unknown parameter {unknown[0]!r}; known: {', '.join(names)}"
            )
        ref = np.array([float(compare.get(n, m)) for n, m in zip(names, checked.theta)])
        out["reference"] = _score(prob, ref, effects) | {"given": {k: float(v) for k, v in compare.items()}}
    return out


def run_warnings(
    samples: np.ndarray, summary: dict, box: Box, names, longitudinal: LongitudinalChoice
) -> list[dict[str, Any]]:
    """posterior.json's `warnings`: mass piled at the prior's edges, or a predictive band that
    misses the recording, each pointing to `vdsbi diagnose`."""
    from ..diagnostics import MAX_STD_RATIO

    rec, veh, out = (n if isinstance(n, (str, os.PathLike)) else None for n in names)
    if rec is None:
        rec = summary["recording"]
    ppc = summary["ppc"]
    bounds = {n: (float(a), float(b)) for n, a, b in zip(box.names, box.low, box.high)}
    problem = [{"kind": "recording", "message": w} for w in summary["problem"].get("warnings", ())]
    command = diagnose_command(rec, veh, out, longitudinal)
    coverage = {
        "train": ppc["fraction_inside_90pct_band"],
        "held_out": ppc["fraction_inside_90pct_band_held_out"],
    }
    return (
        problem
        + trust_warnings(
            samples,
            list(summary["parameters"]),
            bounds,
            # Only what the drive does not inform: a parameter the box holds is what the edge
            # warning is for.
            [
                n
                for n, p in summary["parameters"].items()
                if not p.get("informed", True) or p["std_ratio_to_prior"] > MAX_STD_RATIO
            ],
            coverage,
            command,
        )
        + model_error_warning(summary["noise_model"], command)
    )


def _score(prob: Problem, values: np.ndarray, effects) -> dict[str, Any]:
    from ..simulator.effects import get_effect

    theta, ep = split_parameters(values, effects)
    eff_values = {
        e: {p: float(v) for p, v in zip(get_effect(e).param_names, np.asarray(x))}
        for e, x in zip(effects, ep)
    }
    return validate(prob, np.asarray(theta), effects, eff_values)


def ppc_summary(prob: Problem, band: dict[str, Any]) -> dict[str, Any]:
    return {
        "draws": int(band["n"]),
        "noise": "the likelihood fit's noise model (model error included)",
        # None when no posterior draw simulated successfully (no band to compare with).
        "fraction_inside_90pct_band": band_coverage(prob, band, prob.train),
        "fraction_inside_90pct_band_held_out": band_coverage(prob, band, prob.held),
    }
