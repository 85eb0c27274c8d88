"""Every drive's windows on one fixed shape, so that a worker compiles the simulation of a drive
once and every later drive (and every later worker, through the persistent cache) reuses it."""

from __future__ import annotations

import dataclasses

import numpy as np

from ..io import InputError
from ..problem import Problem

#: Window counts a drive is padded up to: 1, 2, 3, then 2ᵏ and 3·2ᵏ⁻¹ (4, 6, 8, 12, …). A
#: simulated window costs the same whether it holds data or is padding: the padding adds less
#: than half (a multiple of 4 made a drive of one window cost four), and a fleet of drives from
#: seconds to hours shares a few programs.
WINDOW_COUNTS = (1, 2, 3) + tuple(c for k in range(2, 31) for c in (2**k, 3 * 2 ** (k - 1)))


#: Window lengths a drive is padded up to, as fractions of the longest window the cut makes: a
#: drive whose windows all stay short simulates a fifth less, at the cost of one more program.
LENGTH_FRACTIONS = (0.8, 1.0)


def length_bucket(problem: Problem, longest: float) -> float:
    """The padded window length of `problem`, s: the least of `LENGTH_FRACTIONS` · `longest`
    that holds its longest window (`longest` itself when none does; `fixed_shape` then says so)."""
    for fraction in LENGTH_FRACTIONS:
        n = int(round(fraction * longest / problem.dt))
        if problem.t.shape[1] <= n - n % problem.factor:
            return fraction * longest
    return longest


def window_bucket(windows: int) -> int:
    """The padded window count of a drive of `windows` windows: the least of `WINDOW_COUNTS` that
    holds them."""
    return next(c for c in WINDOW_COUNTS if c >= windows)


def _hold(a: np.ndarray | None, axis1: int | None, windows: int, fill=None) -> np.ndarray | None:
    """`a` (W, N, …) padded along time to `axis1` samples (holding the last one, or `fill`) and
    along windows to `windows` (copies of the last window, or `fill`)."""
    if a is None:
        return None
    if axis1 is not None and a.shape[1] < axis1:
        extra = axis1 - a.shape[1]
        tail = (
            np.repeat(a[:, -1:], extra, axis=1)
            if fill is None
            else np.full((a.shape[0], extra, *a.shape[2:]), fill)
        )
        a = np.concatenate([a, tail], axis=1)
    if a.shape[0] < windows:
        extra = windows - a.shape[0]
        more = np.repeat(a[-1:], extra, axis=0) if fill is None else np.full((extra, *a.shape[1:]), fill)
        a = np.concatenate([a, more], axis=0)
    return a


def fixed_shape(problem: Problem, seconds: float, windows: int | None = None) -> Problem:
    """`problem` with every window padded to `seconds` of model-rate samples (the compared ones
    to match) and the windows to `windows` (default: `window_bucket`'s count).
    Padded samples and windows are not valid, trained on or held out; their inputs hold the
    last sample, so their simulation stays well-behaved and is never scored.

    Raises:
        InputError: a window longer than `seconds`.
    """
    n = int(round(seconds / problem.dt))
    n -= n % problem.factor
    k = n // problem.factor
    if problem.t.shape[1] > n:
        longest = problem.t.shape[1] * problem.dt
        raise InputError(
            problem.source, "windows", f"a window of {longest:.1f} s exceeds the fleet's {seconds:.1f} s"
        )
    w = problem.num_windows
    windows = window_bucket(w) if windows is None else int(windows)
    t = np.concatenate(
        [problem.t, problem.t[:, :1] + problem.dt * np.arange(problem.t.shape[1], n)[None]], axis=1
    )
    t = _hold(t, None, windows)
    return dataclasses.replace(
        problem,
        windows=problem.windows + (problem.windows[-1],) * (windows - w),
        t=t,
        u=_hold(problem.u, n, windows),
        speed=_hold(problem.speed, n, windows),
        accel=_hold(problem.accel, n, windows),
        t_out=t[:, :: problem.factor][:, :k],
        y=_hold(problem.y, k, windows),
        valid=_hold(problem.valid, k, windows, False),
        train=_hold(problem.train, k, windows, False),
        held=_hold(problem.held, k, windows, False),
        v0=_hold(problem.v0[:, None], None, windows)[:, 0],
        r0=_hold(problem.r0[:, None], None, windows)[:, 0],
    )
