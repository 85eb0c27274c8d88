"""The fleet's misfit: which car's model error stands out from its platform's (cheap, on records),
and `shared_misfit` diagnosing pooled drives end to end on a small fleet whose cars share an IMU
bias and one of which also lags its steer."""

from __future__ import annotations

import json

import pandas as pd
import pytest
from drives import drive_csv

from vdsbi.fleet._manifest import Drive, read_manifest
from vdsbi.fleet._misfit import MisfitSettings, cars_missing_alone, plan_misfit, shared_misfit
from vdsbi.simulator import default_vehicle


def _records(ratios: dict[str, list[float]], channel="yaw_rate") -> list[dict]:
    return [
        {"car": car, "key": f"{car}-{i}", "order": i, "noise_ratio": {channel: r, "ay": 1.2}}
        for car, rs in ratios.items()
        for i, r in enumerate(rs)
    ]


def test_a_car_whose_model_error_stands_out_is_told_from_its_platform():
    settings = MisfitSettings()
    alike = {"a": [1.1, 1.3], "b": [1.2, 1.0], "c": [1.4, 1.2], "d": [1.1, 1.2]}
    assert cars_missing_alone(_records(alike), settings) == {}
    # one car's yaw rate misfits four times the others': it alone, on that channel alone
    lagging = alike | {"d": [4.5, 5.0]}
    assert cars_missing_alone(_records(lagging), settings) == {"d": ["yaw_rate"]}
    # a platform whose cars all miss alike flags no car: that misfit is the platform's
    shared = {car: [5 * r for r in rs] for car, rs in alike.items()}
    assert cars_missing_alone(_records(shared), settings) == {}
    # one drive's misfit is that drive's: the car misses alone only on each of its latest drives
    assert cars_missing_alone(_records(alike | {"d": [1.1, 5.0]}), settings) == {}
    assert cars_missing_alone(_records(alike | {"d": [5.0, 1.1, 4.5, 5.0]}), settings) == {"d": ["yaw_rate"]}
    # two cars are too few to tell one from the other
    assert cars_missing_alone(_records({"a": [1.0], "d": [5.0]}), settings) == {}


NOISE = {"ay": 0.05, "yaw_rate": 0.003, "vx": 0.05}
BIAS = {"sensor_bias": {"ax": 0.0, "ay": 0.4, "yaw_rate": 0.0}}


@pytest.fixture(scope="module")
def fleet_folder(tmp_path_factory):
    """Three cars of one platform, two drives each (no torques), every IMU biased the same way."""
    d = tmp_path_factory.mktemp("misfit")
    (d / "vehicle.json").write_text(json.dumps({**default_vehicle().to_dict(), "noise_std": NOISE}))
    rows = []
    for i, car in enumerate(("car1", "car2", "car3")):
        for j in range(2):
            path = drive_csv(d / f"{car}_{j}.csv", 1 + 2 * i + j, BIAS, NOISE, torques=False)
            rows.append({"car": car, "recording": path.name, "vehicle": "vehicle.json", "time": j})
    pd.DataFrame(rows).to_csv(d / "manifest.csv", index=False)
    return d


# A 100-draw null still resolves p below 0.01. What is detected and named is decided before the
# term search describes what the named effects leave, and needs no figures: neither is run.
QUICK = MisfitSettings(
    most_cars=2,
    options=(
        ("candidates", ("sensor_bias", "road_grade")),
        ("max_effects", 1),
        ("final_dt", 0.005),
        ("num_draws", 100),
        ("max_terms", 0),
        ("plots", False),
    ),
)


def test_the_platform_diagnosis_pools_its_cars_and_names_the_shared_bias(fleet_folder, tmp_path):
    drives = read_manifest(fleet_folder / "manifest.csv")
    records = [
        {"car": d.car, "key": d.key, "method": "amortized+fit", "noise_ratio": {"ay": 3.0, "yaw_rate": 1.1}}
        for d in drives
    ]
    said = []
    found = shared_misfit(drives, records, tmp_path, QUICK, said.append)
    (platform,) = found
    assert platform.scope == "platform" and platform.car is None
    # the latest drive of the last two cars, pooled
    assert platform.drives == tuple(d.key for d in drives if d.car in ("car2", "car3") and d.time == "1")
    assert platform.detected and platform.named == ("sensor_bias",)
    report = json.loads((tmp_path / platform.folder / "report.json").read_text())
    assert set(report["windows"]["recording"]) == {0, 1}
    assert json.loads((tmp_path / "misfit.json").read_text())[0]["named"] == ["sensor_bias"]
    # a re-run with the same drives reads the diagnosis back
    said.clear()
    again = shared_misfit(drives, records, tmp_path, QUICK, said.append)
    assert again == found and not any("diagnosing" in s for s in said)


def test_a_failed_diagnosis_is_said_and_left_out_for_a_rerun(fleet_folder, tmp_path):
    drives = read_manifest(fleet_folder / "manifest.csv")
    records = [{"car": d.car, "key": d.key, "method": "amortized+fit", "noise_ratio": {}} for d in drives]
    said = []

    def failing(fn, jobs):
        return [RuntimeError("worker lost") for _ in jobs]

    assert shared_misfit(drives, records, tmp_path, QUICK, said.append, run=failing) == []
    assert any("diagnosis failed (RuntimeError: worker lost)" in s for s in said)
    assert json.loads((tmp_path / "misfit.json").read_text()) == []


def test_platforms_whose_vehicle_files_share_a_name_get_folders_of_their_own(tmp_path):
    # every car of its own platform, each with its own vehicle.json (the shared real drives)
    drives = [
        Drive(car, "r.csv", tmp_path / car / "r.csv", tmp_path / car / "vehicle.json", "0", 0.0, i + 2)
        for i, car in enumerate(("gti", "rav4", "race"))
    ]
    records = [{"car": d.car, "key": d.key, "method": "amortized+fit", "noise_ratio": {}} for d in drives]
    jobs = plan_misfit(drives, records, tmp_path, MisfitSettings())
    names = sorted(j.name for j in jobs)
    assert names == ["platform-gti_vehicle", "platform-race_vehicle", "platform-rav4_vehicle"]
    assert len({j.folder for j in jobs}) == 3
