"""Choosing the stretches of a real drive the model suits, and estimating sensor noise."""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from typing import Literal

import numpy as np
import pandas as pd

from ..simulator import GRAVITY
from ._recording import Recording
from ._resample import noise_gain
from ._speed import forward_speed

#: Wheel radius, m, used to turn wheel speeds into a speed when neither vx nor a radius is given.
FALLBACK_WHEEL_RADIUS = 0.31

# Sample labels, in `find_segments`; EXCLUDED + k is the k-th excluded stretch.
USABLE, SLOW, QUIET, EXCLUDED = 0, 1, 2, 3


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


def _rolling(x: np.ndarray, n: int, how: Literal["mean", "std"]) -> np.ndarray:
    if how not in ("mean", "std"):
        raise ValueError(f"how must be 'mean' or 'std', got {how!r}")
    r = pd.Series(x).rolling(n, center=True, min_periods=1)
    return getattr(r, how)().to_numpy()


def label_runs(labels: np.ndarray) -> list[tuple[int, int]]:
    """[start, stop) index ranges of equal consecutive labels."""
    edges = np.flatnonzero(labels[1:] != labels[:-1]) + 1
    starts = np.r_[0, edges]
    stops = np.r_[edges, labels.shape[0]]
    return list(zip(starts.tolist(), stops.tolist()))


#: Lateral motion below which a stretch counts as straight, m/s²: 0.005 g, the v·r a MEMS gyro's
#: bias (1.5 mrad/s) makes at 30 m/s; below it the yaw signal cannot be told from the sensor's
#: offset. (Gentle highway curves, 0.005–0.04 g, still inform the steady yaw gain.)
LATERAL_FLOOR = 0.005 * GRAVITY
#: ... and it must stand this many noise stds (of the 0.5 s mean) above the noise.
NOISE_MULTIPLE = 3.0
#: Axle cornering stiffness per axle load, /rad, for the lateral time constant: a typical
#: passenger car's.
CORNERING_PER_LOAD = float(np.sqrt(3.0 * 30.0))
#: A window fits at least this many lateral time constants after its burn-in ...
SETTLE = 5.0
#: ... and at least this long, s (a few dozen compared samples through the 5 Hz filter).
MIN_FITTED = 1.0
#: Smoothing of the lateral level and of the speed, s.
LEVEL_WINDOW = 0.5


def lateral_time_constant(speed: float) -> float:
    """Time constant, s, of the single-track model's side-slip mode at `speed` m/s:
    m·v / (C_αf + C_αr) with each axle's cornering stiffness `CORNERING_PER_LOAD` times its
    load m·g/2 (the mass cancels)."""
    return abs(speed) / (CORNERING_PER_LOAD * GRAVITY)


def min_window(speed: float, burn_in: float) -> float:
    """Shortest window, s, worth simulating at `speed` m/s: the burn-in, then `SETTLE` lateral
    time constants (at least `MIN_FITTED` s) of fitted samples."""
    return burn_in + max(SETTLE * lateral_time_constant(speed), MIN_FITTED)


def lateral_level(rec: Recording, speed: np.ndarray) -> tuple[np.ndarray, np.ndarray, str] | None:
    """(T,) lateral level, m/s², with (T,) the noise std of that level, and its name: |v_x·r|
    from the yaw rate if measured (a gyro sees neither road bank nor body roll), else |a_y|,
    each a centred `LEVEL_WINDOW` mean. None without either channel."""
    n = max(1, int(round(LEVEL_WINDOW * rec.rate)))
    noise = estimate_noise_std(rec)
    if "yaw_rate" in rec.channels:
        level = np.abs(_rolling(rec.channels["yaw_rate"] * speed, n, "mean"))
        return level, noise["yaw_rate"] * np.abs(speed) / np.sqrt(n), "|v·r|"
    if "ay" in rec.channels:
        level = np.abs(_rolling(rec.channels["ay"], n, "mean"))
        return level, np.full_like(level, noise["ay"] / np.sqrt(n)), "|ay|"
    return None


@dataclasses.dataclass(frozen=True)
class SegmentRules:
    """What makes driving usable for `find_segments`.

    Attributes:
        min_speed: slowest usable speed, m/s (the tire-slip model is singular near standstill).
        max_quiet: longest quiet spell, s, kept between usable stretches.
        min_torque_std: total axle torque std, N·m, over a centred `window` that counts as
            informative driving.
        window: that window, s.
        max_duration: longest usable segment, s; longer ones are split into equal pieces.
            None (default): no split.
    """

    min_speed: float = 5.0
    max_quiet: float = 3.0
    min_torque_std: float = 100.0
    window: float = 2.0
    max_duration: float | None = None

    def __post_init__(self):
        if self.min_speed < 0 or self.max_quiet < 0 or self.min_torque_std < 0 or not self.window > 0:
            raise ValueError(f"SegmentRules wants non-negative thresholds and window > 0, got {self}")
        if self.max_duration is not None and not self.max_duration > 0:
            raise ValueError(f"SegmentRules.max_duration must be > 0 or None, got {self.max_duration}")


def find_segments(
    rec: Recording,
    *,
    rules: SegmentRules = SegmentRules(),
    min_duration: float | None = None,
    burn_in: float = 1.0,
    torques: bool | None = None,
    exclude: Sequence[tuple[float, float, str]] = (),
    longest_minimum: float = np.inf,
    wheel_radius: float | None = None,
) -> list[Segment]:
    """Split a recording into usable and rejected stretches, covering all of it in time order.
    `rules` (`SegmentRules`) gives `min_speed`, `max_quiet`, `min_torque_std`, `window` and
    `max_duration`.

    A sample is usable where the speed (`forward_speed`: vx, else mean wheel speed ×
    `wheel_radius`, else the estimate from ax and ay ≈ v_x·r), averaged over 0.5 s, is at
    least `min_speed` (the tire-slip model is singular near standstill) and the driving
    informs the lateral dynamics: the lateral level (`lateral_level`: |v_x·r|, else |a_y|) is
    at least `LATERAL_FLOOR` (0.005 g) and `NOISE_MULTIPLE` noise stds for at least
    `LEVEL_WINDOW` s. Steady cornering counts (it sets the stiffnesses' steady-state gain) as
    do steering transients; straight driving does not, however the steering wheel moves. With
    `torques` (default: the recording has them) a total axle torque std over a centred `window` of at least
    `min_torque_std` also counts. Quiet spells shorter than `max_quiet` between usable
    stretches are kept (the model runs through them); stretches in `exclude` ((t0, t1, reason))
    are rejected with their reason.

    Each usable stretch takes up to `burn_in` s of the quiet driving before it as a lead-in
    (the window's burn-in falls on the approach, not on the corner) and, if still shorter than
    its minimum, up to `min_window(v, 0)` s of the quiet driving after it (the response
    decays there). The minimum is `min_duration` if given, else `min_window` at the stretch's
    mean speed (burn-in plus a few lateral time constants), at most `longest_minimum`. Longer
    stretches are split into equal pieces no longer than `max_duration` if given.

    Returns:
        Segments whose reasons give the deciding figure: "cornering: |v·r| rms 2.1 m/s² …",
        "straight: …", "speed below 5 m/s", "too short (…)", or an `exclude` reason.
    """
    min_speed, max_quiet, max_duration = rules.min_speed, rules.max_quiet, rules.max_duration
    t = rec.t
    speed = forward_speed(rec, wheel_radius if wheel_radius is not None else FALLBACK_WHEEL_RADIUS)
    if speed is None:
        return [Segment(float(t[0]), float(t[-1]), False, "no speed: no vx, wheel speeds or estimate")]
    n_level = max(1, int(round(LEVEL_WINDOW * rec.rate)))
    fast = _rolling(speed, n_level, "mean") >= min_speed
    use_torques = rec.has_torques and (torques is None or torques)
    evidence = _evidence(rec, speed, use_torques, rules.window, rules.min_torque_std)
    informed = _informed(evidence, rec.num_samples, n_level, int(round(max_quiet * rec.rate)))
    runs = _labelled_runs(t, fast, informed, exclude)
    # Lead-ins and run-outs first (they move the bounds of the quiet runs), then the segments.
    kept = _verdicts(rec, runs, speed, evidence, burn_in, min_duration, longest_minimum)
    return _to_segments(t, runs, kept, evidence, min_speed, max_duration, exclude)


@dataclasses.dataclass(frozen=True)
class _Evidence:
    """Per-sample figures that decide whether the driving informs the model.

    Attributes:
        level: (T,) lateral level, m/s² (`lateral_level`), or None without ay and yaw rate.
        noise: (T,) noise std of the level, m/s², or None.
        threshold: (T,) level that counts as informative, m/s², or None.
        name: the level's name, "|v·r|" or "|ay|".
        torque_std: (T,) total axle torque std over a centred window, N·m, or None when the
            torques do not count.
        min_torque_std: the torque std that counts, N·m.
    """

    level: np.ndarray | None
    noise: np.ndarray | None
    threshold: np.ndarray | None
    name: str
    torque_std: np.ndarray | None
    min_torque_std: float

    def figure(self, i0: int, i1: int) -> str:
        """The figures over samples [i0, i1) that decide, as a reason reads them."""
        if self.level is None:
            return "no ay or yaw rate to judge the lateral dynamics by"
        rms = float(np.sqrt(np.mean(self.level[i0:i1] ** 2)))
        thr = float(np.mean(self.threshold[i0:i1]))
        noise = float(np.mean(self.noise[i0:i1]))
        text = (
            f"{self.name} rms {rms:.2f} m/s² = {rms / thr:.1f}× the {thr:.2f} m/s² threshold "
            f"({LATERAL_FLOOR / GRAVITY:g} g, {NOISE_MULTIPLE:g}× noise {noise:.3f} m/s²)"
        )
        if self.torque_std is not None:
            most = float(np.max(self.torque_std[i0:i1]))
            text += f"; torque std up to {most:.0f} N·m (needs {self.min_torque_std:g})"
        return text


def _evidence(
    rec: Recording, speed: np.ndarray, use_torques: bool, window: float, min_torque_std: float
) -> _Evidence:
    """The lateral level and its threshold (`lateral_level`), and with `use_torques` the axle
    torque std over a centred `window` s."""
    lateral = lateral_level(rec, speed)
    level, noise, name = (None, None, "") if lateral is None else lateral
    threshold = None if lateral is None else np.maximum(NOISE_MULTIPLE * noise, LATERAL_FLOOR)
    torque_std = None
    if use_torques:
        n_win = max(2, int(round(window * rec.rate)))
        torque_std = _rolling(rec.torque_front + rec.torque_rear, n_win, "std")
    return _Evidence(level, noise, threshold, name, torque_std, min_torque_std)


def _informed(evidence: _Evidence, num_samples: int, n_min: int, n_quiet: int) -> np.ndarray:
    """(T,) samples whose driving informs the model: the lateral level at its threshold for at
    least `n_min` samples (all samples without a lateral channel), or the torque std at its
    minimum; quiet spells of at most `n_quiet` samples between informed ones count too."""
    if evidence.level is None:
        informed = np.ones(num_samples, dtype=bool)
    else:
        informed = evidence.level >= evidence.threshold
        # A corner or a transient lasts longer than the level's smoothing; shorter runs above
        # the threshold are the noise's.
        for i0, i1 in label_runs(informed):
            if informed[i0] and i1 - i0 < n_min:
                informed[i0:i1] = False
    if evidence.torque_std is not None:
        informed = informed | (evidence.torque_std >= evidence.min_torque_std)
    runs = label_runs(informed)
    for k, (i0, i1) in enumerate(runs):
        if not informed[i0] and 0 < k < len(runs) - 1 and i1 - i0 <= n_quiet:
            informed[i0:i1] = True
    return informed


def _labelled_runs(
    t: np.ndarray, fast: np.ndarray, informed: np.ndarray, exclude: Sequence[tuple[float, float, str]]
) -> list[list[int]]:
    """[start, stop, label] of the runs of equal sample labels (`USABLE`, `SLOW`, `QUIET`, or
    `EXCLUDED` + k inside the k-th excluded stretch), in time order."""
    label = np.where(~fast, SLOW, np.where(informed, USABLE, QUIET))
    for k, (a, b, _) in enumerate(exclude):
        label[fast & (t >= a - 1e-9) & (t <= b + 1e-9)] = EXCLUDED + k
    return [[i0, i1, int(label[i0])] for i0, i1 in label_runs(label)]


def _verdicts(
    rec: Recording,
    runs: list[list[int]],
    speed: np.ndarray,
    evidence: _Evidence,
    burn_in: float,
    min_duration: float | None,
    longest_minimum: float,
) -> dict[int, tuple[bool, str]]:
    """Index in `runs` -> (usable, reason) of each `USABLE` run, once given its lead-in and
    run-out from the quiet runs beside it (which moves the runs' bounds, in place)."""
    t = rec.t
    n_lead = int(round(burn_in * rec.rate))
    kept: dict[int, tuple[bool, str]] = {}
    for k, run in enumerate(runs):
        if run[2] != USABLE:
            continue
        why = ("cornering: " if evidence.level is not None else "moving: ") + evidence.figure(run[0], run[1])
        v = float(np.mean(np.abs(speed[run[0] : run[1]])))
        prev = runs[k - 1] if k > 0 else None
        if prev is not None and prev[2] == QUIET and n_lead > 0:
            why += _lead_in(rec, prev, run, n_lead)
        if min_duration is not None:
            need, how = min_duration, f"{min_duration:g} s"
        else:
            need = min(min_window(v, burn_in), longest_minimum)
            how = f"{need:.1f} s at {v:.0f} m/s: burn-in {burn_in:g} s + {SETTLE:g} lateral time constants"
        nxt = runs[k + 1] if k + 1 < len(runs) else None
        missing = need - float(t[run[1] - 1] - t[run[0]])
        if missing > 1e-9 and nxt is not None and nxt[2] == QUIET:
            # The response to the last input decays within the fitted minimum; past it the
            # straight informs nothing.
            why += _run_out(rec, run, nxt, min(missing, min_window(v, 0.0)))
        duration = float(t[run[1] - 1] - t[run[0]])
        kept[k] = (True, why) if duration >= need - 1e-9 else (False, f"too short ({duration:.1f} s < {how})")
    return kept


def _lead_in(rec: Recording, prev: list[int], run: list[int], n_lead: int) -> str:
    """Move up to `n_lead` samples from the end of the quiet run `prev` to the start of `run`."""
    m = min(n_lead, prev[1] - prev[0])
    prev[1] -= m
    run[0] -= m
    return f"; with {m * rec.dt:.1f} s lead-in" if m else ""


def _run_out(rec: Recording, run: list[int], nxt: list[int], seconds: float) -> str:
    """Move up to `seconds` from the start of the quiet run `nxt` to the end of `run`."""
    m = min(int(np.ceil(seconds * rec.rate - 1e-6)), nxt[1] - nxt[0])
    nxt[0] += m
    run[1] += m
    return f"; with {m * rec.dt:.1f} s run-out" if m else ""


def _to_segments(
    t: np.ndarray,
    runs: list[list[int]],
    kept: dict[int, tuple[bool, str]],
    evidence: _Evidence,
    min_speed: float,
    max_duration: float | None,
    exclude: Sequence[tuple[float, float, str]],
) -> list[Segment]:
    """The non-empty runs as segments with their reasons; usable ones split at `max_duration`."""
    out: list[Segment] = []
    for k, (i0, i1, code) in enumerate(runs):
        if i1 <= i0:
            continue
        a, b = float(t[i0]), float(t[i1 - 1])
        if code == SLOW:
            out.append(Segment(a, b, False, f"speed below {min_speed:g} m/s"))
        elif code == QUIET:
            out.append(Segment(a, b, False, f"straight: {evidence.figure(i0, i1)}"))
        elif code >= EXCLUDED:
            out.append(Segment(a, b, False, exclude[code - EXCLUDED][2]))
        elif not kept[k][0] or max_duration is None or b - a <= max_duration:
            out.append(Segment(a, b, *kept[k]))
        else:
            pieces = int(np.ceil((b - a) / max_duration))
            edges = np.linspace(a, b, pieces + 1)
            out.extend(Segment(float(edges[j]), float(edges[j + 1]), True, kept[k][1]) for j in range(pieces))
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
    A recording logged below the model rate is estimated on its own samples (the linear
    interpolation to the model rate smooths the noise away) and returned as the model-rate white
    noise of the same low-frequency density: σ·sqrt(rate / original_rate).

    Args:
        rec: the recording.
        window: filter length, s.
        segments: restrict to these (t0, t1) stretches (e.g. `usable_segments(rec)`); default all.

    Returns:
        channel -> std in the channel's units.
    """
    from scipy.signal import savgol_coeffs, savgol_filter

    t, channels, rate = rec.t, rec.channels, rec.rate
    gain = noise_gain(rec.original_rate, rec.rate)
    if gain > 1.0:
        # Upsampled: the resampled series is linear between the recorded samples, so they are
        # read back at their times.
        rate = rec.original_rate
        t = np.arange(rec.t[0], rec.t[-1] + 1e-9, 1.0 / rate)
        channels = {k: np.interp(t, rec.t, v) for k, v in rec.channels.items()}
    else:
        gain = 1.0  # downsampled (box-averaged) or at the model rate: already the model rate's σ
    n = max(5, int(round(window * rate)) | 1)
    h0 = float(savgol_coeffs(n, 3)[n // 2])
    if segments:
        mask = np.zeros(t.shape[0], dtype=bool)
        for a, b in segments:
            mask |= (t >= a) & (t <= b)
    else:
        mask = np.ones(t.shape[0], dtype=bool)
    # Drop the filter's edge samples around each stretch.
    edge = np.convolve(~mask, np.ones(n), mode="same") > 0
    use = mask & ~edge
    if use.sum() < n:
        use = mask
    out = {}
    for name, x in channels.items():
        r = (x - savgol_filter(x, n, 3, mode="interp"))[use]
        mad = np.median(np.abs(r - np.median(r)))
        s = 1.4826 * mad if mad > 0 else float(np.std(r))
        out[name] = float(gain * s / np.sqrt(1.0 - h0))
    return out
