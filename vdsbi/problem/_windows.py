"""Which stretches of a drive are explained, and which part of them is held out."""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from typing import TYPE_CHECKING, Literal

import numpy as np

from ..io import Recording, Segment, find_segments, forward_speed, running_mean

if TYPE_CHECKING:
    from ._problem import ProblemSettings


@dataclasses.dataclass(frozen=True)
class Window:
    """One stretch [t0, t1] s simulated from its own initial state.

    Attributes:
        t0, t1: start and end, s.
        role: "train" (fitted; its last part is held out when `split` is set), or "held"
            (held out whole).
        split: for a "train" window that is also the held-out window (a short drive), the time
            from which its samples are held out, s; None otherwise.
        recording: which recording of a problem made of several it is cut from (0 for one):
            windows of two drives that span the same times are two windows.
    """

    t0: float
    t1: float
    role: Literal["train", "held"]
    split: float | None = None
    recording: int = 0

    @property
    def duration(self) -> float:
        return self.t1 - self.t0


def _pieces(stretches: list[tuple[float, float]], max_window: float) -> list[tuple[float, float]]:
    """Cut each stretch into equal pieces no longer than `max_window`."""
    out = []
    for a, b in stretches:
        k = max(1, int(np.ceil((b - a) / max_window - 1e-9)))
        edges = np.linspace(a, b, k + 1)
        out += [(float(edges[j]), float(edges[j + 1])) for j in range(k)]
    return out


#: Window edges move by at most this fraction of the window length to a quieter moment ...
EDGE_SEARCH = 0.3
#: ... and only when the car is cornering there: below this lateral acceleration, m/s², the
#: steady-state start is already accurate and the edge stays.
QUIET = 1.0


def lateral_activity(rec: Recording, wheel_radius: float) -> np.ndarray | None:
    """(T,) how far from straight running the car is, in m/s²: |a_y| and |v_x·r| smoothed over
    0.5 s, whichever is larger; None without ay and yaw rate."""
    n = max(1, int(round(0.5 * rec.rate)))
    smooth = lambda x: running_mean(x, n)
    parts = []
    if "ay" in rec.channels:
        parts.append(np.abs(smooth(rec.channels["ay"])))
    speed = forward_speed(rec, wheel_radius)
    if "yaw_rate" in rec.channels and speed is not None:
        parts.append(np.abs(smooth(rec.channels["yaw_rate"] * speed)))
    return np.maximum.reduce(parts) if parts else None


def lateral_information_share(rec: Recording, pieces, activity: np.ndarray | None) -> float | None:
    """Share of the drive's Σ a_lat² (`lateral_activity` squared) inside `pieces` ((t0, t1) s).

    In steady cornering a tyre's slip angle, and so the lateral channels' sensitivity to its
    cornering stiffness, is proportional to the lateral acceleration: with a constant noise,
    this is the share of the stiffnesses' Fisher information the windows carry. None without
    a lateral channel or with no lateral motion at all."""
    if activity is None:
        return None
    energy = activity**2
    total = float(energy.sum())
    if not total > 0.0:
        return None
    inside = np.zeros(len(energy), dtype=bool)
    for a, b in pieces:
        inside |= (rec.t >= a - 1e-9) & (rec.t <= b + 1e-9)
    return float(energy[inside].sum()) / total


def _quiet_edges(rec: Recording, pieces, activity: np.ndarray, max_window: float):
    """Move each window start (and the matching end) to the quietest moment within
    ±EDGE_SEARCH·max_window: a window starting near straight running has a well-estimated
    initial lateral state (a drift or a counter-steer at the start is not steady)."""
    out = [list(p) for p in pieces]
    reach = EDGE_SEARCH * max_window
    for k in range(len(out)):
        a, b = out[k]
        if activity[min(int(np.searchsorted(rec.t, a)), len(activity) - 1)] < QUIET:
            continue
        joined = k > 0 and abs(out[k - 1][1] - a) < 1e-9
        lo = max(a - reach, out[k - 1][0] + 0.5 * max_window) if joined else a
        hi = min(a + reach, b - 0.5 * max_window)
        if hi <= lo:
            continue
        sel = (rec.t >= lo) & (rec.t <= hi)
        t_new = float(rec.t[sel][np.argmin(activity[sel])])
        out[k][0] = t_new
        if joined:
            out[k - 1][1] = t_new
    return [(a, b) for a, b in out]


def choose_windows(
    rec: Recording,
    settings: ProblemSettings,
    *,
    wheel_radius: float,
    min_duration: float | None = None,
    torques: bool = True,
    exclude: Sequence[tuple[float, float, str]] = (),
) -> tuple[list[Window], dict]:
    """Windows over every usable stretch of `rec`, and why; `settings` gives `max_window`,
    `burn_in`, `held_out`, `min_windows_to_split`, `max_windows` and `quiet_edges`.

    The usable driving (`vdsbi.io.find_segments`: moving and informing the lateral dynamics,
    or with `torques` the longitudinal; each stretch with a lead-in of `burn_in` s and at least
    `min_duration` s long, by default the burn-in plus a few lateral time constants at its
    speed) is cut into windows of at most `max_window` s, each edge moved to the quietest
    nearby moment (`quiet_edges`). With at least `min_windows_to_split` windows, those whose
    start lies in the last `held_out` fraction of the usable driving time are held out whole
    (validation on driving the fit never saw); a shorter drive keeps its windows and holds out
    the last `held_out` fraction of each. With `max_windows`, the longest windows are kept
    (ties by time). Stretches in `exclude` ((t0, t1, reason): limit handling) are rejected with
    their reason. With no usable stretch the whole recording is one window.

    Returns:
        windows in time order, and a description: "usable" [[t0, t1]], "rejected"
        [[t0, t1, reason]], "stretches" [[t0, t1, "kept: …" or "dropped: …"]] (the whole drive
        in time order, with the figure that decided), "seconds" {"drive", "in_windows",
        "dropped"}, "lateral_information_share" (`lateral_information_share`, absent without
        lateral channels) and "how".
    """
    max_window, burn_in, held_out = settings.max_window, settings.burn_in, settings.held_out
    min_windows_to_split, max_windows = settings.min_windows_to_split, settings.max_windows
    quiet_edges = settings.quiet_edges
    longest = min(max_window, 0.9 * rec.duration)
    segs = find_segments(
        rec,
        wheel_radius=wheel_radius,
        min_duration=None if min_duration is None else min(min_duration, longest),
        longest_minimum=longest,
        burn_in=burn_in,
        torques=torques,
        exclude=exclude,
    )
    usable, described = _usable(rec, segs)
    pieces = _pieces(usable, max_window)
    activity = lateral_activity(rec, wheel_radius)
    if quiet_edges and activity is not None:
        pieces = _quiet_edges(rec, pieces, activity, max_window)
    if max_windows is not None and len(pieces) > max_windows:
        pieces, beyond = _longest(pieces, max_windows)
        described["rejected"] = sorted(described["rejected"] + beyond)
    described.update(_coverage(rec, pieces, activity))
    windows, how = _held_out(pieces, held_out, min_windows_to_split, max_window, len(usable))
    described.setdefault("how", how)
    return windows, described


def _usable(rec: Recording, segs: Sequence[Segment]) -> tuple[list[tuple[float, float]], dict]:
    """The usable (t0, t1) of `segs` (the whole recording when none is), and their description."""
    usable = [(s.t0, s.t1) for s in segs if s.usable]
    rejected = [(s.t0, s.t1, s.reason) for s in segs if not s.usable]
    described = {
        "usable": [[round(a, 3), round(b, 3)] for a, b in usable],
        "rejected": [[round(a, 3), round(b, 3), why] for a, b, why in sorted(rejected)],
        "stretches": [
            [round(s.t0, 3), round(s.t1, 3), ("kept: " if s.usable else "dropped: ") + s.reason] for s in segs
        ],
    }
    if not usable:
        usable = [(float(rec.t[0]), float(rec.t[-1]))]
        described["how"] = "no usable stretch found: the whole recording"
    return usable, described


def _longest(pieces: list[tuple[float, float]], max_windows: int) -> tuple[list[tuple[float, float]], list]:
    """The `max_windows` longest pieces (ties by time) in time order, and the rest as rejected
    [t0, t1, reason]."""
    chosen = sorted(sorted(pieces, key=lambda p: (-(p[1] - p[0]), p[0]))[:max_windows])
    beyond = [
        [round(a, 3), round(b, 3), f"beyond max_windows={max_windows}"]
        for a, b in pieces
        if (a, b) not in chosen
    ]
    return chosen, beyond


def _coverage(rec: Recording, pieces: list[tuple[float, float]], activity: np.ndarray | None) -> dict:
    """How much of the drive the windows cover: "seconds" and "lateral_information_share"."""
    in_windows = sum(b - a for a, b in pieces)
    out: dict = {
        "seconds": {
            "drive": round(rec.duration, 2),
            "in_windows": round(in_windows, 2),
            "dropped": round(rec.duration - in_windows, 2),
        }
    }
    share = lateral_information_share(rec, pieces, activity)
    if share is not None:
        out["lateral_information_share"] = round(share, 4)
    return out


def _held_out(
    pieces: list[tuple[float, float]],
    held_out: float,
    min_windows_to_split: int,
    max_window: float,
    num_stretches: int,
) -> tuple[list[Window], str]:
    """Windows over `pieces` with their roles (`choose_windows`), and how they were held out."""
    if held_out == 0.0:
        windows = [Window(a, b, "train") for a, b in pieces]
        how = f"{len(windows)} window(s) of <= {max_window:g} s over the usable driving; none held out"
        return windows, how
    if len(pieces) < min_windows_to_split:
        windows = [Window(a, b, "train", split=a + (1 - held_out) * (b - a)) for a, b in pieces]
        how = f"{len(windows)} window(s) of <= {max_window:g} s; the last {held_out:.0%} of each held out"
        return windows, how
    total = sum(b - a for a, b in pieces)
    elapsed = np.cumsum([0.0] + [b - a for a, b in pieces])[:-1]
    windows = [
        Window(a, b, "held" if e >= (1 - held_out) * total - 1e-9 else "train")
        for (a, b), e in zip(pieces, elapsed)
    ]
    # Fit and validation both need a window: with all on one side, the last alone is held out.
    if all(w.role == "held" for w in windows) or all(w.role == "train" for w in windows):
        windows = [dataclasses.replace(w, role="train") for w in windows[:-1]] + [
            dataclasses.replace(windows[-1], role="held")
        ]
    how = (
        f"{len(windows)} windows of <= {max_window:g} s over {num_stretches} usable stretch(es); "
        f"the last {held_out:.0%} of the usable driving held out"
    )
    return windows, how
