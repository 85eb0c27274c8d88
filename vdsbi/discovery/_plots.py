"""The diagnosis's figures: residual heat map, measured vs before/after overlays, residual spectra."""

from __future__ import annotations

from pathlib import Path

import numpy as np


def write_plots(result, out: Path) -> None:
    """residual_heatmap.png, overlay.png and residual_spectra.png in ``out``."""
    # Figures outside pyplot's global state, so that plotting is safe on any thread.
    from matplotlib.figure import Figure

    plots = {
        "residual_heatmap.png": _plot_residual_heatmap,
        "overlay.png": _plot_overlay,
        "residual_spectra.png": _plot_residual_spectra,
    }
    for name, plot in plots.items():
        fig = plot(Figure, result)
        fig.savefig(out / name, dpi=110, bbox_inches="tight")


def _plot_residual_heatmap(figure, result):
    """Channel × time, the low-passed whitened residual of the base fit."""
    win = result.windows
    chans = win.channels
    res = result.residual_stretches["before"]
    ts = result.residual_stretches["t"]
    dt = win.compared_dt
    m = max(1, int(round(0.25 / dt)))
    kern = np.ones(m) / m
    sm = np.stack(
        [
            np.stack([np.convolve(res[w, :, c], kern, "same") for c in range(len(chans))])
            for w in range(res.shape[0])
        ]
    )
    fig = figure(figsize=(max(10, 1.2 * res.shape[0]), 0.5 * len(chans) + 2))
    axes = fig.subplots(1, res.shape[0], squeeze=False)
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
    return fig


def _plot_overlay(figure, result):
    """Measured, before and after per channel; held-out parts shaded."""
    win = result.windows
    chans = win.channels
    p0, p1 = result.predictions["before"], result.predictions["after"]
    fig = figure(figsize=(10, 1.8 * len(chans)))
    axes = fig.subplots(len(chans), 1, sharex=True, squeeze=False)
    for c, name in enumerate(chans):
        ax = axes[c, 0]
        for w in range(win.num_windows):
            v = win.valid[w]
            t = win.t_out[w]
            ax.plot(t[v], win.y[w, v, c], color="0.6", lw=0.6, label="measured" if w == 0 else None)
            ax.plot(t[v], p0[w, v, c], color="C3", lw=1, label="before" if w == 0 else None)
            ax.plot(t[v], p1[w, v, c], color="C0", lw=1, label="after" if w == 0 else None)
            if win.held[w].any():
                ax.axvspan(t[win.held[w]].min(), t[win.held[w]].max(), color="0.92", zorder=0)
        ax.set_ylabel(name)
    axes[0, 0].legend(loc="upper right", fontsize=7, ncol=3)
    axes[-1, 0].set_xlabel("t [s] (grey: held out)")
    return fig


def _plot_residual_spectra(figure, result):
    """Residual power spectra before and after, against the white-noise level."""
    chans = result.windows.channels
    dt = result.windows.compared_dt
    fig = figure(figsize=(8, 1.6 * len(chans)))
    axes = fig.subplots(len(chans), 1, sharex=True, squeeze=False)
    for key, col in (("before", "C3"), ("after", "C0")):
        r = result.residual_stretches[key]
        spec = (np.abs(np.fft.rfft(r, axis=1)) ** 2 / r.shape[1]).mean(0)
        f = np.fft.rfftfreq(r.shape[1], dt)
        for c, name in enumerate(chans):
            axes[c, 0].loglog(f[1:], spec[1:, c], color=col, lw=0.7, label=key)
            axes[c, 0].set_ylabel(name)
    for c in range(len(chans)):
        axes[c, 0].axhline(1.0, color="k", ls=":", lw=0.8)
    axes[0, 0].legend(fontsize=7)
    axes[-1, 0].set_xlabel("frequency [Hz] (dotted: white noise level)")
    return fig
