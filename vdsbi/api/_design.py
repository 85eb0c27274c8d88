"""`design`: a maneuver optimised to make a parameter (or all of them) observable within
driving limits, with the Cramér–Rao bounds before and after."""

from __future__ import annotations

import dataclasses
import json
import os
import time
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ..io import InputError, Recording
from ..simulator import CHANNELS, PARAM_NAMES, SEED_CHANNELS, Vehicle
from ._validate import PROFILE_V0, NoiseName, checked_theta, load_vehicle, noise_channels, sensor_noise

if TYPE_CHECKING:
    from ..diagnostics import Limits


@dataclasses.dataclass
class DesignReport:
    """What `design` found.

    Attributes:
        bounds: CRB of the seed's maneuver ("before"), the optimiser's start and the designed
            maneuver ("after"), the improvement per parameter and the limits check.
        info: the designed maneuver's parameters, the limits, and the optimiser's history.
        recording: the designed maneuver's inputs and noise-free simulated channels.
    """

    bounds: dict[str, Any]
    info: dict[str, Any]
    recording: Recording

    def markdown(self) -> str:
        """bounds.md: the bounds before/after per parameter and the limits reached."""
        b = self.bounds
        lines = [
            f"# Designed maneuver: target {b['target']}",
            "",
            f"Noise: {b['noise']}. Before: {b['before']['maneuver']}. After: designed maneuver "
            f"(v0 = {b['after']['v0']:.3g} m/s). Limits respected: {b['limits_check']['respected']}.",
            "",
            "| parameter | CRB std before | CRB std after | improvement (before/after) |",
            "|---|---|---|---|",
        ]
        for n in b["before"]["crb_std"]:
            lo, hi = b["before"]["crb_std"][n], b["after"]["crb_std"][n]
            lines.append(f"| {n} | {lo:.4g} | {hi:.4g} | {lo / hi:.2f}× |")
        lines += [
            "",
            "log det F (scaled): before {:.3f}, after {:.3f}.".format(
                b["before"]["logdet_scaled"], b["after"]["logdet_scaled"]
            ),
        ]
        c = b["limits_check"]
        lo, hi = c["vx_range"]
        lines += [
            "",
            f"Limits: max |ay| {c['max_abs_ay']:.3f} ≤ {c['ay_limit']:.3f} m/s²; "
            f"vx {lo:.2f}..{hi:.2f} in [{c['speed_window'][0]:g}, {c['speed_window'][1]:g}] m/s; "
            f"|steer| {c['max_abs_steer']:.4f} ≤ {c['steer_limit']:g} rad; "
            f"drive {c['max_drive_torque']:.0f} ≤ {c['drive_limit']:g} N·m; "
            f"brake {c['max_brake_torque']:.0f} ≤ {c['brake_limit']:g} N·m.",
        ]
        return "\n".join(lines) + "\n"

    def save(self, out: str | os.PathLike) -> None:
        """maneuver.csv, bounds.json, bounds.md and design.json into the directory `out`."""
        out = Path(out)
        self.recording.to_csv(out / "maneuver.csv")
        (out / "bounds.json").write_text(json.dumps(self.bounds, indent=2) + "\n")
        (out / "bounds.md").write_text(self.markdown())
        (out / "design.json").write_text(json.dumps(self.info, indent=2) + "\n")


def design(
    vehicle: str | os.PathLike | Vehicle,
    *,
    target: str = "C_kappa_r",
    theta: Mapping[str, float] | Sequence[float] | None = None,
    noise: NoiseName = "seed",
    steps: int = 150,
    learning_rate: float = 0.05,
    limits: Limits | None = None,
    log: Callable[[str], None] | None = None,
) -> DesignReport:
    """Gradient ascent through the simulator on a maneuver's parameters (steer sines, pedal
    levels and timing, initial speed) that minimises the Cramér–Rao bound of `target` (or
    maximises log det F with target "D"), within |ay| ≤ 0.6·μ·g, the steer/torque limits and
    the speed window.

    Args:
        vehicle: vehicle constants (file or object).
        target: a PARAM_NAMES entry, or "D" for D-optimal.
        theta: parameters (array or {name: value} over the seed's Table II truth).
        noise: "seed" (relative) or "vehicle" (the vehicle's additive noise_std).
        steps, learning_rate: Adam steps and step size.
        limits: what the test drive may do (`vdsbi.diagnostics.Limits`; default: its defaults, a
            5 s maneuver in a 5–20 m/s speed window).
        log: where progress lines go, every 10 steps (default: nowhere).

    Raises:
        InputError: a target, θ, limit or noise model that does not fit.
    """
    import jax

    veh, source = load_vehicle(vehicle)
    _check_target_and_steps(target, steps)
    th = checked_theta(theta, veh)
    from ..diagnostics import Limits

    limits = Limits() if limits is None else limits
    sensor = sensor_noise(noise, veh, source)
    channels, _ = noise_channels(list(SEED_CHANNELS), sensor, source)
    with jax.enable_x64(True):
        import jax.numpy as jnp

        from ..diagnostics import Maneuver, MeasurementModel
        from ..simulator import make_model

        model, th = make_model(veh), jnp.asarray(th, dtype=float)
        problem = _problem(model, th, limits, target, channels, sensor)
        start = Maneuver.seed_like(limits)
        res = _optimise(problem, start, steps, learning_rate, log or (lambda s: None))
        designed, v0 = res.maneuver.inputs(limits), float(res.maneuver.initial_speed(limits))
        measurement = MeasurementModel(channels=channels, noise=sensor)
        bounds = _bounds(model, th, limits, (start, res.maneuver), measurement, target, noise)
        rec = _recording(model, th, designed, v0)
        described = res.maneuver.describe(limits)
    return DesignReport(bounds, _info(target, described, limits, steps, res), rec)


def _check_target_and_steps(target: str, steps: int) -> None:
    """InputError for a target that is neither a parameter nor "D", or a negative step count."""
    if target not in (*PARAM_NAMES, "D"):
        raise InputError("--target", "value", f"expected one of {[*PARAM_NAMES, 'D']}, got {target!r}")
    if steps < 0:
        raise InputError("--steps", "value", "must be >= 0")


def _problem(model, theta, limits, target: str, channels, noise):
    """`vdsbi.diagnostics.design_problem` for `target` ("D": log det F, no single parameter)."""
    from ..diagnostics import design_problem

    return design_problem(
        model,
        theta,
        limits,
        target=None if target == "D" else target,
        channels=channels,
        noise=noise,
    )


def _bounds(model, theta, limits, maneuvers: tuple, measurement, target: str, noise: NoiseName) -> dict:
    """bounds.json (`noise`: the noise model's name): the Fisher reports of `_reports` for
    ``maneuvers = (start, designed)``, the improvement per parameter (CRB std before / after)
    and the designed maneuver's limits check."""
    from ..diagnostics import check_limits

    start, maneuver = maneuvers
    designed, v0 = maneuver.inputs(limits), float(maneuver.initial_speed(limits))
    bounds = {"target": target, "noise": noise, "channels": measurement.channels}
    bounds |= _reports(model, theta, limits, start, maneuver, measurement)
    before, after = bounds["before"]["crb_std"], bounds["after"]["crb_std"]
    bounds["improvement"] = {n: before[n] / after[n] for n in before}
    bounds["limits_check"] = check_limits(model, theta, designed, v0, limits)
    return bounds


def _info(target: str, described, limits, steps: int, res) -> dict[str, Any]:
    """design.json: the designed maneuver, the limits and the optimiser's history."""
    return {
        "target": target,
        "maneuver": described,
        "limits": {k: getattr(limits, k) for k in limits.__dataclass_fields__},
        "steps": steps,
        "best_step": res.best_step,
        "history": {k: v.tolist() for k, v in res.history.items()},
    }


def _optimise(problem, start, steps: int, learning_rate: float, say: Callable[[str], None]):
    """`vdsbi.diagnostics.design_maneuver` with a progress line every 10 steps."""
    from ..diagnostics import design_maneuver

    t0 = time.perf_counter()

    def progress(i, obj):
        if i % 10 == 0 or i == steps:
            say(
                f"  step {i:4d}  objective {float(obj.value):9.4f}  penalty {float(obj.penalty):.2e}  "
                f"[{time.perf_counter() - t0:.0f} s]"
            )

    try:
        return design_maneuver(
            problem, start, num_steps=steps, learning_rate=learning_rate, callback=progress
        )
    except ValueError as err:
        raise InputError("limits", "value", str(err)) from None


def _reports(model, theta, limits, start, designed, measurement) -> dict[str, dict]:
    """Fisher reports ("before": the seed's profile, "start", "after": designed), with log det F."""
    from ..diagnostics import fisher_report, model_fisher
    from ..simulator import seed_profile

    maneuvers = {
        "before": (
            seed_profile(duration=limits.duration),
            PROFILE_V0,
            f"seed profile, {limits.duration:g} s, v0 = {PROFILE_V0} m/s",
        ),
        "start": (start.inputs(limits), float(start.initial_speed(limits)), "optimiser start (seed-like)"),
        "after": (designed.inputs(limits), float(designed.initial_speed(limits)), "designed"),
    }
    reports = {}
    for key, (inputs, v0, label) in maneuvers.items():
        rep = fisher_report(model_fisher(model, theta, inputs, v0, measurement=measurement))
        rep["maneuver"], rep["v0"] = label, v0
        rep["logdet_scaled"] = float(np.sum(np.log(rep["eigenvalues"])))
        reports[key] = rep
    return reports


def _recording(model, theta, inputs, v0) -> Recording:
    """The maneuver's inputs and noise-free simulated channels, as a recording."""
    import jax.numpy as jnp

    from ..simulator import solve

    ys, _ = solve(model, jnp.asarray(theta, dtype=float), inputs, jnp.asarray(v0, dtype=float))
    ys = np.asarray(ys, dtype=float)
    return Recording(
        t=np.asarray(inputs.ts, dtype=float),
        steer=np.asarray(inputs.steer, dtype=float),
        torque_front=np.asarray(inputs.torque_front, dtype=float),
        torque_rear=np.asarray(inputs.torque_rear, dtype=float),
        channels={c: ys[:, i] for i, c in enumerate(CHANNELS)},
        source="designed maneuver (noise-free simulation)",
        rate=1.0 / inputs.dt,
        original_rate=1.0 / inputs.dt,
    )
