"""The demo's drive (the README's first command) is always a valid, rolling recording."""

import json

import numpy as np
import pytest

from vdsbi.api._demo import demo_recording
from vdsbi.io import read_recording, read_vehicle


@pytest.mark.parametrize("seed", [0, 1])
def test_demo_recording_is_valid_and_keeps_rolling(tmp_path, seed):
    truth = demo_recording(tmp_path, duration=20.0, seed=seed)
    rec = read_recording(tmp_path / "recording.csv")
    read_vehicle(tmp_path / "vehicle.json")
    assert rec.duration == pytest.approx(20.0, abs=0.01)
    assert np.min(rec.channels["vx"]) > 4.0  # noisy vx; the noise-free speed stays > 5 m/s
    saved = json.loads((tmp_path / "truth.json").read_text())
    assert saved["concealed_effect"] == truth["concealed_effect"]


def test_demo_runs_the_whole_loop_into_one_folder(tmp_path):
    """A tiny demo: the base posterior is flagged (the band misses ax) with the diagnose command,
    diagnose names the bias, the second identify models it; one report.html per folder, each
    referencing only files that exist, and no file naming the temporary working folder."""
    from report_checks import check_folder

    from vdsbi import api

    budget = api.DemoBudget(
        duration=3.0,
        rounds=1,
        sims=100,
        epochs=3,
        diagnose={"candidates": ("sensor_bias",), "max_effects": 1, "final_dt": 0.005, "num_draws": 100},
        ppc_draws=30,
    )
    out = tmp_path / "demo"
    res = api.demo(out, budget=budget)
    # The base model misses the biased accelerometer by far more than its noise: said, with the
    # command to run.
    (miss,) = [w for w in res.identified.summary["warnings"] if w["kind"] == "model_error"]
    assert miss["channels"]["ax"] > 3.0
    assert (
        f"vdsbi diagnose {out}/recording.csv --vehicle {out}/vehicle.json --out {out}/diagnose"
        in miss["message"]
    )
    assert res.refined is not None and res.refined.summary["effects"] == ["sensor_bias"]
    for folder in (out, out / "identify", out / "diagnose", out / "identify-sensor_bias"):
        check_folder(folder)
    page = (out / "report.html").read_text()
    assert "sensor_bias.ax" in page and "truth" in page
    # The before/after overlay draws each run's band over the held-out part it was scored on.
    for run in (res.identified, res.refined):
        held = run.validation.held & run.validation.valid
        assert held.any() and np.isfinite(run.ppc["q95"][held]).all()
    for name in ("before_after.png", "pairplot_0.png", "pairplot_1.png"):
        assert (out / name).stat().st_size > 0
    posterior = json.loads((out / "identify" / "posterior.json").read_text())
    assert posterior["recording"] == str(out / "recording.csv")
