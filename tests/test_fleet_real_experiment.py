"""experiments/fleet_sim.py --real on a drive whose truth is known: the fleet and `identify` alone
on its first 70 %, both scored on the rest beside the least-squares floor."""

import json
import math
import shutil

import pytest
from drives import fleet_drive

from experiments import fleet_sim


@pytest.mark.slow
def test_the_real_mode_scores_both_answers_on_the_held_out_rest(tmp_path):
    recording, vehicle, truth = fleet_drive(tmp_path / "sim", 40.0)
    car = tmp_path / "drives" / "a_car"
    car.mkdir(parents=True)
    shutil.copy(recording, car / "recording.csv")
    shutil.copy(vehicle, car / "vehicle.json")
    spec = json.loads(vehicle.read_text())
    l_f, l_r = truth["l_f"], spec["wheelbase"] - truth["l_f"]
    reference = {"l_f": l_f, "I_z": spec["mass"] * l_f * l_r, "source": "the simulation"}
    (car / "reference.json").write_text(json.dumps(reference))

    out = fleet_sim.real(tmp_path / "drives", workers=1, quick=True)

    row = out["a_car"]
    assert row["method"] in ("amortized", "amortized+fit", "identify")
    assert row["test_seconds"] > 5.0
    held = row["held_out"]
    for who in ("fleet", "identify"):
        scores, inside = held[who]["nrmse"], held[who]["band_coverage"]
        assert {"ay", "yaw_rate"} <= set(scores) and all(math.isfinite(v) for v in scores.values())
        assert all(0.7 <= inside[c] <= 1.0 for c in ("ay", "yaw_rate")), (who, inside)
        # the model the drive was simulated with predicts its held-out driving better than the
        # linear least-squares fit does
        for c in ("ay", "yaw_rate"):
            assert scores[c] < min(0.1, held["least_squares"][c]), (who, scores, held["least_squares"])
    assert "l_f" in row["parameters"]
    page = fleet_sim.real_markdown(out)
    assert "| a_car |" in page and "held-out" in page
