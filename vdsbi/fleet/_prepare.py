"""A platform made ready on a worker: its model and prior from its drives, and its amortized
estimator trained once, saved beside the platform's record and reused on every later run."""

from __future__ import annotations

import hashlib
import json
from collections.abc import Sequence
from pathlib import Path

import jax
import numpy as np

from ..io import InputError, read_vehicle, write_text_atomically
from ..simulator.models import SpeedDriven
from ._amortized import AmortizedSettings, train_estimator
from ._manifest import Drive
from ._platform import WINDOW_SECONDS, Platform, drive_problem, make_platform, platform_from_dict
from ._shape import fixed_shape
from ._windows import window_pool


def vehicle_ident(vehicle_file: Path) -> str:
    """A platform's folder name: a hash of its vehicle file's constants (not of its path)."""
    record = json.dumps(read_vehicle(vehicle_file).to_dict(), sort_keys=True)
    return hashlib.sha1(record.encode()).hexdigest()[:12]


def settings_ident(settings: AmortizedSettings) -> str:
    return hashlib.sha1(repr(settings).encode()).hexdigest()[:12]


def pool_drives(drives: Sequence[Drive], most: int) -> list[Drive]:
    """Up to `most` drives, taken in turn from each car (every car's inputs in the pool)."""
    by_car: dict[str, list[Drive]] = {}
    for d in drives:
        by_car.setdefault(d.car, []).append(d)
    chosen, turn = [], 0
    while len(chosen) < most and any(turn < len(v) for v in by_car.values()):
        chosen += [v[turn] for v in by_car.values() if turn < len(v)][: most - len(chosen)]
        turn += 1
    return chosen


def prepare_platform(
    vehicle_file: Path,
    drives: Sequence[Drive],
    *,
    out: Path,
    settings: AmortizedSettings,
    seed: int,
    retrain: bool = False,
) -> tuple[Platform | None, Path | None, str | None]:
    """(platform, its estimator's folder, None), or (platform or None, None, why there is no
    estimator). The platform's record and estimator are reused when their settings match."""
    folder = out / "platforms" / vehicle_ident(vehicle_file)
    record_file = folder / "platform.json"
    wanted = settings_ident(settings)
    if record_file.exists() and (folder / "estimator.json").exists() and not retrain:
        record = json.loads(record_file.read_text())
        trained = json.loads((folder / "estimator.json").read_text())["training"]
        if trained.get("settings") == wanted:
            return platform_from_dict(record["platform"]), folder, None
    problems = []
    for d in pool_drives(drives, settings.pool_drives):
        try:
            problems.append(drive_problem(d.recording, d.vehicle))
        except InputError:
            continue  # that drive's own task reports it
    if not problems:
        return None, None, "no drive of the platform could be read"
    first = problems[0]
    if not issubclass(first.model_class, SpeedDriven):
        return None, None, "torque-driven platform: the amortized estimator needs the measured speed"
    platform = make_platform(vehicle_file, problems)
    shaped = []
    for p in problems:
        if platform.fits(p) is None:
            try:
                shaped.append(fixed_shape(p, WINDOW_SECONDS))
            except InputError:
                continue
    if not shaped:
        return platform, None, "no drive of the platform has windows the estimator can take"
    pool = window_pool(shaped, platform.effects)
    estimator = train_estimator(jax.random.fold_in(jax.random.key(seed), 7), pool, platform, settings)
    loss = estimator.info.get("best_val_loss")
    if loss is None or not np.isfinite(loss):
        # A diverged estimator would answer nothing: its drives go to identify, saying why.
        return platform, None, f"the platform's estimator did not train (validation loss {loss})"
    estimator.info["settings"] = wanted
    estimator.info["pool_drives"] = [str(d.recording) for d in pool_drives(drives, settings.pool_drives)]
    estimator.save(folder)
    write_text_atomically(record_file, json.dumps({"platform": platform.to_dict()}, indent=2) + "\n")
    return platform, folder, None
