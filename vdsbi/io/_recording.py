"""The in-memory recording every reader produces: `Recording` (one drive on a uniform grid, its
channels and driver inputs), the contract's column names it relies on, and `speed_slope` (the
acceleration derived from a speed when `ax` is absent)."""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Iterable

import numpy as np
import pandas as pd

from ..simulator import INPUTS
from ..simulator.models import AbstractVehicleModel, LongitudinalMode, SpeedDriven, TorqueDriven, model_class
from ._errors import InputError

#: Columns every recording has.
REQUIRED: tuple[str, ...] = ("t", "steer")
#: Axle torques: optional, but a pair (both or neither).
TORQUES: tuple[str, ...] = tuple(c for c in INPUTS if c != "steer")
#: Channels a speed follows from (`vx`, else the wheel speeds × radius): one is required
#: without torques, since the longitudinal motion then follows the measured speed.
SPEED_CHANNELS: tuple[str, ...] = ("vx", "omega_front", "omega_rear")
#: Window, s, of the local quadratic fit whose slope is the acceleration when `ax` is absent.
ACCEL_WINDOW = 0.2


@dataclasses.dataclass(eq=False)
class Recording:
    """One drive on a uniform time grid, validated against the recording contract.

    Attributes:
        t: (T,) time stamps, s, uniform at `dt` = 1/`rate`.
        steer: (T,) front road-wheel angle, rad.
        torque_front: (T,) total front-axle wheel torque, N·m, or None if the recording has
            no torques (then `torque_rear` is None too).
        torque_rear: (T,) total rear-axle wheel torque, N·m, or None.
        channels: measured channels present, name -> (T,) array in SI units (a subset of
            `CHANNELS`, in `CHANNELS` order).
        source: where it came from (file name), used in messages.
        rate: sample rate of `t`, Hz (the model rate after reading).
        original_rate: sample rate of the file, Hz.
        warnings: non-fatal oddities found while reading (one line each).
    """

    t: np.ndarray
    steer: np.ndarray
    torque_front: np.ndarray | None
    torque_rear: np.ndarray | None
    channels: dict[str, np.ndarray]
    source: str
    rate: float
    original_rate: float
    warnings: list[str] = dataclasses.field(default_factory=list)

    def __post_init__(self):
        if (self.torque_front is None) != (self.torque_rear is None):
            raise ValueError(f"{self.source}: torque_front and torque_rear must both be arrays or both None")

    @property
    def has_torques(self) -> bool:
        """Whether the recording carries the applied axle torques."""
        return self.torque_front is not None

    @property
    def dt(self) -> float:
        return 1.0 / self.rate

    @property
    def num_samples(self) -> int:
        return int(self.t.shape[0])

    @property
    def duration(self) -> float:
        return float(self.t[-1] - self.t[0])

    @property
    def channel_names(self) -> tuple[str, ...]:
        return tuple(self.channels)

    def measured(self, names: Iterable[str] | None = None) -> np.ndarray:
        """Stack measured channels into a (T, C) array, in the order of `names` (default all)."""
        names = self.channel_names if names is None else tuple(names)
        missing = [n for n in names if n not in self.channels]
        if missing:
            raise KeyError(f"{self.source}: channel(s) {missing} not in recording {self.channel_names}")
        return np.stack([self.channels[n] for n in names], axis=-1)

    def inputs(
        self,
        *,
        longitudinal: LongitudinalMode | type[AbstractVehicleModel] | None = None,
        wheel_radius: float | None = None,
    ):
        """The driver inputs as a `vdsbi.simulator.Inputs` on this grid.

        Args:
            longitudinal: the model class or its mode's name: "torque" (`TorqueDriven`, the
                wheels are driven by the recorded torques) or "speed" (`SpeedDriven`, the
                longitudinal motion follows the measured speed); default "torque" if the
                recording has torques, else "speed".
            wheel_radius: m, turns wheel speeds into a speed in "speed" mode when `vx` is absent.

        Returns:
            "torque": `Inputs(t0, dt, steer, torque_front, torque_rear)`. "speed": the same with
            the recorded torques (zeros without them) and `speed` (T,) m/s from `speed()`,
            `accel` (T,) m/s²: the measured `ax`, else the slope of the speed over
            `ACCEL_WINDOW` s.

        Raises:
            InputError: "torque" without torques, or "speed" without a speed.
            ValueError: an unknown `longitudinal`.
        """
        from ..simulator import Inputs

        if issubclass(self._longitudinal(longitudinal), TorqueDriven):
            return Inputs(self.t[0], self.dt, self.steer, self.torque_front, self.torque_rear)
        return Inputs(**_speed_inputs(self, wheel_radius))

    def _longitudinal(self, longitudinal: LongitudinalMode | type[AbstractVehicleModel] | None) -> type:
        if longitudinal is None:
            return TorqueDriven if self.has_torques else SpeedDriven
        cls = model_class(longitudinal)
        if issubclass(cls, TorqueDriven) and not self.has_torques:
            raise InputError(
                self.source,
                "torque_front",
                "no torque columns, so the wheels cannot be driven by torques; expected torque_front "
                "and torque_rear, or the speed-driven mode (longitudinal='speed')",
            )
        return cls

    def speed(self, wheel_radius: float | None = None) -> np.ndarray | None:
        """(T,) forward speed, m/s: `vx` if present, else mean wheel speed × `wheel_radius`."""
        if "vx" in self.channels:
            return self.channels["vx"]
        omegas = [self.channels[c] for c in ("omega_front", "omega_rear") if c in self.channels]
        if not omegas or wheel_radius is None:
            return None
        return np.mean(omegas, axis=0) * wheel_radius

    def slice(self, t0: float, t1: float) -> Recording:
        """The samples with t0 <= t <= t1 (a view-free copy)."""
        m = (self.t >= t0 - 1e-9) & (self.t <= t1 + 1e-9)
        if m.sum() < 2:
            raise ValueError(f"{self.source}: slice [{t0}, {t1}] s holds fewer than 2 samples")
        return dataclasses.replace(
            self,
            t=self.t[m].copy(),
            steer=self.steer[m].copy(),
            torque_front=None if self.torque_front is None else self.torque_front[m].copy(),
            torque_rear=None if self.torque_rear is None else self.torque_rear[m].copy(),
            channels={k: v[m].copy() for k, v in self.channels.items()},
            warnings=list(self.warnings),
        )

    def to_frame(self) -> pd.DataFrame:
        """The contract's columns (no torque columns for a recording without torques)."""
        cols = {"t": self.t, "steer": self.steer}
        if self.has_torques:
            cols.update(torque_front=self.torque_front, torque_rear=self.torque_rear)
        cols.update(self.channels)
        return pd.DataFrame(cols)

    def to_csv(self, path: str | os.PathLike) -> None:
        """Write the contract's CSV (header row, SI units)."""
        self.to_frame().to_csv(path, index=False, float_format="%.10g")

    def to_parquet(self, path: str | os.PathLike) -> None:
        """Write the contract's columns as Parquet (float64)."""
        self.to_frame().to_parquet(path, index=False)


def _speed_inputs(rec: Recording, wheel_radius: float | None) -> dict[str, object]:
    """Keyword arguments of `Inputs` for the speed-driven mode (see `Recording.inputs`)."""
    speed = rec.speed(wheel_radius)
    if speed is None:
        if any(c in rec.channels for c in SPEED_CHANNELS):
            what = "no vx channel, and the speed from the wheel speeds needs the vehicle's wheel_radius"
        else:
            what = "no vx or wheel-speed channel; the speed-driven mode follows the measured speed"
        raise InputError(rec.source, "vx", what)
    if "ax" in rec.channels:
        accel = rec.channels["ax"]
    else:
        accel = speed_slope(speed, rec.dt)
    zero = np.zeros_like(rec.steer)
    return {
        "t0": rec.t[0],
        "dt": rec.dt,
        "steer": rec.steer,
        "torque_front": zero if rec.torque_front is None else rec.torque_front,
        "torque_rear": zero if rec.torque_rear is None else rec.torque_rear,
        "speed": speed,
        "accel": accel,
    }


def speed_slope(speed: np.ndarray, dt: float, window: float = ACCEL_WINDOW) -> np.ndarray:
    """(T,) time derivative, m/s², of a (T,) speed: slope of a local quadratic over `window` s.

    A Savitzky–Golay derivative: flat to ~2 Hz at 0.2 s, so speed quantisation and noise do not
    turn into large accelerations while braking and throttle transients survive.
    """
    from scipy.signal import savgol_filter

    n = speed.shape[0]
    w = max(5, int(round(window / dt)) | 1)
    if w > n:
        w = n if n % 2 else n - 1
    if w < 3:
        return np.gradient(speed, dt) if n > 1 else np.zeros_like(speed)
    return savgol_filter(speed, w, min(2, w - 1), deriv=1, delta=dt, mode="interp")
