"""`vdsbi diagnose` on several drives of one car at once: both drives' windows are fitted
together, the bias they share is named, and the identify command it prints takes both drives and
runs."""

from __future__ import annotations

import contextlib
import io
import json
import shlex
from pathlib import Path

import pytest
from drives import drive_csv

from vdsbi.cli import build_parser, main
from vdsbi.simulator import default_vehicle

NOISE = {"ax": 0.05, "ay": 0.05, "yaw_rate": 0.005, "omega_front": 0.1, "omega_rear": 0.1, "vx": 0.05}
BIAS = {"ax": 0.3, "ay": -0.25, "yaw_rate": 0.0}


@pytest.fixture(scope="module")
def pooled(tmp_path_factory):
    d = tmp_path_factory.mktemp("several")
    drives = [drive_csv(d / f"drive{seed}.csv", seed, {"sensor_bias": BIAS}, NOISE) for seed in (1, 2)]
    veh = d / "vehicle.json"
    veh.write_text(json.dumps({**default_vehicle().to_dict(), "noise_std": NOISE}))
    out = d / "diag"
    args = ["diagnose", *map(str, drives), "--vehicle", str(veh), "--out", str(out), "--final-dt", "0.005"]
    args += ["--effects", "sensor_bias,road_grade", "--max-effects", "1"]
    printed = io.StringIO()
    with contextlib.redirect_stdout(printed):
        assert main(args) == 0
    return drives, veh, out, printed.getvalue()


def test_both_drives_are_fitted_together_and_the_shared_bias_is_named(pooled):
    drives, _, out, _ = pooled
    rep = json.loads((out / "report.json").read_text())
    assert rep["source"] == " + ".join(str(p) for p in drives)
    assert rep["mismatch_detected"] and rep["chosen"] == ["sensor_bias"]
    # each drive's last part is held out, so both drives hold fitted and held-out samples
    assert set(rep["windows"]["recording"]) == {0, 1}
    assert abs(rep["effect_params"]["sensor_bias"]["ax"] - BIAS["ax"]) < 0.05


def test_the_printed_identify_command_takes_both_drives_and_runs(pooled):
    drives, veh, out, printed = pooled
    last = printed.strip().splitlines()[-1]
    argv = shlex.split(last)
    parsed = build_parser().parse_args(argv[1:])
    assert parsed.recording == [str(p) for p in drives] and parsed.effects == "+sensor_bias"
    # The neural posterior only proposes the likelihood fit's starts and the estimate is the fit's:
    # the printed command runs end to end, both its rounds, on fewer simulations per round.
    assert main([*argv[1:], "--sims", "150", "--quiet"]) == 0
    post = json.loads((Path(parsed.out) / "posterior.json").read_text())
    # both drives inform the one bias
    assert abs(post["parameters"]["sensor_bias.ax"]["estimate"] - BIAS["ax"]) < 0.02
