"""Several recordings of one car as one problem: their windows side by side, each from its own
initial state."""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import numpy as np

from ..io import InputError
from ._problem import Problem


def _pad(a: np.ndarray | None, n: int, fill=None) -> np.ndarray | None:
    """Pad axis 1 to `n` by holding the last sample (or with `fill`)."""
    if a is None:
        return None
    extra = n - a.shape[1]
    if extra <= 0:
        return a
    if fill is None:
        tail = np.repeat(a[:, -1:], extra, axis=1)
    else:
        tail = np.full((a.shape[0], extra, *a.shape[2:]), fill)
    return np.concatenate([a, tail], axis=1)


def concat_problems(problems: Sequence[Problem]) -> Problem:
    """One problem whose windows are those of `problems`, in order (padded to a common length).

    The recordings must share the vehicle, the longitudinal mode, the channels, the model rate
    and the filter; the noise std is the largest of theirs per channel (the likelihood fit
    estimates its own from the residual).

    Raises:
        InputError: naming the recording that does not match the first.
    """
    first = problems[0]
    if len(problems) == 1:
        return first
    for p in problems[1:]:
        for what, a, b in (
            ("longitudinal mode", p.longitudinal, first.longitudinal),
            ("channels", p.channels, first.channels),
            ("model rate", round(1 / p.dt, 6), round(1 / first.dt, 6)),
            ("filter", p.decimator is None, first.decimator is None),
        ):
            if a != b:
                why = f"{a} differs from {first.source}'s {b}; identify them apart"
                raise InputError(p.source, what, why)
    n = max(p.t.shape[1] for p in problems)
    k = max(p.t_out.shape[1] for p in problems)
    cat = lambda name, length, fill=None: (
        None
        if getattr(first, name) is None
        else np.concatenate([_pad(getattr(p, name), length, fill) for p in problems])
    )
    t = np.concatenate([p.t[:, :1] + p.dt * np.arange(n)[None] for p in problems])
    t_out = t[:, :: first.factor][:, :k]
    return dataclasses.replace(
        first,
        source=" + ".join(p.source for p in problems),
        windows=tuple(dataclasses.replace(w, recording=i) for i, p in enumerate(problems) for w in p.windows),
        t=t,
        u=cat("u", n),
        speed=cat("speed", n),
        accel=cat("accel", n),
        t_out=t_out,
        y=cat("y", k),
        valid=cat("valid", k, False),
        train=cat("train", k, False),
        held=cat("held", k, False),
        v0=np.concatenate([p.v0 for p in problems]),
        r0=np.concatenate([p.r0 for p in problems]),
        sigma=np.max([p.sigma for p in problems], axis=0),
        sigma_raw=np.max([p.sigma_raw for p in problems], axis=0),
        description={"recordings": [p.source for p in problems]}
        | {key: [p.description.get(key) for p in problems] for key in first.description},
        warnings=tuple(w for p in problems for w in p.warnings),
    )
