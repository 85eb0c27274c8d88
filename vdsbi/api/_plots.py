"""Figures: posterior pair plot, posterior predictive check, a simulated drive."""

from __future__ import annotations

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


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def pairplot(
    samples: np.ndarray,
    labels: Sequence[str],
    path: str | os.PathLike,
    truth: np.ndarray | None = None,
    title: str | None = None,
) -> None:
    """Histograms on the diagonal, scatter below it, of (N, d) `samples`; `truth` in red."""
    plt = _pyplot()
    d = samples.shape[1]
    fig, axes = plt.subplots(d, d, figsize=(2.0 * d, 2.0 * d))
    for i in range(d):
        for j in range(d):
            ax = axes[i, j]
            if j > i:
                ax.axis("off")
                continue
            if i == j:
                ax.hist(samples[:, i], bins=40, color="C0", alpha=0.8)
                if truth is not None:
                    ax.axvline(truth[i], color="r")
            else:
                ax.scatter(samples[:, j], samples[:, i], s=1, alpha=0.3, color="C0")
                if truth is not None:
                    ax.plot(truth[j], truth[i], "r+", ms=10)
            if i == d - 1:
                ax.set_xlabel(labels[j])
            if j == 0 and i > 0:
                ax.set_ylabel(labels[i])
            ax.tick_params(labelsize=6)
    if title is not None:
        fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def ppc_plot(prob: Any, ppc: dict[str, np.ndarray], path: str | os.PathLike) -> None:
    """Per compared channel of a `Problem`: the recording over the posterior-predictive median
    and 90 % band, window by window; held-out windows (or parts) shaded grey."""
    plt = _pyplot()
    c = len(prob.channels)
    fig, axes = plt.subplots(c, 1, figsize=(11, 2.0 * c), sharex=True)
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
    plt.close(fig)


def drive_plot(rec: Any, theta: np.ndarray, effects: Sequence[str], path: str | os.PathLike) -> None:
    """A recording's inputs and six channels against time, one panel each (PNG)."""
    plt = _pyplot()
    fig, axes = plt.subplots(4, 2, figsize=(11, 9), sharex=True)
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
    plt.close(fig)
