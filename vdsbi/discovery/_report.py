"""report.json, report.md and figures of a diagnosis."""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any, NamedTuple

import numpy as np

from ..diagnostics import Localisation, MisspecificationTest
from ..problem import Problem, parameter_name
from ..simulator import PARAM_NAMES
from ._candidates import label
from ._data import held_out_from
from ._fit import Fitter
from ._plots import write_plots
from ._rank import PAIR_LOG_PRIOR, STRONG
from ._results import DiagnosisResult, DiscoveryFit, Ranked, TermDiscovery, Verdict
from ._search import describe

if TYPE_CHECKING:  # annotations only (_diagnose imports this module)
    from ..io import Recording
    from ._settings import DiagnoseSettings

REQUIRED_KEYS = ("mismatch_detected", "p_value", "located", "effects", "chosen", "fit", "theta")


def _effect_rows(ranked: Sequence[Ranked]) -> list[dict]:
    return [
        {
            "name": r.name,
            "effects": list(r.effects),
            "score": r.score,
            "log_bayes_factor": r.log_bayes_factor,
            "probability": r.probability,
            "chi2": r.chi2,
            "num_params": r.num_effect_params,
            "params": r.fit.effect_params,
            "params_std": r.fit.effect_std,
        }
        for r in ranked
    ]


def _at_bounds(fit: DiscoveryFit, fitter: Fitter, frac: float = 0.01) -> list[str]:
    """Names of fitted values within `frac` of their box's edge (the data pushed them there:
    a sign that they absorb something the model lacks)."""
    out = []
    lo, hi = np.asarray(fitter.space.theta.low), np.asarray(fitter.space.theta.high)
    for n, v, a, b in zip(PARAM_NAMES, fit.theta, lo, hi):
        if min(v - a, b - v) < frac * (b - a):
            out.append(n)
    for e, d in fit.effect_params.items():
        for (k, v), (a, b) in zip(d.items(), fitter.effects.classes[e].bounds):
            if min(v - a, b - v) < frac * (b - a):
                out.append(parameter_name(e, k))
    return out


def _theta_dict(x) -> dict:
    return {n: float(v) for n, v in zip(PARAM_NAMES, x)}


def _interval_dict(x) -> dict | None:
    return None if x is None else {n: [float(a), float(b)] for n, (a, b) in zip(PARAM_NAMES, x)}


class Findings(NamedTuple):
    """What `diagnose_mismatch` found and concluded, before it becomes a `DiagnosisResult` and a report
    (fields as `DiagnosisResult`'s, and: `held_out_shown`, the held-out scores the report
    shows; `terms_section`, the report's part on discovered terms; `search`, the forward
    search; `separability`, the look-alike verdicts; `fitter`, `coarse`, the final and search
    fitters)."""

    base: DiscoveryFit
    final: DiscoveryFit
    ranked: list[Ranked]
    test_before: MisspecificationTest
    test_after: MisspecificationTest
    localisation: Localisation
    held_out: dict
    held_out_shown: dict
    predictions: dict
    variances: dict
    residual_stretches: dict
    terms: TermDiscovery | None
    test_terms: MisspecificationTest | None
    conclusion: Verdict
    terms_section: dict
    search: Any
    separability: list[dict]
    fitter: Fitter
    coarse: Fitter


def build_report(
    recordings: Sequence[Recording], windows: Problem, s: DiagnoseSettings, f: Findings, seconds: float
) -> dict:
    """report.json's content."""
    chosen = f.conclusion.chosen
    return {
        "source": " + ".join(str(r.source) for r in recordings),
        "mismatch_detected": f.conclusion.detected,
        "p_value": float(f.test_before.p_value),
        "alpha": s.alpha,
        "p_value_after": float(f.test_after.p_value),
        "located": _located(f.localisation, f.test_before, windows),
        "effects": _effect_rows(f.ranked),
        "chosen": list(chosen),
        "base_effects": list(f.base.effects),
        "dropped": list(f.conclusion.dropped),
        "ranking_confidence": _confidence(f.ranked),
        "separability": f.separability,
        "pairs_fitted": [label(p) for p in f.search.pairs],
        "pairs_skipped": _pairs_skipped(s, s.candidate_names(), f.search.pairs),
        "search_steps": describe(f.search.steps),
        "ambiguous": _ambiguous(f.search.steps, chosen),
        "fit": f.held_out_shown,
        **f.terms_section,
        # Validation: does the chosen fix also improve the held-out part (mean χ²/dof over
        # channels)? If not, the effect is absorbing some other mismatch on the fitted part.
        "held_out_improved": f.conclusion.held_out_improved,
        "explained": f.conclusion.explained,
        "verdict": f.conclusion.text,
        **_parameters(f.base, f.final, f.fitter),
        "noise": {
            "model": "sensor noise (the test) and the model's error (the fits and the evidence): "
            "identify's noise model",
            "sigma": {c: float(x) for c, x in zip(windows.channels, windows.sigma)},
            "source": windows.noise_source,
            "base_fit": f.base.noise.to_dict(),
        },
        "windows": _window_spans(windows, s.train_fraction),
        "channels": list(windows.channels),
        "recording_warnings": [w for r in recordings for w in r.warnings],
        "method": _method(s, f.coarse, f.fitter),
        "seconds": seconds,
    }


def _parameters(base: DiscoveryFit, final: DiscoveryFit, fitter: Fitter) -> dict:
    """The fits' θ, initial speeds and effect parameters, before and after the fix."""
    return {
        "fit_train_chi2_dof": {"before": base.chi2_dof, "after": final.chi2_dof},
        "theta": {"before": _theta_dict(base.theta), "after": _theta_dict(final.theta)},
        "theta_std": {"before": _theta_dict(base.theta_std), "after": _theta_dict(final.theta_std)},
        "theta_q05_q95": {
            "before": _interval_dict(base.theta_interval),
            "after": _interval_dict(final.theta_interval),
        },
        "v0": {"before": base.v0.tolist(), "after": final.v0.tolist()},
        "at_bounds": _at_bounds(final, fitter),
        "effect_params": final.effect_params,
        "effect_params_std": final.effect_std,
    }


def _confidence(ranked: Sequence[Ranked]) -> dict:
    top, second = ranked[0], (ranked[1] if len(ranked) > 1 else None)
    return {
        "top": top.name,
        "probability": top.probability,
        "log_evidence_gap_to_next": float(top.score - second.score) if second else None,
        "next": second.name if second else None,
    }


def _pairs_skipped(s: DiagnoseSettings, names: Sequence[str], pairs: Sequence[tuple[str, ...]]) -> str:
    text = (
        f"forward search: effects added one at a time while the evidence gain is ≥ {STRONG:g} "
        f"(up to {s.max_effects}); {len(pairs)} sets of several effects fitted"
    )
    return text + ("" if s.candidates is None else f"; only {sorted(names)} were considered")


def _ambiguous(steps, chosen: Sequence[str]) -> list[str]:
    """Plain sentences for the chosen effects that a look-alike could replace on this drive."""
    return [
        f"{st.added} (added to {label(st.current)}, gain {st.gains[st.added]:.1f}) is not separable here "
        "from " + ", ".join(f"{e} (gain {st.gains[e]:.1f})" for e in st.ambiguous_with)
        for st in steps
        if st.added in chosen and st.ambiguous_with
    ]


def _located(loc: Localisation, test: MisspecificationTest, windows: Problem) -> dict:
    return {
        "channels": loc.channels,
        "windows": loc.windows,
        "bands_hz": loc.bands_hz,
        "channel_scores": loc.channel_scores,
        "whiteness_p": loc.whiteness,
        "input_xcorr": loc.xcorr,
        "band_power_ratio": {
            c: {f"{b[0]:g}-{b[1]:g}": float(test.band_power_ratio[i, j]) for j, b in enumerate(test.bands_hz)}
            for i, c in enumerate(windows.channels)
        },
    }


def _window_spans(windows: Problem, train_fraction: float) -> dict:
    return {
        "spans_s": [
            [float(windows.t_out[w, 0]), float(windows.t_out[w][windows.valid[w]][-1])]
            for w in range(windows.num_windows)
        ],
        "held_out_from_s": held_out_from(windows),
        # which of the diagnosed recordings each window is cut from (0 for one)
        "recording": [w.recording for w in windows.windows],
        "train_fraction": train_fraction,
        # Where the drive is at the limit the model cannot follow: located, left out, said why.
        "left_out": [r for r in _rejected(windows) if str(r[2]).startswith("limit")],
    }


def _rejected(windows: Problem) -> list:
    """The stretches the problem left out, over every recording it holds."""
    rejected = windows.description.get("rejected", [])
    if "recordings" in windows.description:  # several recordings: one list each
        return [r for per in rejected for r in (per or [])]
    return rejected


def _method(s: DiagnoseSettings, coarse: Fitter, fitter: Fitter) -> dict:
    return {
        "identification": "MAP (Levenberg–Marquardt, forward-mode Jacobian, float64) + Laplace covariance",
        "test": "max standardised low-band/high-band residual power ratio; null by simulated noise "
        f"through the linearised refit ({s.num_draws} draws)",
        "evidence": "score = BIC log Bayes factor vs 'none' + log prior odds "
        f"({PAIR_LOG_PRIOR:g} per effect beyond the first); strong if > {STRONG:g}",
        "solver_dt_s": {"search": coarse.dt, "final": fitter.dt},
    }


def _json_default(o):
    if isinstance(o, (np.floating, np.integer)):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, np.bool_):
        return bool(o)
    raise TypeError(type(o))


def markdown(rep: dict) -> str:
    """The report as Markdown: verdict, where, candidates, outside-library terms, held-out fit,
    parameters, noise and what to run next."""
    L = [f"# Mismatch diagnosis: {rep['source']}", ""]
    if "verdict" in rep:
        L += [f"**Verdict: {rep['verdict']}.**", ""]
    det = "**detected**" if rep["mismatch_detected"] else "not detected"
    L.append(
        f"Misspecification of the base model: {det} (p = {rep['p_value']:.4g} at α = {rep['alpha']:g}); "
        f"after the fix p = {rep['p_value_after']:.4g}."
    )
    for section in (_md_located, _md_candidates, _md_terms, _md_fit, _md_parameters, _md_footer):
        L += section(rep)
    return "\n".join(L) + "\n"


def _md_located(rep: dict) -> list[str]:
    loc = rep["located"]
    L = [""]
    L.append(f"- channels: {', '.join(loc['channels']) or '—'}")
    L.append(f"- time windows (s): {', '.join(f'{a:.1f}–{b:.1f}' for a, b in loc['windows']) or '—'}")
    L.append(f"- bands (Hz): {', '.join(f'{a:g}–{b:g}' for a, b in loc['bands_hz']) or '—'}")
    for a, b, why in rep.get("windows", {}).get("left_out", []):
        L.append(f"- left out {a:.1f}–{b:.1f} s: {why}")
    sig = [
        f"{ch}~{inp} {v['peak']:+.2f} @ {v['lag_s']:+.2f} s"
        for ch, d in loc["input_xcorr"].items()
        for inp, v in d.items()
        if v["significant"]
    ]
    L.append(f"- residual–input cross-correlation (significant): {'; '.join(sig) or '—'}")
    L.append(
        "- residual whiteness (Ljung–Box p): "
        + ", ".join(f"{k} {v:.2g}" for k, v in loc["whiteness_p"].items())
    )
    return L


def _md_candidates(rep: dict) -> list[str]:
    L = ["", "## Candidate explanations (log Bayes factor vs none, BIC)", ""]
    L.append("| rank | candidate | score | probability | parameters (± std) |")
    L.append("|---|---|---|---|---|")
    for i, e in enumerate(rep["effects"][:12]):
        ps = "; ".join(
            f"{parameter_name(eff, k)} = {v:.4g} ± {e['params_std'][eff][k]:.2g}"
            for eff, d in e["params"].items()
            for k, v in d.items()
        )
        L.append(f"| {i + 1} | {e['name']} | {e['score']:.1f} | {e['probability']:.3f} | {ps or '—'} |")
    rc = rep["ranking_confidence"]
    L.append("")
    L.append(
        f"Chosen: **{', '.join(rep['chosen']) or 'none'}**. Top candidate {rc['top']} has posterior "
        f"probability {rc['probability']:.3f}; log-evidence gap to {rc['next']}: "
        f"{rc['log_evidence_gap_to_next']:.1f}. {rep['pairs_skipped']}."
    )
    for a in rep.get("ambiguous", []):
        L.append(f"- ambiguous: {a}")
    return L


def _md_terms(rep: dict) -> list[str]:
    L = []
    if rep.get("discovered_terms"):
        L += ["", "## Outside the library: discovered terms", ""]
        L.append("| term | coefficient ± std | RMS change of the fit |")
        L.append("|---|---|---|")
        for t in rep["discovered_terms"]:
            rms = ", ".join(f"{c} {v:.3g}" for c, v in t["rms_change"].items() if v > 0)
            L.append(f"| {t['formula']} | {t['coefficient']:.4g} ± {t['std']:.2g} | {rms} |")
    L.append(f"\nExplanation: **{rep.get('explanation')}**.")
    L += ["", "## Look-alike effects", ""]
    for g in rep["separability"]:
        for p in g["pairs"]:
            L.append(f"- {p['a']} vs {p['b']}: {p['verdict']}")
    return L


def _md_fit(rep: dict) -> list[str]:
    L = ["", "## Held-out fit (last part of each window, not used for fitting)", ""]
    if rep.get("held_out_improved") is False:
        L.append(
            "**The chosen effect does not improve the held-out fit**: on the fitted part it is "
            "absorbing some other mismatch; do not take it as the missing physics."
        )
        L.append("")
    L.append(
        "| channel | NRMSE before | NRMSE after | χ²/dof before | χ²/dof after | "
        "χ²/dof after, predictive (noise + parameter uncertainty) |"
    )
    L.append("|---|---|---|---|---|---|")
    for ch, b in rep["fit"]["before"].items():
        a = rep["fit"]["after"][ch]
        pred = a.get("chi2_dof_predictive")
        L.append(
            f"| {ch} | {b['nrmse']:.4f} | {a['nrmse']:.4f} | {b['chi2_dof']:.3f} | {a['chi2_dof']:.3f} | "
            f"{'—' if pred is None else f'{pred:.3f}'} |"
        )
    if "after_terms" in rep["fit"]:
        L.append("")
        after_t = rep["fit"]["after_terms"].items()
        text = ", ".join(f"{ch} NRMSE {d['nrmse']:.4f}, χ²/dof {d['chi2_dof']:.3f}" for ch, d in after_t)
        L.append(f"With the discovered terms: {text}.")
    return L


def _md_parameters(rep: dict) -> list[str]:
    L = ["", "## Parameters", ""]
    if rep.get("at_bounds"):
        L.append(
            f"At the edge of their range after the fix: {', '.join(rep['at_bounds'])} — they are "
            "probably absorbing something the model lacks; treat their values with suspicion."
        )
        L.append("")
    L += ["| θ | before | after |", "|---|---|---|"]
    for k, v in rep["theta"]["before"].items():
        sb, sa = rep["theta_std"]["before"][k], rep["theta_std"]["after"][k]
        L.append(f"| {k} | {v:.5g} ± {sb:.2g} | {rep['theta']['after'][k]:.5g} ± {sa:.2g} |")
    return L


def _md_footer(rep: dict) -> list[str]:
    L = [
        "",
        f"Noise model: {rep['noise']['model']}; σ = "
        + ", ".join(f"{c} {s:.3g} ({rep['noise']['source'][c]})" for c, s in rep["noise"]["sigma"].items()),
        "",
        "The misspecification test holds the base fit's residual against σ; the fits and the evidence "
        "use identify's noise model: each channel's error scale measured at the fit, its samples "
        "counted by the residual's autocorrelation time ("
        + ", ".join(f"{c} {d['autocorrelation_time']:.1f}" for c, d in rep["noise"]["base_fit"].items())
        + " samples at the base fit).",
    ]
    if rep["recording_warnings"]:
        L += ["", "Recording warnings:"] + [f"- {w}" for w in rep["recording_warnings"]]
    L.append(f"\nTook {rep['seconds']:.0f} s.")
    if rep.get("not_claimed"):
        L += ["", "## Found, not claimed", "", rep["not_claimed"]]
    if rep.get("identify_command"):
        L += [
            "",
            "## Next",
            "",
            "The posterior with what was named modelled:",
            "",
            f"    {rep['identify_command']}",
        ]
    return L


def write_report(result: DiagnosisResult, out: Path, plots: bool = True) -> None:
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    rep = result.report
    (out / "report.json").write_text(json.dumps(rep, indent=2, default=_json_default) + "\n")
    (out / "report.md").write_text(markdown(rep))
    if plots:
        write_plots(result, out)
