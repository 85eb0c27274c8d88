"""`observability`: Fisher information and Cramér–Rao bounds of θ (and of enabled effects'
parameters) for one maneuver."""

from __future__ import annotations

import dataclasses
import json
import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from ..io import InputError, Recording
from ..problem import make_problem
from ..simulator import CHANNELS, SEED_CHANNELS, Inputs, Vehicle
from ..simulator.effects import EffectSettings
from ..simulator.models import LongitudinalMode
from ._validate import (
    PROFILE_V0,
    NoiseName,
    checked_theta,
    checked_v0,
    first_speed,
    load_vehicle,
    noise_channels,
    sensor_noise,
)


@dataclasses.dataclass
class ObservabilityResult:
    """The Fisher report (`vdsbi.diagnostics.fisher_report`) of one maneuver, with the maneuver,
    v0, noise model, channels left out for want of a noise_std, and the effects enabled."""

    report: dict[str, Any]

    def markdown(self) -> str:
        from ..diagnostics import report_markdown

        r = self.report
        text = report_markdown(
            r, title=f"Observability: {r['maneuver']}, v0 = {r['v0']:.3g} m/s, {r['noise']} noise"
        )
        if "identifiability" in r:
            text += (
                f"\n## What this drive can tell ({r['longitudinal']}-driven, all windows)\n\n"
                "| param | identified | posterior std / prior std | why not |\n|---|---|---|---|\n"
            )
            for name, v in r["identifiability"].items():
                why = v["reason"] or ""
                text += f"| {name} | {'yes' if v['identified'] else 'no'} | {v['ratio']:.3g} | {why} |\n"
        return text

    def save(self, out: str | os.PathLike) -> None:
        """fisher.json and fisher.md into the directory `out`."""
        out = Path(out)
        (out / "fisher.json").write_text(json.dumps(self.report, indent=2, allow_nan=True) + "\n")
        (out / "fisher.md").write_text(self.markdown())


def observability(
    vehicle: str | os.PathLike | Vehicle,
    maneuver: Recording | Inputs,
    *,
    theta: Mapping[str, float] | Sequence[float] | None = None,
    v0: float | None = None,
    channels: Sequence[str] | None = None,
    noise: NoiseName = "seed",
    effects: EffectSettings = EffectSettings(),
    label: str | None = None,
) -> ObservabilityResult:
    """Fisher information of the parameters for `maneuver`, by forward-mode autodiff through
    the noise-free simulator in float64.

    Args:
        vehicle: vehicle constants (file or object).
        maneuver: a recording (its inputs and mode as `identify` sees them, by default the
            channels `identify` conditions on and its first speed; the report then also holds
            `identifiability` over the whole drive's windows), or an
            `Inputs` profile (by default the seed's five channels and v0 = 10.5 m/s).
        theta: parameters (array or {name: value} over the seed's Table II truth).
        v0: initial speed, m/s.
        channels: measured channels.
        noise: "seed" (relative) or "vehicle" (additive noise_std; channels without one are
            left out).
        effects: the effects to enable (their parameters join the matrix) and their parameter
            values (`EffectSettings`).
        label: the maneuver's name in the report (default: the recording's file, or "inputs").

    Raises:
        InputError: a value that does not fit the vehicle or the maneuver.
    """
    veh, source = load_vehicle(vehicle)
    rec, problem, mode, inputs = _maneuver(maneuver, veh)
    channels = _checked_channels(channels, problem)
    v0 = checked_v0(_default_v0(rec, veh) if v0 is None else v0)
    sensor = sensor_noise(noise, veh, source)
    channels, dropped = noise_channels(channels, sensor, source)
    th = checked_theta(theta, veh)
    model, params = _model(veh, effects, mode)
    rep = _report(model, th, inputs, v0, params, channels, sensor)
    if problem is not None:
        rep |= _identifiability(problem, th, veh)
    rep["maneuver"] = label or (rec.source if rec is not None else "inputs")
    rep["v0"] = v0
    rep["noise"] = noise
    rep["channels_without_noise_std"] = dropped
    rep["effects"] = list(effects.enabled)
    return ObservabilityResult(rep)


def _maneuver(maneuver: Recording | Inputs, vehicle: Vehicle):
    """``(recording or None, its Problem or None, longitudinal mode, inputs)``: a recording as
    `identify` sees it; an `Inputs` profile as is, torque-driven."""
    if not isinstance(maneuver, Recording):
        return None, None, "torque", maneuver
    problem = make_problem(maneuver, vehicle)
    mode = problem.longitudinal
    return maneuver, problem, mode, maneuver.inputs(longitudinal=mode, wheel_radius=vehicle.wheel_radius)


def _checked_channels(channels: Sequence[str] | None, problem) -> list[str]:
    """The measured channels: as given, else the problem's, else the seed's; all known ones."""
    channels = list(channels or (problem.channels if problem is not None else SEED_CHANNELS))
    bad = [c for c in channels if c not in CHANNELS]
    if bad:
        raise InputError(
            "--channels", "value", f"unknown channel(s) {bad} (expected some of {list(CHANNELS)})"
        )
    return channels


def _default_v0(rec: Recording | None, vehicle: Vehicle) -> float:
    """The recording's first speed, else the seed profile's."""
    return first_speed(rec, vehicle) if rec is not None else PROFILE_V0


def _report(model, theta, inputs, v0, params, channels, noise) -> dict:
    """`fisher_report` of the maneuver in float64."""
    import jax

    from ..diagnostics import MeasurementModel, fisher_report, model_fisher

    with jax.enable_x64(True):
        import jax.numpy as jnp

        fisher = model_fisher(
            model,
            jnp.asarray(theta, dtype=float),
            inputs,
            v0,
            tuple(jnp.asarray(p, dtype=float) for p in params),
            measurement=MeasurementModel(channels=channels, noise=noise),
        )
        return fisher_report(fisher)


def _identifiability(problem, theta, vehicle: Vehicle) -> dict:
    """A recording's identifiability over the whole drive as identify sees it (windows, shared
    filter, noise model), in float64."""
    import jax

    from ..diagnostics import identifiability

    with jax.enable_x64(True):
        return {
            "identifiability": identifiability(problem, theta, vehicle.default_prior()),
            "longitudinal": problem.longitudinal,
        }


def _model(vehicle: Vehicle, effects: EffectSettings, longitudinal: LongitudinalMode = "torque"):
    """The model with `effects` enabled and the effects' parameter vectors."""
    from ..simulator import make_model
    from ..simulator.effects import effect_params_from

    try:
        model = make_model(vehicle, list(effects.enabled), longitudinal=longitudinal)
        _, params = effect_params_from(list(effects.enabled), effects.params)
    except ValueError as err:
        raise InputError("arguments", "value", str(err)) from None
    return model, params
