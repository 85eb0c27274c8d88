"""`make_problem`, the one function that turns a recording and a vehicle into a `Problem`, and
its stages: the longitudinal mode (`longitudinal_mode`), the conditioned channels, the stretch,
the windows with their held-out part, the model-rate inputs and initial states, the filter and
decimation, the compared samples and masks, the noise model and the warnings. It raises
`InputError` naming the recording and what is missing."""

from __future__ import annotations

from collections.abc import Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ..io import InputError, Recording
from ..simulator import CHANNELS, Vehicle
from ..simulator.measurement import Decimator
from ..simulator.models import (
    LONGITUDINAL_MODES,
    AbstractVehicleModel,
    LongitudinalChoice,
    LongitudinalMode,
    SpeedDriven,
    TorqueDriven,
    model_class,
)
from ._limit import slides
from ._measured import (
    TORQUE_SPEED_TOLERANCE,
    longitudinal_arrays,
    smoothed_yaw_rate,
    start_speed,
    torque_speed_error,
)
from ._noise import raw_noise_std
from ._problem import Problem, ProblemSettings
from ._windows import Window, choose_windows

#: Channels that are inputs, not evidence, when the longitudinal motion follows the measured
#: speed: vx is the speed itself, ax loads the tyres, and the wheel speeds are vx/R_eff.
SPEED_MODE_INPUT_CHANNELS = ("ax", "vx", "omega_front", "omega_rear")
#: Speed averaged over this long at a window start gives its initial speed, s.
V0_AVERAGE = 0.05


def longitudinal_mode(rec: Recording, longitudinal: LongitudinalChoice = "auto") -> LongitudinalMode:
    """ "torque" or "speed" for `rec`: "auto" is torque when it has torque columns.

    Raises:
        InputError: an unknown mode, or "torque" for a recording without torques.
    """
    return _longitudinal_model(rec, longitudinal).longitudinal


def _longitudinal_model(rec: Recording, longitudinal: LongitudinalChoice) -> type[AbstractVehicleModel]:
    """`TorqueDriven` or `SpeedDriven` for `rec` and a user's setting (`longitudinal_mode`)."""
    if longitudinal not in (*LONGITUDINAL_MODES, "auto"):
        raise InputError("settings", "--longitudinal", f"must be auto, torque or speed, got {longitudinal!r}")
    if longitudinal == "auto":
        return TorqueDriven if rec.has_torques else SpeedDriven
    model = model_class(longitudinal)
    if issubclass(model, TorqueDriven) and not rec.has_torques:
        raise InputError(
            rec.source,
            "torque_front",
            "no torque columns: the torque-driven model needs them; use the speed-driven mode "
            "(--longitudinal speed)",
        )
    return model


def _channels(
    rec: Recording, model: type[AbstractVehicleModel], settings: ProblemSettings
) -> tuple[str, ...]:
    speed_driven = issubclass(model, SpeedDriven)
    allowed = [c for c in CHANNELS if c in rec.channels]
    if speed_driven:
        allowed = [c for c in allowed if c not in SPEED_MODE_INPUT_CHANNELS]
    if settings.channels is not None:
        bad = [c for c in settings.channels if c not in allowed]
        if bad:
            raise InputError(
                rec.source,
                "channels",
                f"{bad} not available in {model.longitudinal} mode (available: {allowed})",
            )
        allowed = [c for c in CHANNELS if c in settings.channels]
    need = 1 if speed_driven else 2
    if len(allowed) < need:
        what = "ay or yaw_rate" if speed_driven else "at least 2 measured channels"
        raise InputError(
            rec.source,
            "channels",
            f"{model.longitudinal}-driven identification needs {what}; found {allowed}",
        )
    return tuple(allowed)


def _decimator(
    rec: Recording, model: type[AbstractVehicleModel], settings: ProblemSettings
) -> Decimator | None:
    cutoff = settings.bandwidth
    if cutoff == "auto":
        cutoff = None if issubclass(model, TorqueDriven) else 5.0
    if cutoff is None:
        return None
    factor = max(1, int(round(rec.rate / settings.output_rate)))
    if not 0 < float(cutoff) < 0.5 * rec.rate / factor:
        raise ValueError(
            f"bandwidth {cutoff} Hz must lie below the output Nyquist rate {0.5 * rec.rate / factor:g} Hz"
        )
    return Decimator(rate=rec.rate, cutoff=float(cutoff), factor=factor)


def _window_arrays(
    rec: Recording, windows: Sequence[Window], model: type[AbstractVehicleModel], vehicle: Vehicle
):
    """Model-rate arrays (W, T, …) of the windows, padded to a common length by holding the end."""
    idx = [
        (int(np.searchsorted(rec.t, w.t0 - 1e-9)), int(np.searchsorted(rec.t, w.t1 + 1e-9))) for w in windows
    ]
    n_max = max(i1 - i0 for i0, i1 in idx)
    torques = (rec.torque_front, rec.torque_rear) if rec.has_torques else (np.zeros_like(rec.t),) * 2
    u_all = np.stack([rec.steer, *torques], -1)
    speed_all, accel_all = longitudinal_arrays(rec, vehicle.wheel_radius, model)
    yaw_all = smoothed_yaw_rate(rec)

    def padded(a, i0, i1):
        seg = a[i0:i1]
        return np.concatenate([seg, np.repeat(seg[-1:], n_max - len(seg), axis=0)])

    t = np.stack([rec.t[i0] + rec.dt * np.arange(n_max) for i0, _ in idx])
    u = np.stack([padded(u_all, i0, i1) for i0, i1 in idx])
    speed = np.stack([padded(speed_all, i0, i1) for i0, i1 in idx])
    accel = np.stack([padded(accel_all, i0, i1) for i0, i1 in idx])
    n_v0 = max(1, int(round(V0_AVERAGE * rec.rate)))
    v0 = np.array([np.median(speed_all[i0 : i0 + n_v0]) for i0, _ in idx])
    r0 = np.array([yaw_all[i0] if yaw_all is not None else 0.0 for i0, _ in idx])
    lengths = np.array([i1 - i0 for i0, i1 in idx])
    if issubclass(model, TorqueDriven):
        speed = accel = None
    return idx, t, u, speed, accel, np.maximum(v0, 0.5), r0, lengths


def _compared(rec, channels, idx, n_max, decimator):
    """(W, K, C) measured channels, filtered and decimated exactly as the model's will be."""
    y_all = rec.measured(channels)
    ys = []
    for i0, i1 in idx:
        seg = y_all[i0:i1]
        ys.append(np.concatenate([seg, np.repeat(seg[-1:], n_max - len(seg), axis=0)]))
    y = np.stack(ys)
    if decimator is None:
        return y
    return np.asarray(_filtered(decimator, jnp.asarray(y)))


@eqx.filter_jit
def _filtered(decimator: Decimator, y):
    # One program per shape: run eagerly, the filter's dozen operations would each compile for
    # every new recording length (a third of a second per drive in a fleet).
    return jax.vmap(decimator)(y)


def _masks(windows, t_out, lengths, dt, burn_in):
    W, K = t_out.shape
    t_end = np.array([w.t0 + (n - 1) * dt for w, n in zip(windows, lengths)])
    valid = t_out <= t_end[:, None] + 1e-9
    after_burn = t_out >= np.array([w.t0 + burn_in for w in windows])[:, None] - 1e-9
    train = np.zeros((W, K), bool)
    held = np.zeros((W, K), bool)
    for i, w in enumerate(windows):
        if w.role == "held":
            held[i] = valid[i] & after_burn[i]
        elif w.split is None:
            train[i] = valid[i] & after_burn[i]
        else:
            # A short drive: the burn-in never takes more than half the fitted part.
            start = w.t0 + min(burn_in, 0.5 * (w.split - w.t0))
            train[i] = valid[i] & (t_out[i] >= start - 1e-9) & (t_out[i] < w.split - 1e-9)
            held[i] = valid[i] & (t_out[i] >= w.split - 1e-9)
    return valid, train, held


def make_problem(rec: Recording, vehicle: Vehicle, settings: ProblemSettings = ProblemSettings()) -> Problem:
    """The one function that turns a recording and a vehicle into a `Problem`.

    Stages: the longitudinal mode; the conditioned channels; the stretch (a user's segment or
    all of it); the windows and the held-out part; the model-rate inputs and initial states;
    the filter and decimation; the compared samples and masks; the noise model.

    Raises:
        InputError: naming the recording and what is missing (torques, speed, channels, a
            segment outside the recording).
    """
    model = _longitudinal_model(rec, settings.longitudinal)
    channels = _channels(rec, model, settings)
    if settings.segment is not None:
        rec = _restrict(rec, settings.segment)
    # Torque mode needs a speed at each window start only: measured, else estimated.
    speed_note = start_speed(rec, vehicle.wheel_radius)[1] if issubclass(model, TorqueDriven) else None
    windows, described = _select_windows(rec, vehicle, model, settings)
    idx, t, u, speed, accel, v0, r0, lengths = _window_arrays(rec, windows, model, vehicle)
    decimator = _decimator(rec, model, settings)
    factor = 1 if decimator is None else decimator.factor
    t_out = t[:, ::factor]
    y = _compared(rec, channels, idx, t.shape[1], decimator)
    valid, train, held = _masks(windows, t_out, lengths, rec.dt, settings.burn_in)
    segments = [(w.t0, w.t1) for w in windows]
    sigma_raw, source = raw_noise_std(rec, vehicle, channels, segments)
    warnings, described = _warnings(rec, vehicle, model, segments, speed_note, described)
    return Problem(
        source=rec.source,
        vehicle=vehicle,
        longitudinal=model.longitudinal,
        channels=channels,
        windows=tuple(windows),
        dt=rec.dt,
        t=t,
        u=u,
        speed=speed,
        accel=accel,
        decimator=decimator,
        t_out=t_out,
        y=y,
        valid=valid,
        train=train,
        held=held,
        v0=v0,
        r0=r0,
        sigma=sigma_raw * _noise_gain(decimator),
        sigma_raw=sigma_raw,
        noise_source=source,
        description=described,
        warnings=tuple(warnings),
    )


def _select_windows(
    rec: Recording, vehicle: Vehicle, model: type[AbstractVehicleModel], settings: ProblemSettings
):
    """`choose_windows` under `settings`, leaving out the slides `_limit_stretches` names."""
    return choose_windows(
        rec,
        settings,
        wheel_radius=vehicle.wheel_radius,
        torques=issubclass(model, TorqueDriven),
        exclude=_limit_stretches(rec, vehicle, settings),
    )


def _warnings(
    rec: Recording, vehicle: Vehicle, model: type[AbstractVehicleModel], segments, speed_note, described
) -> tuple[list[str], dict]:
    """The recording's and the torque check's warnings; an estimated start speed's note joins
    both the warnings and the description."""
    warnings = list(rec.warnings) + _torque_warning(rec, vehicle, model, segments)
    if speed_note is not None:
        warnings.append(f"{rec.source}: vx: {speed_note}")
        described = {**described, "initial_speed": speed_note}
    return warnings, described


def _noise_gain(decimator) -> float:
    """The std of white noise after the decimation filter, per unit std before (√Σ taps²)."""
    return 1.0 if decimator is None else float(np.sqrt(np.sum(np.asarray(decimator.taps) ** 2)))


def _torque_warning(
    rec: Recording, vehicle: Vehicle, model: type[AbstractVehicleModel], segments
) -> list[str]:
    if not issubclass(model, TorqueDriven):
        return []
    err = torque_speed_error(rec, vehicle.wheel_radius, vehicle.mass, segments)
    if err is None or err <= TORQUE_SPEED_TOLERANCE:
        return []
    return [
        f"the recorded torques do not explain the measured speed (a point mass driven by them misses "
        f"it by {err:.1f} m/s RMS per window): commanded, not applied? Try --longitudinal speed"
    ]


def _limit_stretches(rec: Recording, vehicle: Vehicle, settings: ProblemSettings):
    if not settings.exclude_slides:
        return []
    return slides(rec, wheel_radius=vehicle.wheel_radius, friction=vehicle.friction)


def _restrict(rec: Recording, segment: tuple[float, float]) -> Recording:
    t0, t1 = segment
    if not (rec.t[0] - 1e-9 <= t0 < t1 <= rec.t[-1] + 1e-9):
        raise InputError(
            rec.source,
            "--segment",
            f"[{t0}, {t1}] s is not inside the recording [{rec.t[0]:.3f}, {rec.t[-1]:.3f}] s",
        )
    return rec.slice(t0, t1)
