"""Choosing the stretches of a real drive the model suits, and estimating sensor noise."""

from __future__ import annotations

import dataclasses

import numpy as np
import pandas as pd

from ._recording import Recording
from ._speed import forward_speed

#: Wheel radius, m, used to turn wheel speeds into a speed when neither vx nor a radius is given.
FALLBACK_WHEEL_RADIUS = 0.31


@dataclasses.dataclass(frozen=True)
class Segment:
    """A stretch [t0, t1] s of a recording, and whether it suits the model (and why not)."""

    t0: float
    t1: float
    usable: bool
    reason: str

    @property
    def duration(self) -> float:
        return self.t1 - self.t0


def _rolling(x: np.ndarray, n: int, how: str) -> np.ndarray:
    r = pd.Series(x).rolling(n, center=True, min_periods=1)
    return getattr(r, how)().to_numpy()


def label_runs(labels: np.ndarray) -> list[tuple[int, int]]:
    """[start, stop) index ranges of equal consecutive labels."""
    edges = np.flatnonzero(labels[1:] != labels[:-1]) + 1
    starts = np.r_[0, edges]
    stops = np.r_[edges, labels.shape[0]]
    return list(zip(starts.tolist(), stops.tolist()))


def find_segments(
    rec: Recording,
    *,
    min_speed: float = 5.0,
    min_duration: float = 5.0,
    max_duration: float | None = None,
    window: float = 2.0,
    min_steer_std: float = 0.005,
    min_torque_std: float = 100.0,
    max_quiet: float = 3.0,
    wheel_radius: float | None = None,
) -> list[Segment]:
    """Split a recording into usable and rejected stretches, covering all of it in time order.

    A sample is usable where the speed (`forward_speed`: vx, else mean wheel speed ×
    `wheel_radius`, else the estimate from ax and ay ≈ v_x·r), averaged
    over 0.5 s, is at least `min_speed` (the tire-slip model is singular near standstill) and
    the inputs excite the dynamics: over a centred `window` the steering std is at least
    `min_steer_std` or the total axle torque std at least `min_torque_std` (without torques,
    the steering alone decides). Quiet spells shorter
    than `max_quiet` between excited stretches are kept (the model runs through them). Runs of
    usable samples shorter than `min_duration` are rejected; longer ones are split into equal
    pieces no longer than `max_duration` if given.

    Defaults: 5 m/s is where kinematic slip errors of ~0.1 m/s stay below 2 %; 0.005 rad of
    road-wheel angle gives ~1 m/s² of ay at 20 m/s; 100 N·m per car changes ax by ~0.2 m/s².

    Returns:
        Segments with reasons like "speed below 5 m/s" or "no excitation".
    """
    t = rec.t
    speed = forward_speed(rec, wheel_radius if wheel_radius is not None else FALLBACK_WHEEL_RADIUS)
    if speed is None:
        return [Segment(float(t[0]), float(t[-1]), False, "no speed: no vx, wheel speeds or estimate")]
    n_speed = max(1, int(round(0.5 * rec.rate)))
    n_win = max(2, int(round(window * rec.rate)))
    fast = _rolling(speed, n_speed, "mean") >= min_speed
    steer_std = _rolling(rec.steer, n_win, "std")
    excited = steer_std >= min_steer_std
    if rec.has_torques:
        excited |= _rolling(rec.torque_front + rec.torque_rear, n_win, "std") >= min_torque_std
    n_quiet = int(round(max_quiet * rec.rate))
    runs = label_runs(excited)
    for k, (i0, i1) in enumerate(runs):
        if not excited[i0] and 0 < k < len(runs) - 1 and i1 - i0 <= n_quiet:
            excited[i0:i1] = True
    label = np.where(~fast, 1, np.where(~excited, 2, 0))
    steady = "steady steer and torque" if rec.has_torques else "steady steer"
    reasons = {1: f"speed below {min_speed:g} m/s", 2: f"no excitation ({steady})"}
    out: list[Segment] = []
    for i0, i1 in label_runs(label):
        a, b = float(t[i0]), float(t[i1 - 1])
        code = int(label[i0])
        if code:
            out.append(Segment(a, b, False, reasons[code]))
        elif b - a < min_duration:
            out.append(Segment(a, b, False, f"too short ({b - a:.1f} s < {min_duration:g} s)"))
        elif max_duration is not None and b - a > max_duration:
            k = int(np.ceil((b - a) / max_duration))
            edges = np.linspace(a, b, k + 1)
            out.extend(Segment(float(edges[j]), float(edges[j + 1]), True, "") for j in range(k))
        else:
            out.append(Segment(a, b, True, ""))
    return out


def usable_segments(rec: Recording, **kwargs) -> list[tuple[float, float]]:
    """(t0, t1) of the usable stretches from `find_segments` (same keyword arguments)."""
    return [(s.t0, s.t1) for s in find_segments(rec, **kwargs) if s.usable]


def estimate_noise_std(
    rec: Recording,
    *,
    window: float = 0.2,
    segments: list[tuple[float, float]] | None = None,
) -> dict[str, float]:
    """Sensor noise std per measured channel, from the residual of a local cubic fit.

    Each channel is smoothed with a Savitzky–Golay filter (cubic, `window` s: flat up to
    ~5 Hz at 0.2 s, above the 1–3 Hz of the body dynamics) and the std is taken from the
    residual's median absolute deviation (×1.4826, robust to spikes), falling back to the plain
    std if over half the residuals are zero (quantised or held values). For white noise of std σ
    the residual has std σ·sqrt(1 - h0), with h0 the filter's centre weight; that is divided out.
    Everything the model does not describe above ~5 Hz (vibration, engine orders) counts as noise.

    Args:
        rec: the recording.
        window: filter length, s.
        segments: restrict to these (t0, t1) stretches (e.g. `usable_segments(rec)`); default all.

    Returns:
        channel -> std in the channel's units.
    """
    from scipy.signal import savgol_coeffs, savgol_filter

    n = max(5, int(round(window * rec.rate)) | 1)
    h0 = float(savgol_coeffs(n, 3)[n // 2])
    if segments:
        mask = np.zeros(rec.num_samples, dtype=bool)
        for a, b in segments:
            mask |= (rec.t >= a) & (rec.t <= b)
    else:
        mask = np.ones(rec.num_samples, dtype=bool)
    # Drop the filter's edge samples around each stretch.
    edge = np.convolve(~mask, np.ones(n), mode="same") > 0
    use = mask & ~edge
    if use.sum() < n:
        use = mask
    out = {}
    for name, x in rec.channels.items():
        r = (x - savgol_filter(x, n, 3, mode="interp"))[use]
        mad = np.median(np.abs(r - np.median(r)))
        s = 1.4826 * mad if mad > 0 else float(np.std(r))
        out[name] = float(s / np.sqrt(1.0 - h0))
    return out
