"""The in-memory recording every reader produces, and the contract's validation."""

from __future__ import annotations

import dataclasses
import difflib
import os
from collections.abc import Iterable, Mapping

import numpy as np
import pandas as pd

from ..simulator import CHANNELS, INPUTS, SpeedDriven, TorqueDriven, model_class
from ._errors import InputError
from ._resample import check_uniform, resample, running_mean

#: Columns every recording has.
REQUIRED: tuple[str, ...] = ("t", "steer")
#: Axle torques: optional, but a pair (both or neither).
TORQUES: tuple[str, ...] = tuple(c for c in INPUTS if c != "steer")
#: Channels a speed follows from (`vx`, else the wheel speeds × radius): one is required
#: without torques, since the longitudinal motion then follows the measured speed.
SPEED_CHANNELS: tuple[str, ...] = ("vx", "omega_front", "omega_rear")
#: Window, s, of the local quadratic fit whose slope is the acceleration when `ax` is absent.
ACCEL_WINDOW = 0.2
MIN_MEASURED = 2
#: Shortest accepted recording, s: the slowest dynamics of interest (yaw, wheel spin-up) settle
#: in well under a second, so less cannot inform the parameters.
MIN_DURATION = 1.0
#: "Sustained" plausibility checks use the centred running median over this window, s, so a
#: single glitch does not trip them but a signal in the wrong unit does.
SUSTAIN_WINDOW = 0.2

#: Plausibility limits (SI units) that catch unit mistakes. Each is far outside what a road
#: vehicle does and far inside what the usual wrong unit produces.
LIMITS: dict[str, tuple[float, str]] = {
    # Road-wheel angle: full lock on a passenger car is ~0.6 rad (35°); 1 rad is 57°.
    "steer": (1.0, "looks like degrees; expected the road-wheel angle in rad"),
    # 90 m/s = 324 km/h; a drive at >= 90 km/h logged in km/h trips it.
    "vx": (90.0, "looks like km/h; expected m/s"),
    # 3 rad/s = 172 deg/s, beyond any non-spinning car; yaw rates in deg/s reach it at ~3 deg/s.
    "yaw_rate": (3.0, "looks like deg/s; expected rad/s"),
    # 50 m/s² ≈ 5 g sustained over 0.2 s: crash level; mm/s² or cm/s² exceed it at once.
    "ax": (50.0, "implausible acceleration; expected m/s² (is it mm/s² or cm/s²?)"),
    "ay": (50.0, "implausible acceleration; expected m/s² (is it mm/s² or cm/s²?)"),
    # 300 rad/s · 0.3 m = 90 m/s; wheel speeds in rpm (≈ 9.5 × rad/s) or deg/s exceed it.
    "omega_front": (300.0, "looks like rpm or deg/s; expected rad/s"),
    "omega_rear": (300.0, "looks like rpm or deg/s; expected rad/s"),
    # 2e4 N·m per axle is ~3× the peak brake torque of a heavy passenger car.
    "torque_front": (2.0e4, "implausible axle torque; expected N·m (is it N·cm, or a force in N×100?)"),
    "torque_rear": (2.0e4, "implausible axle torque; expected N·m (is it N·cm, or a force in N×100?)"),
}
#: Wheel speeds below this (sustained, rad/s ≈ -1.5 m/s) mean a flipped sign or reverse driving,
#: which the model does not cover.
MIN_OMEGA = -5.0


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

    def inputs(self, *, longitudinal: str | type | None = None, wheel_radius: float | None = None):
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

    def _longitudinal(self, longitudinal: str | type | None) -> type:
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


def _running_median(x: np.ndarray, n: int) -> np.ndarray:
    if n <= 1:
        return x
    return pd.Series(x).rolling(n, center=True, min_periods=1).median().to_numpy()


def _where(t: np.ndarray, i: int) -> str:
    return f"row {i + 1} (t = {t[i]:.6g} s)"


def _missing_column_error(
    source: str, name: str, found: list[str], what: str = "missing required column"
) -> InputError:
    hint = ""
    close = difflib.get_close_matches(name, _unknown(found), n=1, cutoff=0.6)
    lowered = {c.strip().lower(): c for c in found}
    if name in lowered and lowered[name] != name:
        hint = f" (found '{lowered[name]}': names are case- and space-sensitive)"
    elif close:
        hint = f" (found '{close[0]}': misspelled?)"
    elif len(found) == 1 and any(sep in found[0] for sep in ";\t|"):
        hint = " (the header has a single column: expected comma-separated values)"
    elif found and all(_is_number(c) for c in found):
        hint = " (the first row holds numbers: is the header row missing?)"
    shown = ", ".join(found[:12]) + (", ..." if len(found) > 12 else "")
    return InputError(source, name, f"{what}{hint}; found columns: {shown}")


def _unknown(found: list[str]) -> list[str]:
    """The found columns that are not contract names (a contract name is no misspelling)."""
    known = {"t", *INPUTS, *CHANNELS}
    return [c for c in found if c not in known]


def _near(names: tuple[str, ...], found: list[str], cutoff: float) -> str:
    """Hints "'x' for 'name', ..." for found columns close to (not equal to) the wanted `names`."""
    pairs = []
    for name in names:
        if name in found:
            continue
        close = difflib.get_close_matches(name, _unknown(found), n=1, cutoff=cutoff)
        lowered = [c for c in found if c.strip().lower() == name]
        if lowered or close:
            pairs.append(f"'{(lowered or close)[0]}' for '{name}'")
    return ", ".join(pairs)


def _is_number(s: str) -> bool:
    try:
        float(s)
    except ValueError:
        return False
    return True


def build_recording(
    columns: Mapping[str, np.ndarray],
    source: str | os.PathLike,
    *,
    rate: float = 200.0,
) -> Recording:
    """Validate contract columns and resample them to `rate`: the constructor every reader uses.

    Args:
        columns: column name -> (T,) values, in file order (extra columns are ignored).
        source: file name for messages.
        rate: model rate, Hz.

    Raises:
        InputError: "<source>: <column>: <what was wrong and what was expected>".
    """
    source = str(source)
    found = [str(c) for c in columns]
    torques = _check_header(columns, found, source)
    warnings = _torque_warnings(torques, found, source)
    present = _check_measured(columns, found, torques, source)
    names = [*REQUIRED, *torques, *present]
    data = _to_numeric(columns, names, source)
    t = data["t"]
    dt = _check_time(t, source)
    signals = {k: data[k] for k in names[1:]}
    _check_finite(signals, t, source)
    n_sustain = max(1, int(round(SUSTAIN_WINDOW / dt)))
    _check_limits(signals, t, n_sustain, source)
    _check_wheel_sign(signals, t, n_sustain, source)
    return _assemble(t, signals, present, source, rate, 1.0 / dt, warnings)


def _check_header(columns: Mapping[str, np.ndarray], found: list[str], source: str) -> list[str]:
    """Check the header row, duplicates, the required columns and the torque pair; the torques given."""
    if found and all(_is_number(c) for c in found):
        raise InputError(source, "header", "the first row holds numbers; expected a header row t,steer,...")
    dup = sorted({c for c in found if found.count(c) > 1})
    if dup:
        raise InputError(source, dup[0], "duplicated column; expected each column once")
    for name in REQUIRED:
        if name not in columns:
            raise _missing_column_error(source, name, found)
    torques = [c for c in TORQUES if c in columns]
    if len(torques) == 1:
        (missing,) = [c for c in TORQUES if c not in columns]
        raise _missing_column_error(
            source,
            missing,
            found,
            f"missing column: {torques[0]} is given without it, but the axle torques come as a pair "
            "(both or neither)",
        )
    return torques


def _torque_warnings(torques: list[str], found: list[str], source: str) -> list[str]:
    """A warning when there are no torque columns but columns that look like misspelled ones."""
    warnings = []
    if not torques:
        near = _near(TORQUES, found, cutoff=0.8)
        if near:
            warnings.append(
                f"{source}: {', '.join(TORQUES)}: no torque columns, read without torques "
                f"(found {near}: misspelled?)"
            )
    return warnings


def _check_measured(
    columns: Mapping[str, np.ndarray], found: list[str], torques: list[str], source: str
) -> list[str]:
    """Check for enough measured channels, and a speed when there are no torques; the channels present."""
    present = [c for c in CHANNELS if c in columns]
    if len(present) < MIN_MEASURED:
        missing = [c for c in CHANNELS if c not in columns]
        near = {m: difflib.get_close_matches(m, _unknown(found), n=1, cutoff=0.6) for m in missing}
        hints = [f"'{v[0]}' for '{k}'?" for k, v in near.items() if v]
        raise InputError(
            source,
            "measured channels",
            f"found {present or 'none'} of {list(CHANNELS)}; expected at least {MIN_MEASURED}"
            + (f" (misspelled: {', '.join(hints)})" if hints else ""),
        )
    if not torques and not any(c in columns for c in SPEED_CHANNELS):
        near = _near((*TORQUES, *SPEED_CHANNELS), found, cutoff=0.6)
        raise InputError(
            source,
            "vx",
            "no torque columns (torque_front, torque_rear), so the longitudinal motion follows the "
            "measured speed: expected vx or the wheel speeds omega_front, omega_rear"
            + (f" (found {near}: misspelled?)" if near else "")
            + f"; found columns: {', '.join(found[:12])}"
            + (", ..." if len(found) > 12 else ""),
        )
    return present


def _to_numeric(columns: Mapping[str, np.ndarray], names: list[str], source: str) -> dict[str, np.ndarray]:
    """The columns `names` as 1-D float arrays; non-numeric cells (not empty ones) are an error."""
    data: dict[str, np.ndarray] = {}
    for name in names:
        x = np.asarray(columns[name])
        if x.ndim != 1:
            raise InputError(source, name, f"expected a 1-D column, got shape {x.shape}")
        if x.dtype.kind not in "fiub":
            num = pd.to_numeric(pd.Series(x), errors="coerce").to_numpy(dtype=float)
            bad = np.flatnonzero(np.isnan(num) & ~pd.isna(pd.Series(x)).to_numpy())
            if bad.size:
                raise InputError(
                    source,
                    name,
                    f"non-numeric value {x[bad[0]]!r} at row {bad[0] + 1}; expected numbers in SI units",
                )
            x = num
        data[name] = x.astype(float)
    return data


def _check_time(t: np.ndarray, source: str) -> float:
    """Check the time stamps: finite, strictly increasing, long enough and uniform; the step, s."""
    n = t.shape[0]
    if n == 0:
        raise InputError(source, "t", "no data rows; expected a header row followed by samples")
    bad_t = np.flatnonzero(~np.isfinite(t))
    if bad_t.size:
        raise InputError(source, "t", f"non-finite time stamp {t[bad_t[0]]} at row {bad_t[0] + 1}")
    if n < 2:
        raise InputError(source, "t", f"only {n} row; expected at least {MIN_DURATION:g} s of samples")
    steps = np.diff(t)
    if np.any(steps <= 0):
        i = int(np.flatnonzero(steps <= 0)[0])
        what = "duplicated" if steps[i] == 0 else "decreasing"
        raise InputError(
            source,
            "t",
            f"{what} time stamp {t[i + 1]:.6g} s at row {i + 2} after {t[i]:.6g} s at row {i + 1}; "
            "expected strictly increasing t",
        )
    if t[-1] - t[0] < MIN_DURATION:
        raise InputError(
            source,
            "t",
            f"recording spans {t[-1] - t[0]:.3g} s ({n} rows); expected at least {MIN_DURATION:g} s",
        )
    return check_uniform(t, source)


def _check_finite(signals: dict[str, np.ndarray], t: np.ndarray, source: str) -> None:
    """Every value of every signal is finite (the first NaN, empty cell or inf is reported)."""
    for name, x in signals.items():
        bad = np.flatnonzero(~np.isfinite(x))
        if bad.size:
            kind = "NaN (or empty cell)" if np.isnan(x[bad[0]]) else f"{x[bad[0]]}"
            raise InputError(source, name, f"{kind} at {_where(t, int(bad[0]))}; expected finite numbers")


def _check_limits(signals: dict[str, np.ndarray], t: np.ndarray, n_sustain: int, source: str) -> None:
    """No signal exceeds its plausibility limit in `LIMITS` over `n_sustain` samples (unit mistakes)."""
    for name, x in signals.items():
        limit, hint = LIMITS.get(name, (None, ""))
        if limit is None:
            continue
        smooth = np.abs(_running_median(x, n_sustain))
        if smooth.max() > limit:
            i = int(np.argmax(smooth))
            raise InputError(
                source,
                name,
                f"|{name}| = {smooth[i]:.4g} sustained over {SUSTAIN_WINDOW:g} s at {_where(t, i)} "
                f"exceeds {limit:g}: {hint}",
            )


def _check_wheel_sign(signals: dict[str, np.ndarray], t: np.ndarray, n_sustain: int, source: str) -> None:
    """No wheel speed stays below `MIN_OMEGA` over `n_sustain` samples (a flipped sign, or reverse)."""
    for name in ("omega_front", "omega_rear"):
        if name in signals:
            smooth = _running_median(signals[name], n_sustain)
            if smooth.min() < MIN_OMEGA:
                i = int(np.argmin(smooth))
                raise InputError(
                    source,
                    name,
                    f"wheel speed {smooth[i]:.4g} rad/s at {_where(t, i)} is below {MIN_OMEGA:g}: "
                    "expected forward driving with omega >= 0 (is the sign flipped?)",
                )


def _assemble(
    t: np.ndarray,
    signals: dict[str, np.ndarray],
    present: list[str],
    source: str,
    rate: float,
    original_rate: float,
    warnings: list[str],
) -> Recording:
    """Resample the validated signals to `rate`, then add the kinematic consistency checks' warnings."""
    t_new, out = resample(t, signals, rate)
    rec = Recording(
        t=t_new,
        steer=out["steer"],
        torque_front=out.get("torque_front"),
        torque_rear=out.get("torque_rear"),
        channels={c: out[c] for c in present},
        source=source,
        rate=float(rate),
        original_rate=float(original_rate),
        warnings=warnings,
    )
    rec.warnings.extend(consistency_warnings(rec))
    return rec


#: Running-mean window, s, for the kinematic consistency checks below.
_KIN_WINDOW = 0.5


def kinematic_slopes(rec: Recording, min_speed: float = 3.0) -> dict[str, float]:
    """Least-squares slopes of two kinematic identities, after a 0.5-s running mean.

    - "dvx/dt~ax": d(vx)/dt against ax (1 for consistent units and time base; 3.6 if vx is in
      km/h; 1/k if the time stamps are stretched k-fold).
    - "ay~vx*yaw_rate": ay against vx·yaw_rate (≈ 1 in steady cornering; ≈ 57 if yaw_rate is in
      deg/s, ≈ 1/3.6 if vx is in km/h).

    Only samples with vx > `min_speed` are used; a slope is omitted where its regressor has
    too little variation (std < 0.3 m/s²) to tell.
    """
    ch = rec.channels
    if "vx" not in ch:
        return {}
    n = max(1, int(round(_KIN_WINDOW * rec.rate)))
    vx = running_mean(ch["vx"], n)
    moving = vx > min_speed
    moving[: n // 2 + 1] = moving[-(n // 2 + 1) :] = False  # edges of the running mean are biased
    if moving.sum() < n:
        return {}
    out = {}
    if "ax" in ch:
        ax = running_mean(ch["ax"], n)[moving]
        dv = np.gradient(vx, rec.dt)[moving]
        if ax.std() > 0.3:
            out["dvx/dt~ax"] = float(np.sum(dv * ax) / np.sum(ax * ax))
    if "ay" in ch and "yaw_rate" in ch:
        ay = running_mean(ch["ay"], n)[moving]
        vr = running_mean(ch["vx"] * ch["yaw_rate"], n)[moving]
        if vr.std() > 0.3:
            out["ay~vx*yaw_rate"] = float(np.sum(ay * vr) / np.sum(vr * vr))
    return out


def consistency_warnings(rec: Recording) -> list[str]:
    """Raise on unit mistakes the kinematics reveal; return softer oddities as warning lines.

    Raises:
        InputError: d(vx)/dt ≈ 3.6·ax (vx in km/h) or ay ≈ vx·yaw_rate / 57 (yaw_rate in deg/s).
    """
    slopes = kinematic_slopes(rec)
    warnings = []
    s = slopes.get("dvx/dt~ax")
    if s is not None:
        if 2.8 < s < 4.6:
            raise InputError(rec.source, "vx", f"d(vx)/dt is {s:.2f} × ax: looks like km/h; expected m/s")
        if not 0.7 < s < 1.4:
            warnings.append(
                f"{rec.source}: t: d(vx)/dt is {s:.2f} × ax where 1 is expected: check the time base "
                f"(true rate {rec.original_rate / s:.4g} Hz?) or the units of vx and ax"
            )
    s = slopes.get("ay~vx*yaw_rate")
    if s is not None:
        if s < 0.05:
            raise InputError(
                rec.source,
                "yaw_rate",
                f"ay is {s:.3g} × vx·yaw_rate: yaw_rate looks like deg/s; expected rad/s",
            )
        if not 0.6 < s < 1.6:
            warnings.append(
                f"{rec.source}: ay: ay is {s:.2f} × vx·yaw_rate where ≈ 1 is expected in steady "
                "cornering: check signs and units of ay, vx, yaw_rate"
            )
    return warnings
