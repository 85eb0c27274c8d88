"""A recording plus a vehicle becomes one immutable problem: the one road from data to estimators.

Everything downstream (`identify`, `diagnose`, `simulate --inputs`, `observability`, the CLI
and the Python API) works on a `Problem` built by `make_problem` (in `_make`), so the windows,
the noise model, the inputs, each window's initial state and the held-out part are decided there
only. This module holds the `ProblemSettings` it takes, the `Problem` it returns and what is
read off a `Problem`: its speed, the grip it uses and the yaw rate at a logged steer of zero.
"""

from __future__ import annotations

import dataclasses
from typing import Literal

import jax
import jax.numpy as jnp
import numpy as np

from ..simulator import CHANNELS, GRAVITY, Inputs, Vehicle
from ..simulator.measurement import Decimator
from ..simulator.models import LONGITUDINAL_MODES, LongitudinalChoice, LongitudinalMode, model_class
from ._windows import EDGE_SEARCH, Window

#: A problem's samples: the fitted ones, the held-out ones, or every usable one.
Part = Literal["train", "held", "valid"]


@dataclasses.dataclass(frozen=True)
class ProblemSettings:
    """How a recording becomes a problem.

    Attributes:
        longitudinal: "torque" (wheels driven by the recorded torques), "speed" (the
            longitudinal motion follows the measured speed; for logs without torques or with
            commanded ones), or "auto" (torque if the recording has torques, else speed).
        max_window: longest window, s (each window is simulated from its own initial state).
        held_out: fraction of the usable driving held out for validation (0: none).
        min_windows_to_split: with at least this many windows, whole windows at the end of the
            drive are held out; fewer, and the end of each window is.
        max_windows: keep at most this many windows (the longest); None keeps all.
        burn_in: seconds at each window start left out of the fit (the estimated initial
            lateral state settles).
        bandwidth: low-pass cutoff, Hz, applied to measured and simulated channels alike
            before decimation; None keeps the model rate unfiltered; "auto" is None in torque
            mode and 5 Hz in speed mode (real drives: vibration above the body dynamics).
        output_rate: rate after decimation, Hz (when filtering).
        segment: a user's [t0, t1] s to restrict the drive to, or None.
        channels: channels to condition on (default: every measured channel the mode allows).
        quiet_edges: start windows at the quietest nearby moment (near straight running), where
            the steady-state initial lateral state is accurate.
        exclude_slides: cut slides caught by counter-steer out of the driving, with margins and
            a stated reason (`slides`); False keeps them.
    """

    longitudinal: LongitudinalChoice = "auto"
    max_window: float = 20.0
    held_out: float = 0.3
    min_windows_to_split: int = 3
    max_windows: int | None = None
    burn_in: float = 1.0
    bandwidth: float | Literal["auto"] | None = "auto"
    output_rate: float = 25.0
    segment: tuple[float, float] | None = None
    channels: tuple[str, ...] | None = None
    quiet_edges: bool = True
    exclude_slides: bool = True

    def __post_init__(self):
        if self.longitudinal not in (*LONGITUDINAL_MODES, "auto"):
            raise ValueError(f"longitudinal must be 'torque', 'speed' or 'auto', got {self.longitudinal!r}")
        if not 0.0 <= self.held_out < 1.0:
            raise ValueError(f"held_out must lie in [0, 1), got {self.held_out}")
        if not self.max_window > 0:
            raise ValueError(f"max_window must be > 0, got {self.max_window}")

    @property
    def longest_window(self) -> float:
        """The longest window these settings cut, s: `max_window` with both edges moved out to
        the quietest moments nearby (`quiet_edges`)."""
        return self.max_window * (1.0 + 2.0 * EDGE_SEARCH if self.quiet_edges else 1.0)


@dataclasses.dataclass(frozen=True, eq=False)
class Problem:
    """What is to be explained: W windows of a drive on a common length, padded and masked.

    Attributes:
        source: the recording as the user named it.
        vehicle: known constants.
        longitudinal: "torque" or "speed".
        channels: C conditioned channels, in `CHANNELS` order.
        windows: the W windows (times, role).
        dt: model sample interval, s.
        t: (W, T) model-rate time stamps.
        u: (W, T, 3) steer, torque_front, torque_rear (zeros without torques).
        speed: (W, T) measured speed (speed mode), else None.
        accel: (W, T) measured longitudinal specific force, low-passed (speed mode), else None.
        decimator: the filter and decimation shared by measured and simulated channels, or None.
        t_out: (W, K) time stamps of the compared samples.
        y: (W, K, C) measured channels at those samples (filtered and decimated like the model).
        valid: (W, K) real (not padded) samples.
        train: (W, K) samples that enter the fit (after the burn-in, not held out).
        held: (W, K) held-out samples.
        v0: (W,) measured speed at each window start, m/s.
        r0: (W,) measured yaw rate at each window start, rad/s (0 without a yaw-rate channel):
            with θ it gives each window's estimated initial lateral state.
        sigma: (C,) noise std of the compared samples (after filtering), channel units.
        sigma_raw: (C,) noise std at the model rate, channel units.
        noise_source: channel -> where σ came from.
        description: why these windows ({"usable", "rejected", "how"}).
        warnings: the recording's warnings.
    """

    source: str
    vehicle: Vehicle
    longitudinal: LongitudinalMode
    channels: tuple[str, ...]
    windows: tuple[Window, ...]
    dt: float
    t: np.ndarray
    u: np.ndarray
    speed: np.ndarray | None
    accel: np.ndarray | None
    decimator: Decimator | None
    t_out: np.ndarray
    y: np.ndarray
    valid: np.ndarray
    train: np.ndarray
    held: np.ndarray
    v0: np.ndarray
    r0: np.ndarray
    sigma: np.ndarray
    sigma_raw: np.ndarray
    noise_source: dict
    description: dict
    warnings: tuple[str, ...] = ()

    @property
    def num_windows(self) -> int:
        return int(self.t.shape[0])

    @property
    def channel_index(self) -> tuple[int, ...]:
        return tuple(CHANNELS.index(c) for c in self.channels)

    @property
    def model_class(self) -> type:
        """`TorqueDriven` or `SpeedDriven`: the simulator model `longitudinal` names."""
        return model_class(self.longitudinal)

    def part(self, name: Part) -> np.ndarray:
        """The (W, K) mask of "train", "held" or "valid" samples."""
        if name not in ("train", "held", "valid"):
            raise ValueError(f"part must be 'train', 'held' or 'valid', got {name!r}")
        return getattr(self, name)

    def select(self, name: Part) -> Problem:
        """The windows holding any `name` samples, truncated after the last one.

        The simulation need not run past the last compared sample, so a "train" selection of a
        long drive does not simulate the held-out windows.
        """
        mask = self.part(name)
        keep = np.flatnonzero(mask.any(1))
        k_end = int(np.max(np.nonzero(mask[keep].any(0))[0])) + 1
        n_end = self.model_samples(k_end)
        cut = lambda a, n: None if a is None else a[keep, :n]
        return dataclasses.replace(
            self,
            windows=tuple(self.windows[i] for i in keep),
            t=cut(self.t, n_end),
            u=cut(self.u, n_end),
            speed=cut(self.speed, n_end),
            accel=cut(self.accel, n_end),
            t_out=cut(self.t_out, k_end),
            y=cut(self.y, k_end),
            valid=cut(self.valid, k_end),
            train=cut(self.train, k_end),
            held=cut(self.held, k_end),
            v0=self.v0[keep],
            r0=self.r0[keep],
        )

    def inputs(self) -> Inputs:
        """The W windows' inputs as one `Inputs` whose leaves are stacked over windows."""
        per = [
            Inputs(
                self.t[w, 0],
                self.dt,
                *self.u[w].T,
                speed=None if self.speed is None else self.speed[w],
                accel=None if self.accel is None else self.accel[w],
            )
            for w in range(self.num_windows)
        ]
        return jax.tree.map(lambda *a: jnp.stack(a), *per)

    def compare(self, readings):
        """Model readings (…, W, T, 6) at the model rate -> (…, W, K, C) compared samples."""
        ys = readings[..., list(self.channel_index)]
        if self.decimator is None:
            return ys
        lead = ys.shape[:-2]
        flat = ys.reshape((-1, *ys.shape[-2:]))
        out = jax.vmap(self.decimator)(flat)
        return out.reshape((*lead, *out.shape[-2:]))

    def summary(self) -> dict:
        """What a report says about the problem (JSON-ready)."""
        return {
            "recording": self.source,
            "longitudinal": self.longitudinal,
            "channels": list(self.channels),
            "windows": [
                {"t0": round(w.t0, 3), "t1": round(w.t1, 3), "role": w.role}
                | ({"held_from": round(w.split, 3)} if w.split is not None else {})
                for w in self.windows
            ],
            "train_seconds": round(float(self.train.sum()) * self.compared_dt, 2),
            "held_out_seconds": round(float(self.held.sum()) * self.compared_dt, 2),
            "filter": None
            if self.decimator is None
            else {"cutoff_hz": self.decimator.cutoff, "output_rate_hz": 1.0 / self.compared_dt},
            "noise_std": {c: float(s) for c, s in zip(self.channels, self.sigma)},
            "noise_source": dict(self.noise_source),
            "warnings": list(self.warnings),
            **self.description,
        }

    @property
    def factor(self) -> int:
        """Model samples per compared sample."""
        return 1 if self.decimator is None else self.decimator.factor

    @property
    def compared_dt(self) -> float:
        """Interval of the compared samples, s."""
        return self.dt * self.factor

    def model_samples(self, k_end: int) -> int:
        """Model-rate samples needed to produce the first `k_end` compared ones (a filtered
        sample reaches `factor − 1` samples past its own time)."""
        return min(self.t.shape[1], (k_end - 1) * self.factor + self.factor)


def compared_speed(problem: Problem) -> np.ndarray | None:
    """(W, K) forward speed at the compared samples, m/s: the measured speed (speed mode), else
    the vx channel, else the mean wheel speed × the free radius; None without any."""
    k = problem.y.shape[1]
    if problem.speed is not None:
        return problem.speed[:, :: problem.factor][:, :k]
    if "vx" in problem.channels:
        return problem.y[..., problem.channels.index("vx")]
    wheels = [problem.channels.index(c) for c in ("omega_front", "omega_rear") if c in problem.channels]
    if wheels:
        return problem.y[..., wheels].mean(-1) * problem.vehicle.wheel_radius
    return None


def top_speed(problem: Problem, quantile: float = 0.9) -> float | None:
    """The speed the drive exceeds on a share 1 − `quantile` of its compared samples, m/s; None
    without a speed (`compared_speed`)."""
    speed = compared_speed(problem)
    if speed is None:
        return None
    return float(np.quantile(speed[problem.train | problem.held], quantile))


def grip_used(problem: Problem, min_speed: float = 0.0) -> float | None:
    """How much of the grip μ·g the drive uses: the 99th percentile of |a_y| over the compared
    samples (the filtered ay channel, else speed × yaw rate) over vehicle.json's μ·g; None
    without a lateral channel. Above 0.5 Dugoff's tyre leaves its linear range.

    With `min_speed` (m/s) > 0, only over the samples at least that fast (where downforce
    would add grip): 0 where there are none, None also without a speed (`compared_speed`).
    """
    mask = problem.train | problem.held
    if min_speed > 0:
        speed = compared_speed(problem)
        if speed is None:
            return None
        mask = mask & (speed >= min_speed)
        if not mask.any():
            return 0.0
    if "ay" in problem.channels:
        lateral = problem.y[..., problem.channels.index("ay")][mask]
    elif "yaw_rate" in problem.channels and problem.speed is not None:
        speed = problem.speed[:, :: problem.factor]
        lateral = (problem.y[..., problem.channels.index("yaw_rate")] * speed)[mask]
    else:
        return None
    return float(np.quantile(np.abs(lateral), 0.99) / (problem.vehicle.friction * GRAVITY))


def yaw_at_zero_steer(
    problem: Problem, max_lag: float = 0.3, understeer: tuple[float, float] = (-0.01, 0.02)
) -> tuple[float, float] | None:
    """The yaw rate the car keeps at a logged steer of zero (at the drive's mean speed), rad/s,
    and its share of the yaw rate's spread (std) over the compared samples; None without a yaw
    rate or a measured speed.

    A steady turn obeys r = g·v·(δ + δ₀) / (L + K·v²) whatever the tyres (K the understeer
    gradient, s²/m): the measured yaw rate is regressed on v/(L + K·v²) and v·δ/(L + K·v²) for
    K on a grid over `understeer` and the response lag from 0 to `max_lag` s, and the best fit's
    g·δ₀ is a steer whose zero is not the car's straight ahead (sensor zero, alignment, crown).
    """
    if "yaw_rate" not in problem.channels or problem.speed is None:
        return None
    mask = problem.train | problem.held
    r = problem.y[..., problem.channels.index("yaw_rate")]
    k = r.shape[1]
    wheelbase = problem.vehicle.wheelbase
    v = problem.speed[:, :: problem.factor][:, :k]
    steer = problem.u[:, :: problem.factor, 0][:, :k]
    best = None
    for s in range(int(round(max_lag / problem.compared_dt)) + 1):
        m = mask[:, s:] & mask[:, : k - s]
        if m.sum() < 3:
            break
        vs, rs, ds = v[:, s:][m], r[:, s:][m], steer[:, : k - s][m]
        for gradient in np.linspace(*understeer, 31):
            denominator = wheelbase + gradient * vs**2
            if denominator.min() < 0.2 * wheelbase:  # at or past an oversteering car's critical speed
                continue
            design = np.stack([vs, vs * ds], axis=1) / denominator[:, None]
            coef, *_ = np.linalg.lstsq(design, rs, rcond=None)
            sse = float(np.sum((rs - design @ coef) ** 2))
            if best is None or sse < best[0]:
                v_mean = float(vs.mean())
                best = (sse, float(coef[0] * v_mean / (wheelbase + gradient * v_mean**2)), float(rs.std()))
    if best is None or best[2] == 0.0:
        return None
    return best[1], best[1] / best[2]
