"""report.json, report.md and figures of a diagnosis."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from ..simulator._vehicle import CHANNELS

REQUIRED_KEYS = ("mismatch_detected", "p_value", "located", "effects", "chosen", "fit", "theta")


def _json_default(o):
    if isinstance(o, (np.floating, np.integer)):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, np.bool_):
        return bool(o)
    raise TypeError(type(o))


def markdown(rep: dict) -> str:
    L = [f"# Mismatch diagnosis: {rep['source']}", ""]
    if "verdict" in rep:
        L += [f"**Verdict: {rep['verdict']}.**", ""]
    det = "**detected**" if rep["mismatch_detected"] else "not detected"
    L.append(
        f"Misspecification of the base model: {det} (p = {rep['p_value']:.4g} at α = {rep['alpha']:g}); "
        f"after the fix p = {rep['p_value_after']:.4g}."
    )
    loc = rep["located"]
    L.append("")
    L.append(f"- channels: {', '.join(loc['channels']) or '—'}")
    L.append(f"- time windows (s): {', '.join(f'{a:.1f}–{b:.1f}' for a, b in loc['windows']) or '—'}")
    L.append(f"- bands (Hz): {', '.join(f'{a:g}–{b:g}' for a, b in loc['bands_hz']) or '—'}")
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
    L += ["", "## Candidate explanations (log Bayes factor vs none, BIC)", ""]
    L.append("| rank | candidate | score | probability | parameters (± std) |")
    L.append("|---|---|---|---|---|")
    for i, e in enumerate(rep["effects"][:12]):
        ps = "; ".join(
            f"{eff}.{k} = {v:.4g} ± {e['params_std'][eff][k]:.2g}"
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
    L += ["", "## Look-alike effects", ""]
    for g in rep["separability"]:
        for p in g["pairs"]:
            L.append(f"- {p['a']} vs {p['b']}: {p['verdict']}")
    L += ["", "## Held-out fit (last part of each window, not used for fitting)", ""]
    if rep.get("held_out_improved") is False:
        L.append(
            "**The chosen effect does not improve the held-out fit**: on the fitted part it is "
            "absorbing some other mismatch; do not take it as the missing physics."
        )
        L.append("")
    L.append("| channel | NRMSE before | NRMSE after | χ²/dof before | χ²/dof after |")
    L.append("|---|---|---|---|---|")
    for ch, b in rep["fit"]["before"].items():
        a = rep["fit"]["after"][ch]
        L.append(
            f"| {ch} | {b['nrmse']:.4f} | {a['nrmse']:.4f} | {b['chi2_dof']:.3f} | {a['chi2_dof']:.3f} |"
        )
    L += ["", "## Parameters", ""]
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
    L += [
        "",
        f"Noise model: {rep['noise']['model']}; σ = "
        + ", ".join(f"{c} {s:.3g} ({rep['noise']['source'][c]})" for c, s in rep["noise"]["sigma"].items()),
        "",
        "If σ is estimated (no noise_std in the vehicle file) or the noise is coloured (vibration), "
        "χ² differences and hence the evidence and ranking odds are overstated.",
    ]
    if rep["recording_warnings"]:
        L += ["", "Recording warnings:"] + [f"- {w}" for w in rep["recording_warnings"]]
    L.append(f"\nTook {rep['seconds']:.0f} s.")
    return "\n".join(L) + "\n"


def write_report(result, out: Path, plots: bool = True) -> None:
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    rep = result.report
    (out / "report.json").write_text(json.dumps(rep, indent=2, default=_json_default) + "\n")
    (out / "report.md").write_text(markdown(rep))
    if plots:
        write_plots(result, out)


def write_plots(result, out: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    win = result.windows
    chans = win.channels
    # Residual heat map: channel × time, low-passed whitened residual of the base fit.
    res = result.residual_stretches["before"]
    ts = result.residual_stretches["t"]
    m = max(1, int(round(0.25 / win.dt)))
    kern = np.ones(m) / m
    sm = np.stack(
        [
            np.stack([np.convolve(res[w, :, c], kern, "same") for c in range(len(chans))])
            for w in range(res.shape[0])
        ]
    )
    fig, axes = plt.subplots(1, res.shape[0], figsize=(10, 0.5 * len(chans) + 2), squeeze=False)
    vmax = max(3.0, float(np.percentile(np.abs(sm), 99)))
    for w in range(res.shape[0]):
        ax = axes[0, w]
        im = ax.imshow(
            sm[w],
            aspect="auto",
            cmap="RdBu_r",
            vmin=-vmax,
            vmax=vmax,
            extent=[ts[w, 0], ts[w, -1], len(chans) - 0.5, -0.5],
        )
        ax.set_yticks(range(len(chans)), chans if w == 0 else [""] * len(chans))
        ax.set_xlabel("t [s]")
    fig.colorbar(im, ax=axes[0, -1], label="whitened residual, 0.25 s mean")
    fig.suptitle("Base-model residual (training part)")
    fig.savefig(out / "residual_heatmap.png", dpi=110, bbox_inches="tight")
    plt.close(fig)
    # Before/after overlays per channel.
    p0, p1 = result.predictions["before"], result.predictions["after"]
    fig, axes = plt.subplots(len(chans), 1, figsize=(10, 1.8 * len(chans)), sharex=True, squeeze=False)
    for c, name in enumerate(chans):
        ax = axes[c, 0]
        k = CHANNELS.index(name)
        for w in range(win.num_windows):
            v = win.valid[w]
            ax.plot(win.t[w][v], win.y[w, v, c], color="0.6", lw=0.6, label="measured" if w == 0 else None)
            ax.plot(win.t[w][v], p0[w, v, k], color="C3", lw=1, label="before" if w == 0 else None)
            ax.plot(win.t[w][v], p1[w, v, k], color="C0", lw=1, label="after" if w == 0 else None)
            ax.axvline(win.t_train_end[w], color="k", ls=":", lw=0.8)
        ax.set_ylabel(name)
    axes[0, 0].legend(loc="upper right", fontsize=7, ncol=3)
    axes[-1, 0].set_xlabel("t [s] (dotted: held-out part starts)")
    fig.savefig(out / "overlay.png", dpi=110, bbox_inches="tight")
    plt.close(fig)
    # Residual spectra before/after.
    fig, axes = plt.subplots(len(chans), 1, figsize=(8, 1.6 * len(chans)), sharex=True, squeeze=False)
    for key, col in (("before", "C3"), ("after", "C0")):
        r = result.residual_stretches[key]
        spec = (np.abs(np.fft.rfft(r, axis=1)) ** 2 / r.shape[1]).mean(0)
        f = np.fft.rfftfreq(r.shape[1], win.dt)
        for c, name in enumerate(chans):
            axes[c, 0].loglog(f[1:], spec[1:, c], color=col, lw=0.7, label=key)
            axes[c, 0].set_ylabel(name)
    for c in range(len(chans)):
        axes[c, 0].axhline(1.0, color="k", ls=":", lw=0.8)
    axes[0, 0].legend(fontsize=7)
    axes[-1, 0].set_xlabel("frequency [Hz] (dotted: white noise level)")
    fig.savefig(out / "residual_spectra.png", dpi=110, bbox_inches="tight")
    plt.close(fig)
