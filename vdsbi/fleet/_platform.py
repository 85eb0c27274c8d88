"""A platform: the cars that share a vehicle file, and so one model, one prior box and one
amortized estimator. Its identity is a hash of what the estimator depends on."""

from __future__ import annotations

import dataclasses
import hashlib
import json
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from ..io import InputError, load_drive, read_vehicle
from ..problem import (
    Box,
    Problem,
    ProblemSettings,
    default_effects,
    grip_used,
    make_problem,
    parameter_names,
    prior_box,
)
from ..simulator import Vehicle
from ..simulator.models import LongitudinalMode

#: Longest window of a fleet drive, s: identify's for drives that follow the measured speed.
MAX_WINDOW = 10.0
#: How a fleet drive is read: following the measured speed, all of it fitted.
DRIVE_SETTINGS = ProblemSettings(max_window=MAX_WINDOW, held_out=0.0, longitudinal="speed")
#: Fixed length every window is padded to, s (`fixed_shape`): the longest window the cut makes
#: (its edges move to the quietest moments nearby, past `MAX_WINDOW`).
WINDOW_SECONDS = DRIVE_SETTINGS.longest_window


def drive_problem(recording: Path, vehicle: Path) -> Problem:
    """A fleet drive as `identify` reads it following the measured speed, all of it fitted
    (nothing held out: the fleet checks its answer against the likelihood, not on a held-out
    part). The platform's estimator follows the speed, so a drive that logs wheel torques is
    answered that way too where it measures its speed (its C_κ, which only the torques inform, is
    then not identified); one without a measured speed is read torque-driven, and `identify`
    answers it."""
    rec, veh = load_drive(recording, vehicle)
    try:
        return make_problem(rec, veh, DRIVE_SETTINGS)
    except InputError:
        if not rec.has_torques:
            raise
        return make_problem(rec, veh, dataclasses.replace(DRIVE_SETTINGS, longitudinal="torque"))


def platform_effects(problems: Sequence[Problem]) -> tuple[str, ...]:
    """The effects every drive of the platform gets: the union of `identify`'s defaults
    (`vdsbi.problem.default_effects`) over its drives, in the registry's order."""
    from ..simulator.effects import EFFECTS

    chosen = {name for p in problems for name, _ in default_effects(p)}
    return tuple(e for e in EFFECTS if e in chosen)


@dataclasses.dataclass(frozen=True)
class Platform:
    """One platform's model.

    Attributes:
        vehicle_file: the vehicle file its cars share.
        vehicle: its constants.
        longitudinal: "speed" or "torque" (its drives' mode).
        channels: the channels its estimator conditions on.
        effects: effects whose parameters join θ.
        low, high: the prior box, in `names` order.
    """

    vehicle_file: Path
    vehicle: Vehicle
    longitudinal: LongitudinalMode
    channels: tuple[str, ...]
    effects: tuple[str, ...]
    low: tuple[float, ...]
    high: tuple[float, ...]

    @property
    def names(self) -> tuple[str, ...]:
        return parameter_names(self.effects)

    @property
    def box(self) -> Box:
        return Box(np.asarray(self.low), np.asarray(self.high), self.names)

    @property
    def ident(self) -> str:
        """A short hash of everything the estimator depends on (not the file's path)."""
        record = {
            "vehicle": self.vehicle.to_dict(),
            "longitudinal": self.longitudinal,
            "channels": list(self.channels),
            "effects": list(self.effects),
            "low": list(self.low),
            "high": list(self.high),
        }
        return hashlib.sha1(json.dumps(record, sort_keys=True).encode()).hexdigest()[:12]

    def fits(self, problem: Problem) -> str | None:
        """Why `problem` cannot use this platform's estimator, or None."""
        if problem.longitudinal != self.longitudinal:
            return f"{problem.longitudinal}-driven, the platform's estimator is {self.longitudinal}-driven"
        if tuple(problem.channels) != self.channels:
            return f"channels {', '.join(problem.channels)}, the platform's are {', '.join(self.channels)}"
        return None

    def to_dict(self) -> dict:
        return {
            "id": self.ident,
            "vehicle_file": str(self.vehicle_file),
            "vehicle": self.vehicle.to_dict(),
            "longitudinal": self.longitudinal,
            "channels": list(self.channels),
            "effects": list(self.effects),
            "prior": {n: [lo, hi] for n, lo, hi in zip(self.names, self.low, self.high)},
        }


def platform_from_dict(record: dict) -> Platform:
    """The `Platform` a `Platform.to_dict` record describes."""
    from ..simulator import Vehicle

    vehicle = Vehicle.from_dict(record["vehicle"])
    prior = record["prior"]
    return Platform(
        Path(record["vehicle_file"]),
        vehicle,
        record["longitudinal"],
        tuple(record["channels"]),
        tuple(record["effects"]),
        tuple(float(v[0]) for v in prior.values()),
        tuple(float(v[1]) for v in prior.values()),
    )


def make_platform(vehicle_file: Path, problems: Sequence[Problem]) -> Platform:
    """The platform of `vehicle_file` from its drives' problems: the first one's mode and
    channels, `platform_effects`, and the prior box for the most grip any of them uses."""
    veh = read_vehicle(vehicle_file)
    first = problems[0]
    effects = platform_effects(problems)
    grips = [g for p in problems if (g := grip_used(p)) is not None]
    bounds = prior_box(veh, effects, None, max(grips) if grips else None)
    names = parameter_names(effects)
    return Platform(
        Path(vehicle_file),
        veh,
        first.longitudinal,
        tuple(first.channels),
        effects,
        tuple(float(bounds[n][0]) for n in names),
        tuple(float(bounds[n][1]) for n in names),
    )
