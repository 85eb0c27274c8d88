"""Cutting a recording into fit windows, with a training part and a held-out part in each."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np

from ..io import Recording, estimate_noise_std, usable_segments
from ..simulator import Inputs, Vehicle
from ..simulator._vehicle import CHANNELS
from ._fit import FitData, channel_indices


@dataclasses.dataclass
class Windows:
    """W equal-length windows of a recording (shorter ones padded and masked).

    Attributes:
        t: (W, T) time stamps, s.
        u: (W, T, 3) inputs (steer, torque_front, torque_rear).
        y: (W, T, C) measured channels.
        valid: (W, T) bool, real (not padded) samples.
        train: (W, T) bool, samples that enter the fit (after the burn-in, before the split).
        held: (W, T) bool, held-out samples (the last `1 − train_fraction` of each window).
        channels: C names.
        sigma: (C,) noise std used, channel units.
        sigma_source: {channel: "vehicle" | "estimated"}.
        v0: (W,) measured speed at each window start, m/s.
        dt: sample interval, s.
        t_train_end: (W,) time where each window's held-out part starts, s.
    """

    t: np.ndarray
    u: np.ndarray
    y: np.ndarray
    valid: np.ndarray
    train: np.ndarray
    held: np.ndarray
    channels: tuple[str, ...]
    sigma: np.ndarray
    sigma_source: dict
    v0: np.ndarray
    dt: float
    t_train_end: np.ndarray

    @property
    def num_windows(self) -> int:
        return int(self.t.shape[0])

    def fit_data(self, part: str = "train", *, truncate: bool = True) -> FitData:
        """FitData whose mask is `part` ("train", "held" or "valid"); truncated after the
        last masked sample when `truncate` (the simulation need not run past it)."""
        mask = getattr(self, part)
        end = int(np.max(np.nonzero(mask.any(0))[0])) + 1 if truncate else mask.shape[1]
        inp = [Inputs(self.t[w, 0], self.dt, *self.u[w, :end].T) for w in range(self.num_windows)]
        stacked = jax.tree.map(lambda *a: jnp.stack(a), *inp)
        return FitData(
            inputs=stacked,
            measured=jnp.asarray(self.y[:, :end]),
            sigma=jnp.asarray(self.sigma),
            mask=jnp.asarray(mask[:, :end].astype(float)),
            v0_meas=jnp.asarray(self.v0),
            channel_index=channel_indices(self.channels),
            channels=self.channels,
        )


def noise_sigma(rec: Recording, vehicle: Vehicle, segments=None) -> tuple[np.ndarray, dict]:
    """σ per measured channel: vehicle.json's noise_std where given, else estimated."""
    est = None
    out, src = [], {}
    for c in rec.channel_names:
        if c in vehicle.noise_std and vehicle.noise_std[c] > 0:
            out.append(float(vehicle.noise_std[c]))
            src[c] = "vehicle"
        else:
            if est is None:
                est = estimate_noise_std(rec, segments=segments or None)
            scale = float(np.std(rec.channels[c])) + 1e-9
            out.append(max(float(est[c]), 1e-4 * scale))
            src[c] = "estimated"
    return np.asarray(out), src


def make_windows(
    rec: Recording,
    vehicle: Vehicle,
    *,
    max_window: float = 20.0,
    max_windows: int = 3,
    train_fraction: float = 0.7,
    burn_in: float = 1.0,
    min_duration: float = 5.0,
) -> Windows:
    """Choose windows from the usable stretches of `rec` (the whole recording if none).

    Stretches longer than `max_window` are cut into equal pieces; at most `max_windows` pieces
    are kept (the longest; ties by time). Each window is simulated from its own start
    (v0 from vx or wheel speeds, Vy = r = 0), its first `burn_in` s are excluded (the assumed
    lateral initial state settles), the next part up to `train_fraction` of its length is fitted
    and the rest is held out.
    """
    segs = usable_segments(rec, wheel_radius=vehicle.wheel_radius, min_duration=min_duration)
    if not segs:
        segs = [(float(rec.t[0]), float(rec.t[-1]))]
    pieces = []
    for a, b in segs:
        k = max(1, int(np.ceil((b - a) / max_window - 1e-9)))
        edges = np.linspace(a, b, k + 1)
        pieces += [(float(edges[j]), float(edges[j + 1])) for j in range(k)]
    pieces = sorted(pieces, key=lambda p: (-(p[1] - p[0]), p[0]))[:max_windows]
    pieces = sorted(pieces)
    dt = rec.dt
    idx = [(int(np.searchsorted(rec.t, a - 1e-9)), int(np.searchsorted(rec.t, b + 1e-9))) for a, b in pieces]
    T = max(i1 - i0 for i0, i1 in idx)
    W = len(idx)
    chans = rec.channel_names
    y_all = rec.measured(chans)
    u_all = np.stack([rec.steer, rec.torque_front, rec.torque_rear], -1)
    t = np.zeros((W, T))
    u = np.zeros((W, T, 3))
    y = np.zeros((W, T, len(chans)))
    valid = np.zeros((W, T), bool)
    train = np.zeros((W, T), bool)
    held = np.zeros((W, T), bool)
    v0 = np.zeros(W)
    t_split = np.zeros(W)
    speed = rec.speed(vehicle.wheel_radius)
    n_burn = int(round(burn_in / dt))
    for w, (i0, i1) in enumerate(idx):
        n = i1 - i0
        t[w] = rec.t[i0] + dt * np.arange(T)
        u[w, :n] = u_all[i0:i1]
        u[w, n:] = u_all[i1 - 1]  # hold the last input over the padding
        y[w, :n] = y_all[i0:i1]
        valid[w, :n] = True
        n_tr = int(round(train_fraction * n))
        train[w, min(n_burn, n_tr // 2) : n_tr] = True
        held[w, n_tr:n] = True
        t_split[w] = rec.t[i0 + min(n_tr, n - 1)]
        k = max(1, int(round(0.05 / dt)))
        v0[w] = float(np.median(speed[i0 : i0 + k])) if speed is not None else 10.0
    sigma, src = noise_sigma(rec, vehicle, segs)
    return Windows(
        t=t,
        u=u,
        y=y,
        valid=valid,
        train=train,
        held=held,
        channels=tuple(c for c in CHANNELS if c in chans),
        sigma=sigma,
        sigma_source=src,
        v0=np.maximum(v0, 0.5),
        dt=dt,
        t_train_end=t_split,
    )
