"""Figures: posterior pair plot, posterior predictive check, a simulated drive."""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Sequence
from typing import Any

import numpy as np

from ..simulator import CHANNELS, PARAM_NAMES

#: Units of the channels, for axis labels.
UNITS = {
    "ax": "m/s²",
    "ay": "m/s²",
    "yaw_rate": "rad/s",
    "omega_front": "rad/s",
    "omega_rear": "rad/s",
    "vx": "m/s",
}


def _figure(**kwargs):
    """A figure outside pyplot's global state: figures drawn on several threads (the demo
    identifies while it diagnoses) then never share a figure manager."""
    from matplotlib.figure import Figure

    return Figure(**kwargs)


#: Units shown scaled, so that axes read 72 kN/rad rather than 72000.
SCALED_UNITS = {"N/rad": (1e-3, "kN/rad"), "N": (1e-3, "kN")}


def display_unit(unit: str) -> tuple[float, str]:
    """(factor, label): a value in `unit` times factor reads in label."""
    return SCALED_UNITS.get(unit, (1.0, unit.replace("^2", "²")))


@dataclasses.dataclass(frozen=True, kw_only=True)
class ParameterAxes:
    """How a `pairplot` draws each parameter's axes (one entry per parameter; None: not used).

    Attributes:
        box: (low, high) per parameter: the axes span the prior box, so a posterior piled at an
            edge shows as such (None: the samples' range).
        units: unit per parameter, shown in the axis labels; N and N/rad are shown in kN and
            kN/rad.
        faded: parameters drawn grey (the drive cannot inform them).
    """

    box: Sequence[tuple[float, float]] | None = None
    units: Sequence[str] | None = None
    faded: Sequence[bool] | None = None


def pairplot(
    samples: np.ndarray,
    labels: Sequence[str],
    path: str | os.PathLike,
    truth: np.ndarray | None = None,
    title: str | None = None,
    *,
    axes: ParameterAxes = ParameterAxes(),
    reference: np.ndarray | None = None,
) -> None:
    """Pair plot of (N, d) `samples`: histograms on the diagonal, density contours (50 and 90 %
    of the mass) over faint points below it.

    Args:
        truth: (d,) values marked in red (NaN: unknown, not marked).
        axes: each parameter's span, unit and whether it is drawn grey (`ParameterAxes`).
        reference: (d,) values marked in green (e.g. a lab's).
    """
    box, units, faded = axes.box, axes.units, axes.faded
    d = samples.shape[1]
    scale = np.array([display_unit(u)[0] for u in units]) if units is not None else np.ones(d)
    shown = [f"{n} [{display_unit(u)[1]}]" for n, u in zip(labels, units)] if units is not None else labels
    x = samples * scale
    lim = np.asarray(box, float) * scale[:, None] if box is not None else None
    span = lim if lim is not None else _data_span(x)  # one x range per column, one y range per row
    marks = [(v * scale, c) for v, c in ((truth, "r"), (reference, "g")) if v is not None]
    # Only the lower triangle is drawn, with fixed margins: creating and laying out d² axes
    # (tight_layout) took most of a 9-parameter plot's seconds.
    width = 1.9 * d + 0.6
    fig = _figure(figsize=(width, width - 0.2))
    grid = fig.add_gridspec(
        d, d, left=0.8 / width, right=0.98, bottom=0.7 / width, top=1 - 0.6 / width, wspace=0.1, hspace=0.1
    )
    for i in range(d):
        for j in range(i + 1):
            ax = fig.add_subplot(grid[i, j])
            grey = faded is not None and (faded[i] or faded[j])
            colour = "0.6" if grey else "C0"
            if i == j:
                _diagonal(ax, x[:, i], None if lim is None else lim[i], colour, marks, i)
                ax.set_xlim(*span[i])
            else:
                _pair(ax, x[:, j], x[:, i], (span[j], span[i]), colour, marks, j, i)
            ax.tick_params(labelsize=6, labelbottom=i == d - 1, labelleft=j == 0 and i > 0)
            ax.locator_params(nbins=4)
            if i == d - 1:
                ax.set_xlabel(shown[j], fontsize=8)
            if j == 0 and i > 0:
                ax.set_ylabel(shown[i], fontsize=8)
    legend = ["blue: posterior (contours hold 50 / 90 %)"]
    legend += ["red: truth"] if truth is not None else []
    legend += ["green: reference"] if reference is not None else []
    legend += ["grey: not informed by the drive"] if faded is not None and any(faded) else []
    legend += ["axes span the prior box"] if box is not None else []
    fig.text(0.98, 0.98, "\n".join(legend), ha="right", va="top", fontsize=9)
    if title is not None:
        fig.suptitle(title, x=0.02, ha="left", fontsize=10)
    fig.savefig(path, dpi=80)


def _data_span(x: np.ndarray) -> np.ndarray:
    """(d, 2) range of each column of `x`, widened where it is a single value."""
    lo, hi = x.min(0), x.max(0)
    pad = np.where(hi > lo, 0.0, np.maximum(np.abs(lo) * 1e-3, 1e-9))
    return np.stack([lo - pad, hi + pad], 1)


def _diagonal(ax, v: np.ndarray, lim, colour: str, marks, i: int) -> None:
    """Histogram of one parameter (over its prior range when given) and the prior's flat density."""
    ax.hist(v, bins=40, range=None if lim is None else tuple(lim), density=True, color=colour, alpha=0.8)
    if lim is not None:
        ax.axhline(1.0 / (lim[1] - lim[0]), color="0.4", ls=":", lw=0.8)
        ax.set_xlim(*lim)
    for m, c in marks:
        if np.isfinite(m[i]):
            ax.axvline(m[i], color=c, lw=1.2)
    ax.set_yticks([])


def _pair(ax, vx: np.ndarray, vy: np.ndarray, lims, colour: str, marks, j: int, i: int) -> None:
    """Faint points and the 50 / 90 % highest-density contours of a smoothed 2-D histogram."""
    ax.scatter(vx, vy, s=1, alpha=0.15, color=colour, rasterized=True)
    h, xe, ye = np.histogram2d(vx, vy, bins=40, range=[tuple(r) for r in lims])
    h = _smooth(h)
    levels = _mass_levels(h, (0.9, 0.5))
    if np.all(np.diff(levels) > 0):
        xc, yc = 0.5 * (xe[1:] + xe[:-1]), 0.5 * (ye[1:] + ye[:-1])
        ax.contour(xc, yc, h.T, levels=levels, colors=colour, linewidths=(0.8, 1.3))
    ax.set_xlim(*lims[0])
    ax.set_ylim(*lims[1])
    for m, c in marks:
        if np.isfinite(m[j]) and np.isfinite(m[i]):
            ax.plot(m[j], m[i], "+", color=c, ms=11, mew=1.8)


def _smooth(h: np.ndarray) -> np.ndarray:
    """`h` convolved with a 5-bin binomial kernel along both axes (a cheap Gaussian)."""
    k = np.array([1.0, 4.0, 6.0, 4.0, 1.0]) / 16.0
    h = np.apply_along_axis(lambda r: np.convolve(r, k, "same"), 0, h)
    return np.apply_along_axis(lambda r: np.convolve(r, k, "same"), 1, h)


def _mass_levels(h: np.ndarray, masses: Sequence[float]) -> list[float]:
    """Density thresholds whose super-level sets hold `masses` of `h`, increasing."""
    flat = np.sort(h.ravel())[::-1]
    cum = np.cumsum(flat) / max(flat.sum(), 1e-300)
    return [float(flat[min(np.searchsorted(cum, m), flat.size - 1)]) for m in masses]


def ppc_plot(prob: Any, ppc: dict[str, np.ndarray], path: str | os.PathLike) -> None:
    """Per compared channel of a `Problem`: the recording over the posterior-predictive median
    and 90 % band, window by window; held-out windows (or parts) shaded grey."""
    c = len(prob.channels)
    fig = _figure(figsize=(11, 2.0 * c))
    axes = fig.subplots(c, 1, sharex=True)
    axes = np.atleast_1d(axes)
    for w in range(prob.num_windows):
        t = prob.t_out[w]
        valid = prob.valid[w]
        held = prob.held[w]
        for i, name in enumerate(prob.channels):
            ax = axes[i]
            if held.any():
                ax.axvspan(t[held].min(), t[held].max(), color="0.9", zorder=0)
            first = w == 0
            ax.fill_between(
                t[valid],
                ppc["q05"][w, valid, i],
                ppc["q95"][w, valid, i],
                color="C0",
                alpha=0.3,
                label="posterior predictive 90 %" if first else None,
            )
            ax.plot(
                t[valid],
                ppc["q50"][w, valid, i],
                color="C0",
                lw=1,
                label="predictive median" if first else None,
            )
            ax.plot(t[valid], prob.y[w, valid, i], color="k", lw=0.7, label="recording" if first else None)
            ax.set_ylabel(f"{name} [{UNITS[name]}]")
    axes[0].legend(loc="upper right", fontsize=7)
    axes[0].set_title("grey: held out (never seen by the fit)", fontsize=8, loc="left")
    axes[-1].set_xlabel("t [s]")
    for ax in axes:
        ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=90)


def drive_plot(rec: Any, theta: np.ndarray, effects: Sequence[str], path: str | os.PathLike) -> None:
    """A recording's inputs and six channels against time, one panel each (PNG)."""
    fig = _figure(figsize=(11, 9))
    axes = fig.subplots(4, 2, sharex=True)
    ax = axes[0, 0]
    ax.plot(rec.t, rec.steer, color="k")
    ax.set_ylabel("steer [rad]")
    ax = axes[0, 1]
    if rec.has_torques:
        ax.plot(rec.t, rec.torque_front, label="front")
        ax.plot(rec.t, rec.torque_rear, label="rear")
    ax.set_ylabel("axle torque [N·m]")
    ax.legend(loc="best", fontsize=8)
    for ax, c in zip(axes[1:].ravel(), CHANNELS):
        ax.plot(rec.t, rec.channels[c], lw=0.8)
        ax.set_ylabel(f"{c} [{UNITS[c]}]")
    for ax in axes[-1]:
        ax.set_xlabel("t [s]")
    for ax in axes.ravel():
        ax.grid(alpha=0.3)
    title = "simulated drive: " + ", ".join(f"{n}={v:.3g}" for n, v in zip(PARAM_NAMES, theta))
    if effects:
        title += "\neffects: " + ", ".join(effects)
    fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110, format="png")


def before_after_plot(
    runs: Sequence[tuple[str, Any]],
    truth: dict[str, float],
    path: str | os.PathLike,
    channels: Sequence[str] = ("ax", "ay", "yaw_rate"),
    title: str | None = None,
) -> None:
    """Two identifications of one drive side by side: top, each θ parameter's posterior over its
    prior box with the truth; below, the held-out recording against each run's 90 % predictive band.

    Args:
        runs: (label, `IdentifyResult` with `validation` and `ppc`) pairs, e.g. before and after
            modelling an effect (same drive, same windows).
        truth: true values by parameter name (red lines).
        channels: channels of the held-out overlay.
    """
    names = [n for n in PARAM_NAMES if n in runs[0][1].summary["parameters"]]
    fig = _figure(figsize=(13, 3.0 + 2.1 * len(channels)))
    grid = fig.add_gridspec(1 + len(channels), len(names), height_ratios=[1.2] + [1.0] * len(channels))
    colours = ("C3", "C0")
    for k, n in enumerate(names):
        ax = fig.add_subplot(grid[0, k])
        for (label, res), col in zip(runs, colours):
            p = res.summary["parameters"][n]
            f, unit = display_unit(p["unit"])
            i = list(res.summary["parameters"]).index(n)
            lo, hi = np.asarray(p["prior"]) * f
            style = dict(bins=40, range=(lo, hi), density=True, alpha=0.55, color=col, label=label)
            ax.hist(res.samples[:, i] * f, **style)
        if n in truth:
            ax.axvline(truth[n] * f, color="k", lw=1.5, label="truth")
        ax.set_xlim(lo, hi)
        ax.set_yticks([])
        ax.set_xlabel(f"{n} [{unit}]", fontsize=8)
        ax.tick_params(labelsize=7)
    fig.axes[0].legend(fontsize=7, loc="upper left")
    for r, c in enumerate(channels):
        ax = fig.add_subplot(grid[1 + r, :])
        _held_out_bands(ax, runs, c, colours)
        ax.set_ylabel(f"{c} [{UNITS[c]}]")
        ax.grid(alpha=0.3)
        if r == 0:
            ax.legend(fontsize=7, loc="upper right", ncol=3)
            ax.set_title(
                "held-out driving (never fitted): recording vs each posterior's 90 % predictive band",
                fontsize=9,
            )
    ax.set_xlabel("t [s]")
    if title:
        fig.suptitle(title, fontsize=11)
    fig.tight_layout()
    fig.savefig(path, dpi=80)


def _held_out_bands(ax, runs, channel: str, colours) -> None:
    """The held-out part of every window: each run's 90 % band and the recording."""
    prob = runs[0][1].validation
    i = list(prob.channels).index(channel)
    first = True
    for w in range(prob.num_windows):
        m = prob.held[w] & prob.valid[w]
        if not m.any():
            continue
        t = prob.t_out[w][m]
        for (label, res), col in zip(runs, colours):
            ppc = res.ppc
            ax.fill_between(
                t,
                ppc["q05"][w, m, i],
                ppc["q95"][w, m, i],
                color=col,
                alpha=0.35,
                label=label if first else None,
            )
        ax.plot(t, prob.y[w, m, i], color="k", lw=0.7, label="recording" if first else None)
        first = False
