"""report.md: a diagnosis' report.json read as Markdown."""

from __future__ import annotations

from ..problem import parameter_name


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
