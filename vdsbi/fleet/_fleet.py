"""`fleet`: every drive of a manifest answered on a cluster, the platforms' estimators trained once,
the results written as drives finish, then the changes per car and the report."""

from __future__ import annotations

import contextlib
import dataclasses
import hashlib
import json
import os
import time
from collections.abc import Callable
from pathlib import Path

from ..io import InputError, write_text_atomically
from ._amortized import AmortizedSettings
from ._changes import ChangeSettings
from ._drive import Escalation, answer_drive
from ._engine import Cluster, open_client
from ._manifest import Drive, read_manifest
from ._misfit import Misfit, MisfitSettings, shared_misfit
from ._prepare import prepare_platform
from ._report import write_report
from ._tables import append_estimates, fleet_changes, read_results, write_changes, write_estimates


@dataclasses.dataclass(frozen=True)
class FleetSettings:
    """How the fleet is answered.

    Attributes:
        amortized: the platforms' estimators.
        escalation: `identify`'s settings for drives whose check fails.
        changes: the sequential test per car and parameter.
        misfit: which pooled drives `diagnose` runs on (None: no diagnosis).
        seed: the only source of randomness.
    """

    amortized: AmortizedSettings = AmortizedSettings()
    escalation: Escalation = Escalation()
    changes: ChangeSettings = ChangeSettings()
    misfit: MisfitSettings | None = MisfitSettings()
    seed: int = 0

    @property
    def ident(self) -> str:
        """A drive's answer is reused on a re-run only when it was made with the same settings."""
        return hashlib.sha1(repr((self.amortized, self.escalation, self.seed)).encode()).hexdigest()[:12]


@dataclasses.dataclass(frozen=True)
class FleetResult:
    """What a fleet run did.

    Attributes:
        out: the output folder.
        records: every drive's result (this run's and earlier runs' with the same settings).
        changes: the detected changes.
        misfits: the platforms' and the cars' diagnoses.
        answered: drives answered in this run.
        skipped: drives already answered by an earlier run.
        seconds: wall time of this run.
    """

    out: Path
    records: list
    changes: list
    misfits: list[Misfit]
    answered: int
    skipped: int
    seconds: float

    def methods(self) -> dict[str, int]:
        out: dict[str, int] = {}
        for r in self.records:
            out[r["method"]] = out.get(r["method"], 0) + 1
        return out


def fleet(
    manifest: str | os.PathLike,
    out_dir: str | os.PathLike,
    settings: FleetSettings = FleetSettings(),
    cluster: Cluster = Cluster(),
    *,
    retrain: bool = False,
    log: Callable[[str], None] | None = None,
) -> FleetResult:
    """Answer every drive of `manifest` into `out_dir` (see the `vdsbi fleet` command).

    Writes out_dir/estimates.csv (rows appended as drives finish, rebuilt in order at the end),
    changes.csv, misfit.json and misfit/ (the pooled drives' diagnoses), report.html,
    drives/<drive>/result.json (and identify/ where a drive escalated) and platforms/<vehicle>/
    (the platform's record and its estimator). A re-run with the same settings skips the drives
    already answered; `retrain` trains the estimators again.

    Raises:
        InputError: a bad manifest (naming its line), or `out_dir` not a folder.
    """
    say = log or (lambda s: None)
    start = time.perf_counter()
    drives = read_manifest(manifest)
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise InputError(out, "--out", "exists and is not a directory")
    out.mkdir(parents=True, exist_ok=True)
    sid = settings.ident
    write_text_atomically(
        out / "fleet.json", json.dumps(_run_record(manifest, settings, cluster), indent=2) + "\n"
    )
    done = {r["key"] for r in read_results(out, sid) if r.get("method") != "failed"}
    todo = [d for d in drives if d.key not in done]
    estimates = out / "estimates.csv"
    write_estimates(estimates, [r for r in read_results(out, sid) if r["key"] in {d.key for d in drives}])
    say(
        f"{len(drives)} drives of {len({d.car for d in drives})} cars; "
        f"{len(drives) - len(todo)} already answered"
    )
    with contextlib.ExitStack() as stack:
        client = _Client(stack, cluster, say)
        answered = _run(todo, drives, out, settings, client, retrain, estimates, say) if todo else 0
        keys = {d.key for d in drives}
        records = [r for r in read_results(out, sid) if r["key"] in keys]
        write_estimates(estimates, records)
        changes = fleet_changes(records, settings.changes)
        write_changes(out / "changes.csv", changes)
        misfits = []
        if settings.misfit is not None:
            misfits = shared_misfit(drives, records, out, settings.misfit, say, run=client.map)
    seconds = time.perf_counter() - start
    write_report(out / "report.html", records, changes, seconds, misfits)
    return FleetResult(out, records, changes, misfits, answered, len(drives) - len(todo), seconds)


class _Client:
    """The run's cluster client, started on first use (a re-run with nothing left to do starts
    none) and closed with the run."""

    def __init__(self, stack: contextlib.ExitStack, cluster: Cluster, say):
        self.stack, self.cluster, self.say, self.client = stack, cluster, say, None

    def __call__(self):
        if self.client is None:
            self.client = self.stack.enter_context(open_client(self.cluster))
            self.say(f"cluster: {len(self.client.scheduler_info().get('workers', {}))} workers")
        return self.client

    def map(self, fn, jobs: list) -> list:
        """`fn` over `jobs` on the workers, results in order; a job that failed (or that a
        cluster left without workers could not run) gives its error instead."""
        if not jobs:
            return []
        client = self()
        stamp = time.time_ns()
        futures = {
            client.submit(fn, job, key=f"{fn.__name__}-{i}-{stamp}", pure=False): i
            for i, job in enumerate(jobs)
        }
        results: list = [RuntimeError("not run: the cluster had no workers")] * len(jobs)
        for future in _finished(client, futures, self.cluster, self.say):
            try:
                results[futures[future]] = future.result()
            except Exception as err:  # noqa: BLE001 - one job failing leaves the others
                results[futures[future]] = err
        return results


def _run(todo, drives, out, settings, run: _Client, retrain, estimates, say) -> int:
    """Submit each platform's preparation, then its drives (which wait for it); write each drive's
    rows as it finishes."""
    by_vehicle: dict[Path, list[Drive]] = {}
    for d in drives:
        by_vehicle.setdefault(d.vehicle, []).append(d)
    cluster, client = run.cluster, run()
    prepared = {}
    for vehicle, group in by_vehicle.items():
        if any(d in todo for d in group):
            prepared[vehicle] = client.submit(
                prepare_platform,
                vehicle,
                group,
                out=out,
                settings=settings.amortized,
                seed=settings.seed,
                retrain=retrain,
                key=f"platform-{vehicle.name}-{settings.ident}-{time.time_ns()}",
                pure=False,
            )
    futures = {
        client.submit(
            answer_drive,
            d,
            prepared[d.vehicle],
            out=out,
            seed=settings.seed,
            escalation=settings.escalation,
            settings_id=settings.ident,
            draws_per_window=settings.amortized.draws_per_window,
            key=f"drive-{d.key}-{time.time_ns()}",
            pure=False,
        ): d
        for d in todo
    }
    n, t0 = 0, time.perf_counter()
    for future in _finished(client, futures, cluster, say):
        d = futures[future]
        n += 1
        try:
            record = future.result()
        except Exception as err:  # the drive's workers died ALLOWED_FAILURES times
            say(
                f"[{n}/{len(todo)}] {d.car} {d.name}: not answered ({type(err).__name__}); "
                "a re-run retries it"
            )
            continue
        append_estimates(estimates, record)
        rate = n / (time.perf_counter() - t0) * 3600
        k = _k_text(record)
        say(
            f"[{n}/{len(todo)}] {d.car} {d.name}: {record['method']}{k} in {record['seconds']:.0f} s"
            f" (attempt {record.get('attempt', 1)}; {rate:.0f} drives/h)"
            + (f": {record['error']}" if record["method"] == "failed" else "")
        )
    return n


#: How often, s, a run waiting for its drives checks that the cluster still has workers.
WORKER_CHECK_S = 30.0
#: How long, s, a local cluster may have no workers before the drives left are given up.
NO_WORKERS_S = 180.0


def _finished(client, futures, cluster: Cluster, say):
    """The futures as they finish. A local cluster left without workers (every worker process
    gone, none restarted) gives up the drives left after `NO_WORKERS_S`, saying so, rather than
    wait forever; a cluster joined by address may get workers back, so it is waited for."""
    from distributed import wait

    pending, since = set(futures), None
    while pending:
        try:
            done = wait(pending, timeout=WORKER_CHECK_S, return_when="FIRST_COMPLETED").done
        except TimeoutError:
            done = set()
        yield from done
        pending -= done
        if done or client.scheduler_info().get("workers"):
            since = None
            continue
        since = since or time.perf_counter()
        waited = time.perf_counter() - since
        if cluster.address is None and waited > NO_WORKERS_S:
            say(
                f"the local cluster has had no workers for {waited:.0f} s: {len(pending)} drives "
                "not answered; a re-run retries them"
            )
            client.cancel(list(pending))
            return
        if waited >= WORKER_CHECK_S:
            say(f"no workers for {waited:.0f} s; {len(pending)} drives waiting")


def _k_text(record: dict) -> str:
    # The last check made (the amortized one, then each fit's in turn) decided the level.
    checks = list((record.get("checks") or {}).values())
    last = checks[-1] if checks else None
    return "" if not last or last.get("k_hat") is None else f" (k̂ {last['k_hat']:.2f})"


def _run_record(manifest, settings: FleetSettings, cluster: Cluster) -> dict:
    return {
        "manifest": str(Path(manifest).resolve()),
        "settings_id": settings.ident,
        "settings": repr(settings),
        "address": cluster.address,
        "workers": cluster.workers,
    }
