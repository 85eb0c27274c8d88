"""The shared option parsing (vdsbi/cli/_args.py) as every command sees it: bad θ, effects,
effect parameters and settings exit with status 2, one line naming the option's field, and no
output; good ones reach the library."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import pytest

from vdsbi.cli import main

GOOD = Path(__file__).parent / "data" / "good"
REC, VEHICLE = str(GOOD / "recording.csv"), str(GOOD / "vehicle.json")


@pytest.mark.parametrize(
    "argv, field",
    [
        (["observability", "--vehicle", VEHICLE, "--profile", "seed", "--theta", '{"l_f": 9}'], "l_f"),
        (["observability", "--vehicle", VEHICLE, "--profile", "seed", "--theta", "[1, 2]"], "--theta"),
        (
            ["observability", "--vehicle", VEHICLE, "--profile", "seed", "--effects", "warp_drive"],
            "warp_drive",
        ),
        (
            ["observability", "--vehicle", VEHICLE, "--profile", "seed"]
            + ["--effects", "aero_drag", "--effect-params", '{"aero_drag": {"cda": 1}}'],
            "aero_drag.cda",
        ),
        (["observability", "--vehicle", VEHICLE, "--profile", "seed", "--channels", "speed"], "--channels"),
        (["observability", "--vehicle", VEHICLE, "--profile", "seed", "--duration", "0"], "--duration"),
        (["design", "--vehicle", VEHICLE, "--theta", '{"h_cog": -1}'], "h_cog"),
        (["design", "--vehicle", VEHICLE, "--steps", "-1"], "--steps"),
        (["design", "--vehicle", VEHICLE, "--speed-window", "20", "5"], "limits"),
        (["diagnose", REC, "--vehicle", VEHICLE, "--effects", "sensor_bias,warp"], "warp"),
        (["identify", REC, "--vehicle", VEHICLE, "--max-duration", "0"], "--max-duration"),
        (["identify", REC, "--vehicle", VEHICLE, "--sims", "5"], "sims_per_round"),
        (["identify", REC, "--vehicle", VEHICLE, "--segment", "5:1"], "--segment"),
        (["sample", str(GOOD), "--n", "3"], "no estimator"),
    ],
)
def test_bad_option_exits_2_naming_it(tmp_path, capsys, argv, field):
    out = tmp_path / "out"
    assert main([*argv, "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("vdsbi: error:") and field in err and "\n" not in err, err
    assert not out.exists()


def test_observability_with_effects_from_a_theta_file(tmp_path):
    theta = tmp_path / "theta.txt"  # any file name: inline JSON starts with "{"
    theta.write_text(json.dumps({"l_f": 1.3}))
    out = tmp_path / "obs"
    argv = ["observability", "--vehicle", VEHICLE, "--profile", "seed", "--duration", "1.0"]
    argv += [
        "--theta",
        str(theta),
        "--effects",
        "aero_drag",
        "--effect-params",
        '{"aero_drag": {"CdA": 0.6}}',
    ]
    assert main([*argv, "--out", str(out)]) == 0
    rep = json.loads((out / "fisher.json").read_text())
    assert rep["effects"] == ["aero_drag"] and len(rep["params"]) > 6
    assert rep["maneuver"] == "seed profile, 1 s"


def test_every_help_page_formats():
    """`vdsbi --help` and each `vdsbi COMMAND --help` print (argparse %-formats help strings: a
    bare "%" in one breaks them all)."""
    from vdsbi.cli._main import build_parser

    parser = build_parser()
    assert "COMMAND" in parser.format_help()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    assert len(sub.choices) >= 5
    for name, p in sub.choices.items():
        assert name in p.format_help()
