"""report.html of `identify` and `diagnose`: the tables and the pictures of a folder on one page."""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from scipy.stats import binom

from ..diagnostics import ridge_sentence
from ..problem import parameter_name
from ..simulator import PARAM_UNITS
from . import _html as H
from ._export import identified_status
from ._held_out import held_out_verdict
from .plots import display_unit

#: Files `identify` leaves beside its page.
IDENTIFY_FILES = (
    "posterior.json",
    "samples.csv",
    "predictive_draws.csv",
    "run.json",
    "estimator.npz",
    "pairplot.png",
    "ppc.png",
)
DIAGNOSE_FILES = ("report.json", "report.md", "residual_heatmap.png", "overlay.png", "residual_spectra.png")


def fmt(value: float | None, unit: str = "") -> str:
    """`value` in `unit`'s readable scale (kN/rad, not 72000), 4 significant digits."""
    if value is None:
        return "–"
    return f"{value * display_unit(unit)[0]:.4g}"


def parameter_rows(params: Mapping[str, Any]) -> list[list[str]]:
    """Rows name, unit, estimate, std, 90 % interval, prior, identified: every estimate (what
    `export` writes and `predict` simulates), and whether the drive identifies it alone."""
    rows = []
    for n, p in params.items():
        u = p["unit"]
        lo, hi = p["prior"]
        row = [n, display_unit(u)[1], fmt(p.get("estimate", p["mean"]), u), fmt(p["std"], u)]
        row.append(f"[{fmt(p['q05'], u)}, {fmt(p['q95'], u)}]")
        row.append(f"[{fmt(lo, u)}, {fmt(hi, u)}]")
        rows.append([*row, identified_cell(p)])
    return rows


def identified_cell(p: Mapping[str, Any]) -> str:
    return identified_status(p, "yes", "no")


PARAM_HEADER = ["parameter", "unit", "estimate", "std", "90 % interval", "prior", "identified alone"]


def combination_rows(summary: Mapping[str, Any]) -> list[list[str]]:
    """Rows quantity, estimate, 95 % interval, unit, identified: the understeer gradient and the
    steady-state yaw-rate gain the drive determines."""
    comb = summary.get("combinations") or {}
    names = {"understeer_gradient": "understeer gradient", "yaw_rate_gain": "steady-state yaw-rate gain"}
    rows = []
    for key, name in names.items():
        c = comb.get(key)
        if not c:
            continue
        at = f" at {c['at']:g} m/s" if c.get("at") else ""
        told = "–" if "identified" not in c else ("yes" if c["identified"] else "no: near its prior spread")
        rows.append([name + at, fmt(c["median"]), f"[{fmt(c['q025'])}, {fmt(c['q975'])}]", c["unit"], told])
    return rows


def trading_pair_lines(summary: Mapping[str, Any]) -> list[str]:
    """One sentence per pair of parameters that trade along a ridge, with the step along it."""
    params = summary["parameters"]
    lines = []
    for pair in (summary.get("combinations") or {}).get("trading_pairs", []):
        step = " with ".join(
            f"{pair['direction'][n] * display_unit(params[n]['unit'])[0]:+.3g} "
            f"{display_unit(params[n]['unit'])[1]} of {n}"
            for n in pair["pair"]
        )
        lines.append(
            f"{ridge_sentence(pair)}: {step} leaves the fit about unchanged. The drive determines "
            "them together, not each alone."
        )
    return lines


def data_split(summary: Mapping[str, Any]) -> str:
    """How the estimate was fitted and how it was validated: the estimate is the fit of all the
    usable driving, the validation a fit of the training part scored on the held-out part (the
    grey part of the fit figure)."""
    problem = summary["problem"]
    windows = len(problem.get("windows", ()))
    seconds = problem.get("train_seconds", 0)
    fitted = f"the estimate fits all the usable driving ({seconds:g} s fitted in {windows} window(s))"
    val = summary.get("validation") or {}
    if not val:
        return f"{fitted}; nothing held out to validate on"
    split = val.get("split") or "the last part of the usable driving held out"
    held = val.get("estimate", {}).get("held_out_seconds")
    held = "" if held is None else f", {held:g} s"
    return (
        f"{fitted}; validated before that by a fit of the rest, scored on the held-out part "
        f"({split}{held}; grey below)"
    )


def held_out_block(summary: Mapping[str, Any]) -> str:
    """Whether the estimate predicts the held-out part, by the rule `export` applies."""
    verdict = held_out_verdict(summary)
    if not verdict.scored:
        return ""
    if verdict.passed:
        return H.paragraph(f"The estimate predicts the {verdict.describe()}: `vdsbi export` writes it.", "ok")
    return H.paragraph(
        f"The estimate fails the held-out part ({'; '.join(verdict.failures)}): `vdsbi export --format "
        "autoware` refuses it.",
        "warn",
    )


def warnings_block(summary: Mapping[str, Any]) -> str:
    ws = summary.get("warnings") or []
    if not ws:
        return H.paragraph(
            "No warning: no posterior mass piled at the prior's edges, and the predictive band "
            "covers every channel.",
            "ok",
        )
    return "".join(H.paragraph("Warning: " + w["message"], "warn") for w in ws)


def validation_rows(summary: Mapping[str, Any]) -> list[list[str]]:
    """Per channel: held-out NRMSE and χ²/dof of the estimate (the fit of the training part), of the
    neural posterior's mean and of the reference, share of the recording inside the 90 %
    predictive band (fitted / held out)."""
    val = summary.get("validation", {})
    mean = val.get("estimate", {}).get("channels", {})
    point = val.get("npe_mean", {}).get("channels", {})
    ref = val.get("reference", {}).get("channels", {})
    ppc = summary.get("ppc", {})
    inside = ppc.get("fraction_inside_90pct_band", {})
    held = ppc.get("fraction_inside_90pct_band_held_out", {})
    pct = lambda v: "–" if v is None else f"{v:.0%}"
    rows = []
    for c in summary["channels"]:
        m = mean.get(c, {})
        row = [c, fmt(m.get("nrmse")), fmt(m.get("chi2_dof"))]
        if point:
            row += [fmt(point.get(c, {}).get("nrmse")), fmt(point.get(c, {}).get("chi2_dof"))]
        if ref:
            row += [fmt(ref.get(c, {}).get("nrmse")), fmt(ref.get(c, {}).get("chi2_dof"))]
        rows.append([*row, pct(inside.get(c)), pct(held.get(c))])
    return rows


def validation_header(summary: Mapping[str, Any]) -> list[str]:
    val = summary.get("validation", {})
    head = ["channel", "held-out NRMSE", "held-out χ²/dof"]
    head += ["NPE mean NRMSE", "NPE mean χ²/dof"] if "npe_mean" in val else []
    head += ["reference NRMSE", "reference χ²/dof"] if "reference" in val else []
    return [*head, "inside 90 % band (fitted)", "inside 90 % band (held out)"]


def identify_page(summary: Mapping[str, Any], folder: str | os.PathLike, also: Sequence[Path] = ()) -> str:
    """The page of an identify folder (pictures read from `folder`)."""
    folder = Path(folder)
    effects = ", ".join(summary.get("effects") or []) or "none"
    return H.page(
        f"vdsbi identify: {summary['recording']}",
        [
            H.paragraph(
                f"Effects in θ: {effects}; {data_split(summary)}; channels {', '.join(summary['channels'])}."
            ),
            warnings_block(summary),
            H.heading("Posterior"),
            H.table(PARAM_HEADER, parameter_rows(summary["parameters"])),
            H.heading("What the drive determines"),
            H.table(
                ["quantity", "estimate", "95 % interval", "unit", "identified"], combination_rows(summary)
            ),
            *(H.paragraph(line, "warn") for line in trading_pair_lines(summary)),
            H.figure(folder / "pairplot.png", "Posterior pair plot over the prior box."),
            H.heading("Fit to the recording"),
            H.table(validation_header(summary), validation_rows(summary)),
            held_out_block(summary),
            H.figure(
                folder / "ppc.png",
                "Recording over the posterior-predictive median and 90 % band; grey: held out.",
            ),
            H.links(folder, IDENTIFY_FILES, also),
        ],
    )


def diagnose_page(rep: Mapping[str, Any], folder: str | os.PathLike) -> str:
    """The page of a diagnose folder."""
    folder = Path(folder)
    det = "detected" if rep["mismatch_detected"] else "not detected"
    loc = rep["located"]
    cand = [
        [e["name"], f"{e['score']:.1f}", f"{e['probability']:.3f}", _effect_values(e)]
        for e in rep["effects"][:8]
    ]
    fit = [
        [c, fmt(b["nrmse"]), fmt(rep["fit"]["after"][c]["nrmse"])]
        + [fmt(b["chi2_dof"]), fmt(rep["fit"]["after"][c]["chi2_dof"])]
        for c, b in rep["fit"]["before"].items()
    ]
    theta = [
        [
            k,
            display_unit(PARAM_UNITS[k])[1],
            fmt(v, PARAM_UNITS[k]),
            fmt(rep["theta"]["after"][k], PARAM_UNITS[k]),
        ]
        for k, v in rep["theta"]["before"].items()
    ]
    return H.page(
        f"vdsbi diagnose: {rep['source']}",
        [
            H.paragraph(f"Verdict: {rep['verdict']}.", "ok" if rep.get("explained") else "warn"),
            H.paragraph(
                f"Misspecification {det} (p = {rep['p_value']:.3g}, α = {rep['alpha']:g}); after the "
                f"fix p = {rep['p_value_after']:.3g}. Located on channels "
                f"{', '.join(loc['channels']) or '–'}; bands (Hz) "
                f"{', '.join(f'{a:g}–{b:g}' for a, b in loc['bands_hz']) or '–'}."
            ),
            H.heading("Next"),
            H.paragraph("The posterior with what was named modelled:"),
            H.code(rep.get("identify_command", "")),
            H.heading("Candidates (log Bayes factor vs none)"),
            H.table(["candidate", "score", "probability", "parameters"], cand),
            H.heading("Held-out fit, before → after"),
            H.table(["channel", "NRMSE before", "NRMSE after", "χ²/dof before", "χ²/dof after"], fit),
            H.figure(folder / "overlay.png", "Measured vs base model (before) and with the fix (after)."),
            H.figure(folder / "residual_heatmap.png", "Base-model residual by channel and time."),
            H.figure(folder / "residual_spectra.png", "Residual spectra before and after the fix."),
            H.heading("θ (MAP), before → after"),
            H.table(["θ", "unit", "before", "after"], theta),
            H.links(folder, DIAGNOSE_FILES),
        ],
    )


def _effect_values(e: Mapping[str, Any]) -> str:
    return "; ".join(
        f"{parameter_name(eff, k)} = {v:.3g} ± {e['params_std'][eff][k]:.2g}"
        for eff, d in e["params"].items()
        for k, v in d.items()
    )


def demo_page(
    truth: Mapping[str, float],
    runs: Sequence[tuple[str, str, Mapping[str, Any]]],
    diagnosis: Mapping[str, Any] | None,
    folder: str | os.PathLike,
    concealed: str,
) -> str:
    """The demo's before/after page.

    Args:
        truth: true values by parameter name (θ and the concealed effect's parameters).
        runs: (label, subfolder, posterior.json summary) of each identification, in order.
        diagnosis: the diagnosis report (None: not run).
        concealed: what the drive hid, in words.
    """
    folder = Path(folder)
    labels = [label for label, _, _ in runs]
    held = [[c, *(_held_chi2(summ, c) for _, _, summ in runs)] for c in runs[0][2]["channels"]]
    subpages = [f"{sub}/report.html" for _, sub, _ in runs] + (["diagnose/report.html"] if diagnosis else [])
    return H.page(
        f"vdsbi demo: a concealed {concealed}, found and modelled",
        [
            *_demo_steps(runs, diagnosis, concealed),
            H.heading("Parameters: truth, before and after"),
            H.table(
                ["parameter", "unit", "truth"] + [f"{label}: estimate [90 %]" for label in labels],
                _truth_rows(truth, runs),
            ),
            *(H.paragraph(line) for line in _interval_tally(truth, runs)),
            H.heading("Held-out driving: χ²/dof of each estimate (1: the sensor-noise level)"),
            H.table(["channel", *labels], held),
            H.figure(
                folder / "before_after.png",
                "Posterior marginals over the prior box (black: truth) and the "
                "held-out recording against each posterior's 90 % predictive band.",
            ),
            *(
                H.figure(folder / f"pairplot_{k}.png", f"Pair plot, {label} (red: truth).")
                for k, label in enumerate(labels)
            ),
            H.links(folder, [*subpages, "truth.json", "recording.csv", "vehicle.json"]),
        ],
    )


def _held_chi2(summ: Mapping[str, Any], channel: str) -> str:
    """The estimate's held-out χ²/dof of a channel ('–' where it did not simulate)."""
    val = summ.get("validation", {})
    return fmt(val.get("estimate", {}).get("channels", {}).get(channel, {}).get("chi2_dof"))


def _demo_steps(runs, diagnosis, concealed: str) -> list[str]:
    """The story, one coloured paragraph a step: flagged or not, what diagnose named."""
    steps = [
        H.paragraph(f"1. Simulated a drive of the built-in car with a concealed {concealed} (truth.json).")
    ]
    for k, (label, sub, summ) in enumerate(runs):
        flagged = [w for w in summ.get("warnings", ()) if w.get("kind") != "recording"]
        note = "flagged: " + " ".join(w["message"] for w in flagged) if flagged else "no warning"
        step = 2 if k == 0 else 4
        steps.append(
            H.paragraph(
                f"{step}. identify, {label} ({sub}/report.html): {note}.", "warn" if flagged else "ok"
            )
        )
        if k == 0 and diagnosis is not None:
            steps.append(
                H.paragraph(
                    f"3. diagnose (diagnose/report.html): {diagnosis['verdict']}; named: "
                    f"{', '.join(diagnosis['chosen']) or 'none'}; "
                    f"next: {diagnosis.get('identify_command', '')}",
                    "ok" if diagnosis.get("explained") else "warn",
                )
            )
    return steps


def _truth_rows(truth: Mapping[str, float], runs) -> list[list[str]]:
    """Per parameter of the last run: unit, truth, and each run's estimate [90 %] (✓/✗ truth inside)."""
    rows = []
    for n, last in runs[-1][2]["parameters"].items():
        unit = last["unit"]
        row = [n, display_unit(unit)[1], fmt(truth.get(n), unit)]
        for _, _, summ in runs:
            p = summ["parameters"].get(n)
            row.append("not in the model" if p is None else _with_interval(p, truth.get(n)))
        rows.append(row)
    return rows


def _interval_tally(truth: Mapping[str, float], runs) -> list[str]:
    """Per run, how many truths fall outside their 90 % intervals against what chance gives: a
    tenth of them, and k or more misses in P(≥ k) of drives (binomial)."""
    lines = []
    for label, _, summ in runs:
        scored = [
            (n, p)
            for n, p in summ["parameters"].items()
            if p.get("identified") is not False and truth.get(n) is not None
        ]
        missed = [n for n, p in scored if not p["q05"] <= truth[n] <= p["q95"]]
        if not scored:
            continue
        chance = binom.sf(len(missed) - 1, len(scored), 0.1) if missed else 1.0
        lines.append(
            f"{label}: {len(missed)} of {len(scored)} truths outside their 90 % intervals"
            + (f" ({', '.join(missed)})" if missed else "")
            + f"; intervals that hold 90 % leave {0.1 * len(scored):.1f} out on average, and "
            f"{len(missed)} or more on {chance:.0%} of drives."
        )
    return lines


def _with_interval(p: Mapping[str, Any], truth: float | None) -> str:
    """'estimate [q05, q95]' (✓ when the truth lies inside, ✗ when not)."""
    if p.get("identified") is False:
        return "not identified"
    u = p["unit"]
    mark = "" if truth is None else (" ✓" if p["q05"] <= truth <= p["q95"] else " ✗")
    return f"{fmt(p.get('estimate', p['mean']), u)} [{fmt(p['q05'], u)}, {fmt(p['q95'], u)}]{mark}"
