"""A tiny fleet on a local cluster of 2 workers: a worker killed mid-drive loses nothing (its
drive is retried), estimates.csv has every drive's rows, and a re-run skips what is done."""

import json
import os
import signal
import threading
import time

import pytest

pytest.importorskip("distributed")

from vdsbi.fleet import (  # noqa: E402
    AmortizedSettings,
    Cluster,
    Escalation,
    FleetSettings,
    MisfitSettings,
    TrueChange,
    fleet,
    simulated_fleet,
)
from vdsbi.inference import TrainingSettings  # noqa: E402

pytestmark = pytest.mark.slow

#: The quick setting: a small estimator, a short identify for escalated drives.
QUICK = FleetSettings(
    amortized=AmortizedSettings(
        simulations=600,
        training=TrainingSettings(
            batch_size=128, learning_rate=1e-3, max_epochs=8, patience=4, cosine_decay=True
        ),
        draws_per_window=200,
    ),
    escalation=Escalation(rounds=1, sims=100, epochs=2, ppc_draws=10),
    # The platform's diagnosis only has to run and be linked here (test_fleet_misfit checks what it
    # names): a small null sample, no term search, no figures.
    misfit=MisfitSettings(
        most_cars=2,
        options=(
            ("candidates", ("sensor_bias",)),
            ("max_effects", 1),
            ("final_dt", 0.005),
            ("num_draws", 50),
            ("max_terms", 0),
            ("plots", False),
        ),
    ),
)


def _kill_first_running(out, killed: list, stop: threading.Event):
    """SIGKILL the worker process of the first drive seen running (its running.json's pid)."""
    while not stop.is_set() and not killed:
        for marker in sorted((out / "drives").glob("*/running.json")):
            try:
                info = json.loads(marker.read_text())
            except (OSError, ValueError):
                continue
            os.kill(int(info["pid"]), signal.SIGKILL)
            killed.append(marker.parent.name)
            return
        time.sleep(0.2)


def test_tiny_fleet_survives_a_killed_worker_and_reruns_skip(tmp_path):
    change = (TrueChange("car01", 1, scale={"C_alpha_f": 0.7, "C_alpha_r": 0.7}),)
    manifest = simulated_fleet(tmp_path / "fleet", cars=3, drives=2, duration=20.0, changes=change, seed=1)
    out = tmp_path / "out"
    cluster = Cluster(workers=2)  # XLA's default optimisation: the fit runs far slower at -O0
    killed, stop = [], threading.Event()
    killer = threading.Thread(target=_kill_first_running, args=(out, killed, stop), daemon=True)
    killer.start()
    try:
        first = fleet(manifest, out, QUICK, cluster)
    finally:
        stop.set()
    assert killed, "no drive was seen running"
    assert first.answered == 6 and first.skipped == 0
    assert all(r["method"] in ("amortized", "amortized+fit", "identify") for r in first.records), [
        r.get("error") for r in first.records
    ]
    retried = json.loads((out / "drives" / killed[0] / "result.json").read_text())
    assert retried["attempt"] >= 2
    lines = (out / "estimates.csv").read_text().splitlines()
    assert lines[0] == "car,recording,time,parameter,estimate,q05,q95,identified,method"
    names = first.records[0]["parameters"]
    assert len(lines) - 1 == 6 * len(names)
    assert (out / "changes.csv").read_text().startswith("car,parameter,time,before,after")
    assert "<img" in (out / "report.html").read_text()
    # the platform's two latest-driven cars' last drives, diagnosed together, linked from the report
    (platform,) = [m for m in first.misfits if m.scope == "platform"]
    assert len(platform.drives) == 2 and (out / platform.folder / "report.json").exists()
    assert f"{platform.folder}/report.html" in (out / "report.html").read_text()

    said = []
    again = fleet(manifest, out, QUICK, cluster, log=said.append)
    assert again.answered == 0 and again.skipped == 6
    assert not any(s.startswith("cluster:") for s in said)  # nothing left to run: no cluster started
    assert again.misfits == first.misfits  # read back, not diagnosed again
    assert (out / "estimates.csv").read_text().splitlines() == lines
