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
from ._markdown import markdown
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


def write_report(result: DiagnosisResult, out: Path, plots: bool = True) -> None:
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    rep = result.report
    (out / "report.json").write_text(json.dumps(rep, indent=2, default=_json_default) + "\n")
    (out / "report.md").write_text(markdown(rep))
    if plots:
        write_plots(result, out)
