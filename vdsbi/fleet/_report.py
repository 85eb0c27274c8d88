"""report.html: per car, each identified parameter against its drives with the 90 % intervals and
the changes marked; per platform, which level answered and the misfit its drives share (each
channel's residual scale over its sensor noise)."""

from __future__ import annotations

import base64
import html
import io
from pathlib import Path

import numpy as np

from ..io import write_text_atomically

#: Marker per method.
MARKERS = {"amortized": "o", "amortized+fit": "s", "identify": "D"}


def _png(fig) -> str:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=90, bbox_inches="tight")
    return base64.b64encode(buf.getvalue()).decode()


def _car_figure(drives: list[dict], changes: list, names: list[str]) -> str:
    """One panel per parameter: median and 90 % interval per drive, changes as vertical lines."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=(7.5, 1.6 * len(names) + 0.4))
    axes = fig.subplots(len(names), 1, sharex=True, squeeze=False)[:, 0]
    index = {r["time"]: i for i, r in enumerate(drives)}
    for ax, name in zip(axes, names):
        for i, r in enumerate(drives):
            p = r["parameters"].get(name)
            if p is None:
                continue
            color = "C0" if p["identified"] else "0.7"
            ax.errorbar(
                i,
                p["q50"],
                yerr=[[p["q50"] - p["q05"]], [p["q95"] - p["q50"]]],
                fmt=MARKERS.get(r["method"], "x"),
                color=color,
                capsize=3,
                ms=5,
            )
        for c in changes:
            if c.parameter == name and c.time in index:
                ax.axvline(index[c.time] - 0.5, color="C3", ls="--", lw=1.2)
        ax.set_ylabel(name, fontsize=8, rotation=0, ha="right")
        ax.tick_params(labelsize=7)
    axes[-1].set_xticks(range(len(drives)))
    axes[-1].set_xticklabels([r["time"] for r in drives], rotation=30, ha="right", fontsize=7)
    return _png(fig)


def write_report(
    path: Path, records: list[dict], changes: list, seconds: float | None = None, misfits: list = ()
) -> None:
    """Write the fleet's report.html."""
    answered = [r for r in records if r.get("parameters")]
    failed = [r for r in records if r.get("method") == "failed"]
    parts = [
        "<!doctype html><html><head><meta charset='utf-8'><title>vdsbi fleet</title>",
        "<style>body{font-family:sans-serif;max-width:960px;margin:auto}table{border-collapse:collapse}"
        "td,th{border:1px solid #ccc;padding:2px 6px;font-size:13px}</style></head><body>",
        "<h1>Fleet report</h1>",
        f"<p>{len(answered)} drives answered, {len(failed)} failed"
        + (f", {seconds:.0f} s this run" if seconds is not None else "")
        + ". Markers: ○ amortized, □ amortized + likelihood fit, ◇ full identify; grey: not identified by"
        " that drive; red dashed: a change detected (CUSUM over the drives' posteriors).</p>",
    ]
    parts += _platforms(answered)
    parts += _misfits(misfits)
    if failed:
        parts.append("<h2>Failed drives</h2><table><tr><th>car</th><th>recording</th><th>error</th></tr>")
        parts += [
            f"<tr><td>{html.escape(r['car'])}</td><td>{html.escape(r['recording'])}</td>"
            f"<td>{html.escape(r.get('error', ''))}</td></tr>"
            for r in failed
        ]
        parts.append("</table>")
    by_car: dict[str, list[dict]] = {}
    for r in answered:
        by_car.setdefault(r["car"], []).append(r)
    for car, drives in by_car.items():
        mine = [c for c in changes if c.car == car]
        names = [
            n
            for n in drives[0]["parameters"]
            if any(d["parameters"].get(n, {}).get("identified") for d in drives)
        ]
        parts.append(f"<h2>{html.escape(car)}</h2>")
        if mine:
            parts.append(
                "<ul>"
                + "".join(
                    f"<li>{html.escape(c.parameter)} from {html.escape(c.time)}: "
                    f"{c.before:.4g} → {c.after:.4g}</li>"
                    for c in mine
                )
                + "</ul>"
            )
        if names:
            parts.append(
                f"<img alt='{html.escape(car)}' "
                f"src='data:image/png;base64,{_car_figure(drives, changes, names)}'>"
            )
    parts.append("</body></html>")
    write_text_atomically(path, "\n".join(parts) + "\n")


def _platforms(records: list[dict]) -> list[str]:
    """Per platform: drives per method, and each channel's median residual scale over its sensor
    noise (≈ 1 where the model explains the drives; a channel well above 1 on most drives is a
    misfit the platform shares: `vdsbi diagnose` on one of them names it)."""
    by: dict[str, list[dict]] = {}
    for r in records:
        by.setdefault(r.get("platform") or "none", []).append(r)
    out = [
        "<h2>Platforms</h2><table><tr><th>platform</th><th>drives</th><th>methods</th>"
        "<th>residual / sensor noise (median over drives)</th></tr>"
    ]
    for plat, rs in by.items():
        methods = {m: sum(r["method"] == m for r in rs) for m in sorted({r["method"] for r in rs})}
        ratios: dict[str, list[float]] = {}
        for r in rs:
            for c, v in (r.get("noise_ratio") or {}).items():
                ratios.setdefault(c, []).append(v)
        misfit = ", ".join(f"{c} {np.median(v):.2f}" for c, v in ratios.items())
        text = ", ".join(f"{m} {n}" for m, n in methods.items())
        out.append(f"<tr><td>{html.escape(plat)}</td><td>{len(rs)}</td><td>{text}</td><td>{misfit}</td></tr>")
    out.append("</table>")
    return out


def _misfits(misfits) -> list[str]:
    """What each pooled diagnosis found, linked to its own report."""
    if not misfits:
        return []
    out = [
        "<h2>Misfit</h2><p>`vdsbi diagnose` on pooled drives: each platform's (the latest drive of "
        "its cars) and each car's whose model error stands out from its platform's.</p>",
        "<table><tr><th>scope</th><th>drives</th><th>detected</th><th>named</th><th>claimed</th>"
        "<th>verdict</th></tr>",
    ]
    for m in misfits:
        scope = f"platform {m.platform}" if m.car is None else f"car {m.car}"
        link = f"<a href='{html.escape(m.folder)}/report.html'>{html.escape(scope)}</a>"
        out.append(
            f"<tr><td>{link}</td><td>{len(m.drives)}</td><td>{'yes' if m.detected else 'no'}</td>"
            f"<td>{html.escape(', '.join(m.named) or '–')}</td><td>{'yes' if m.claimed else 'no'}</td>"
            f"<td>{html.escape(m.verdict)}</td></tr>"
        )
    out.append("</table>")
    return out
