"""What a platform's model misses, and what a car misses alone: `diagnose` on pooled drives.

Each answered drive carries its model error: per channel, the residual's RMS at its answer over
the sensor noise (`noise_ratio`). The platform's diagnosis pools the latest drive of each of its
cars (at most `MisfitSettings.most_cars`): whether the drives share a misfit is the diagnosis'
own misspecification test, and what it names (and claims, where the named effect also predicts
the pooled drives' held-out parts better) is the platform's. A car whose model error stands out
from its platform's on some channel on each of its latest drives (the least log ratio over its
latest `MisfitSettings.drives_per_car` drives more than `MisfitSettings.alone` robust standard
deviations above the other cars' median: a lagging actuator, a bent sensor mount; one drive's
misfit alone is that drive's, not the car's) is diagnosed alone on those drives and left out of
the platform's pool.

A diagnosis is kept in `misfit/<scope>/` beside a record of the drives it pooled; a re-run with
the same drives and settings reads it back instead of diagnosing again.
"""

from __future__ import annotations

import dataclasses
import json
import shutil
from collections.abc import Callable
from pathlib import Path

import numpy as np

from ..io import write_text_atomically
from ._manifest import Drive, safe_name

#: Median absolute deviation to the standard deviation of a normal sample.
MAD_TO_STD = 1.4826


@dataclasses.dataclass(frozen=True)
class MisfitSettings:
    """Which drives are diagnosed, and how.

    Attributes:
        alone: a car misses alone when its least log model-error ratio on a channel over its
            latest `drives_per_car` drives exceeds the other cars' median by this many robust
            standard deviations of the cars' (and by a factor 1.5 at least, so that cars that all
            fit alike flag none).
        min_cars: fewest cars of a platform for a car to be told from the others.
        most_cars: most cars whose latest drive the platform's diagnosis pools.
        drives_per_car: a car is judged, and diagnosed alone, on its latest this many drives.
        options: `vdsbi.api.diagnose` options (e.g. a smaller search), as (name, value) pairs.
    """

    alone: float = 3.0
    min_cars: int = 3
    most_cars: int = 4
    drives_per_car: int = 2
    options: tuple[tuple[str, object], ...] = ()


@dataclasses.dataclass(frozen=True)
class Misfit:
    """One diagnosis of pooled drives.

    Attributes:
        scope: "platform" or "car".
        platform: the platform (its vehicle file's stem).
        car: the car diagnosed alone (None for the platform).
        drives: the pooled drives' keys.
        detected: the pooled drives' residual is more than the sensor noise can explain.
        named: the effects the diagnosis chose.
        claimed: the named effects also predict the held-out parts better (the identify
            command is then printed).
        verdict: the diagnosis' own sentence.
        identify_command: how to identify the pooled drives with what was named (None unless
            claimed).
        folder: the diagnosis' folder, relative to the fleet's output.
    """

    scope: str
    platform: str
    car: str | None
    drives: tuple[str, ...]
    detected: bool
    named: tuple[str, ...]
    claimed: bool
    verdict: str
    identify_command: str | None
    folder: str

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)


def cars_missing_alone(records: list[dict], settings: MisfitSettings) -> dict[str, list[str]]:
    """{car: channels on which its model error stands out from its platform's} (module docstring)."""
    latest: dict[str, list[dict]] = {}
    for r in sorted(records, key=lambda r: r.get("order", 0.0)):
        latest.setdefault(r["car"], []).append(r)
    by_car: dict[str, dict[str, list[float]]] = {}
    for car, rs in latest.items():
        for r in rs[-settings.drives_per_car :]:
            for channel, ratio in (r.get("noise_ratio") or {}).items():
                if ratio and ratio > 0:
                    by_car.setdefault(car, {}).setdefault(channel, []).append(np.log(ratio))
    if len(by_car) < settings.min_cars:
        return {}
    out: dict[str, list[str]] = {}
    channels = sorted({c for per in by_car.values() for c in per})
    for channel in channels:
        med = {car: float(np.min(v[channel])) for car, v in by_car.items() if channel in v}
        if len(med) < settings.min_cars:
            continue
        values = np.array(list(med.values()))
        centre = float(np.median(values))
        spread = MAD_TO_STD * float(np.median(np.abs(values - centre)))
        for car, m in med.items():
            # judged against the other cars: one car's own excess does not widen its yardstick
            others = np.array([v for c, v in med.items() if c != car])
            ref = float(np.median(others))
            scale = max(spread, MAD_TO_STD * float(np.median(np.abs(others - ref))), 1e-9)
            if m - ref > max(settings.alone * scale, np.log(1.5)):
                out.setdefault(car, []).append(channel)
    return out


#: Runs `diagnose_pooled` on each of a list of pooled-drive sets and returns their results in order:
#: in this process by default; the fleet passes one that runs them on its cluster's workers.
Mapper = Callable[[Callable[["Pooled"], "Misfit"], list["Pooled"]], list["Misfit | BaseException"]]


@dataclasses.dataclass(frozen=True)
class Pooled:
    """One diagnosis to make: drives pooled for a platform (`car` None) or for one car alone."""

    vehicle: Path
    platform: str
    car: str | None
    drives: tuple[Drive, ...]
    out: Path
    settings: MisfitSettings

    @property
    def name(self) -> str:
        if self.car is None:
            return f"platform-{safe_name(self.platform)}"
        return f"car-{safe_name(self.car)}"

    @property
    def folder(self) -> Path:
        return self.out / "misfit" / self.name

    @property
    def ident(self) -> dict:
        return {"drives": [d.key for d in self.drives], "options": repr(self.settings.options)}

    def kept(self) -> Misfit | None:
        """The diagnosis of these same drives with the same options, kept by an earlier run."""
        kept = self.folder / "pooled.json"
        if not kept.exists():
            return None
        record = json.loads(kept.read_text())
        if record.get("ident") != self.ident:
            return None
        m = record["misfit"]
        return Misfit(**m | {"drives": tuple(m["drives"]), "named": tuple(m["named"])})


def in_process(fn, jobs):
    """The default `Mapper`: one after another, here; a failed diagnosis is returned, not raised."""
    out = []
    for job in jobs:
        try:
            out.append(fn(job))
        except Exception as err:  # noqa: BLE001 - one diagnosis failing leaves the others
            out.append(err)
    return out


def shared_misfit(
    drives: list[Drive],
    records: list[dict],
    out: Path,
    settings: MisfitSettings = MisfitSettings(),
    say: Callable[[str], None] = lambda s: None,
    run: Mapper = in_process,
) -> list[Misfit]:
    """Diagnose each platform's pooled drives and each car that misses alone (module docstring),
    the diagnoses not kept from an earlier run through `run`; write misfit.json. Drives not
    answered are left out; a diagnosis that fails is said and left out (a re-run retries it)."""
    jobs = plan_misfit(drives, records, out, settings, say)
    kept = [job.kept() for job in jobs]
    todo = [job for job, k in zip(jobs, kept, strict=True) if k is None]
    for job in todo:
        say(f"diagnosing {job.name} on {len(job.drives)} pooled drive(s)")
    done = iter(run(diagnose_pooled, todo))
    found = []
    for job, k in zip(jobs, kept, strict=True):
        result = k if k is not None else next(done)
        if isinstance(result, BaseException):
            say(f"{job.name}: diagnosis failed ({type(result).__name__}: {result}); a re-run retries it")
            continue
        found.append(result)
    write_text_atomically(out / "misfit.json", json.dumps([m.to_dict() for m in found], indent=1) + "\n")
    return found


def plan_misfit(
    drives: list[Drive], records: list[dict], out: Path, settings: MisfitSettings, say=lambda s: None
) -> list[Pooled]:
    """The diagnoses to make: each platform's pool, and each car that misses alone."""
    answered = {r["key"]: r for r in records if r.get("method") not in (None, "failed")}
    by_platform: dict[Path, list[Drive]] = {}
    for d in drives:
        if d.key in answered:
            by_platform.setdefault(d.vehicle, []).append(d)
    labels = platform_labels(list(by_platform))
    jobs = []
    for vehicle, group in by_platform.items():
        alone = cars_missing_alone([answered[d.key] for d in group], settings)
        latest = _latest(group)
        pooled = [ds[-1] for car, ds in latest.items() if car not in alone][-settings.most_cars :]
        if pooled:
            jobs.append(Pooled(vehicle, labels[vehicle], None, tuple(pooled), out, settings))
        for car, channels in alone.items():
            say(f"{car}: model error beyond its platform's on {', '.join(channels)}")
            own = latest[car][-settings.drives_per_car :]
            jobs.append(Pooled(vehicle, labels[vehicle], car, tuple(own), out, settings))
    return jobs


def platform_labels(vehicles: list[Path]) -> dict[Path, str]:
    """Each platform's name: its vehicle file's stem, with the folder before it where two
    platforms' files share a stem (every car's own vehicle.json)."""
    stems = [v.stem for v in vehicles]
    return {v: v.stem if stems.count(v.stem) == 1 else f"{v.parent.name}/{v.stem}" for v in vehicles}


def _latest(group: list[Drive]) -> dict[str, list[Drive]]:
    """Each car's drives, oldest first."""
    out: dict[str, list[Drive]] = {}
    for d in sorted(group, key=lambda d: d.order):
        out.setdefault(d.car, []).append(d)
    return out


def diagnose_pooled(job: Pooled) -> Misfit:
    """`api.diagnose` on the pooled drives into misfit/<name>/diagnose, kept beside their record."""
    from .. import api

    report = job.folder / "diagnose"
    # an interrupted diagnosis left a partial folder: diagnose writes into an empty one
    shutil.rmtree(report, ignore_errors=True)
    job.folder.mkdir(parents=True, exist_ok=True)
    found = api.diagnose(
        [d.recording for d in job.drives],
        job.vehicle,
        report,
        quiet=True,
        **dict(job.settings.options),
    )
    rep = found.report
    misfit = Misfit(
        scope="platform" if job.car is None else "car",
        platform=job.platform,
        car=job.car,
        drives=tuple(d.key for d in job.drives),
        detected=bool(rep["mismatch_detected"]),
        named=tuple(rep["chosen"]),
        claimed=rep.get("identify_command") is not None,
        verdict=str(rep["verdict"]),
        identify_command=rep.get("identify_command"),
        folder=str(report.relative_to(job.out)),
    )
    record = {"ident": job.ident, "misfit": misfit.to_dict()}
    write_text_atomically(job.folder / "pooled.json", json.dumps(record, indent=1) + "\n")
    return misfit
