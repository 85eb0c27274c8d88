"""The recording contract's validation: `build_recording` checks the columns a reader found
(header, required columns, the torque pair, enough measured channels, numeric finite values, a
strictly increasing uniform time base, plausible units) and resamples them into a `Recording`,
raising `InputError` with the column and what was expected; `LIMITS` are the plausibility limits
that catch unit mistakes."""

from __future__ import annotations

import difflib
import os
from collections.abc import Mapping

import numpy as np
import pandas as pd

from ..simulator import CHANNELS, INPUTS
from ._consistency import consistency_warnings
from ._errors import InputError
from ._recording import REQUIRED, SPEED_CHANNELS, TORQUES, Recording
from ._resample import LOW_RATE, check_uniform, resample

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
    elif found and all(is_number(c) for c in found):
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


def is_number(s: str) -> bool:
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
    if 1.0 / dt < LOW_RATE * (1.0 - 1e-6):
        warnings.append(
            f"{source}: t: sample rate {1.0 / dt:.3g} Hz is below {LOW_RATE:g} Hz: the body's "
            "dynamics (1-3 Hz) are barely resolved; read and resampled, expect wide intervals"
        )
    signals = {k: data[k] for k in names[1:]}
    _check_finite(signals, t, source)
    n_sustain = max(1, int(round(SUSTAIN_WINDOW / dt)))
    _check_limits(signals, t, n_sustain, source)
    _check_wheel_sign(signals, t, n_sustain, source)
    return _assemble(t, signals, present, source, rate, 1.0 / dt, warnings)


def _check_header(columns: Mapping[str, np.ndarray], found: list[str], source: str) -> list[str]:
    """Check the header row, duplicates, the required columns and the torque pair; the torques given."""
    if found and all(is_number(c) for c in found):
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
