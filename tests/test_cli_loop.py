"""The user's loop on a drive with a concealed IMU bias, on small budgets: `identify` with the base
model warns and points to `diagnose`; `identify --effects sensor_bias` recovers the bias; the
written files name only the folders the user gave."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from vdsbi.cli import main
from vdsbi.simulator import (
    CHANNELS,
    SEED_TRUE_THETA,
    default_vehicle,
    seed_profile,
    simulate,
    theta_from_dict,
)

NOISE = {"ax": 0.05, "ay": 0.05, "yaw_rate": 0.005, "omega_front": 0.1, "omega_rear": 0.1, "vx": 0.05}
BIAS = {"ax": 0.3, "ay": -0.25, "yaw_rate": 0.0}
#: Base model: enough to see the band miss; with the effect: enough to learn the ax bias.
BASE = ["--rounds", "2", "--sims", "100", "--epochs", "3", "--samples", "300", "--quiet"]
WITH_EFFECT = ["--rounds", "2", "--sims", "200", "--epochs", "30", "--samples", "500", "--quiet"]


@pytest.fixture(scope="module")
def biased(tmp_path_factory) -> tuple[Path, Path]:
    """A 3 s drive of the built-in vehicle at the seed's truth with a concealed sensor bias."""
    d = tmp_path_factory.mktemp("biased")
    veh = default_vehicle()
    inp = seed_profile(duration=3.0)
    eff = {"sensor_bias": BIAS}
    ys, ok = simulate(
        theta_from_dict(SEED_TRUE_THETA), inp, veh, v0=10.0, effects=list(eff), effect_params=eff
    )
    assert ok
    rng = np.random.default_rng(0)
    df = pd.DataFrame({"t": np.asarray(inp.ts), "steer": np.asarray(inp.steer)})
    df["torque_front"], df["torque_rear"] = np.asarray(inp.torque_front), np.asarray(inp.torque_rear)
    for i, c in enumerate(CHANNELS):
        df[c] = np.asarray(ys)[:, i] + rng.normal(0.0, NOISE[c], len(df))
    df.to_csv(d / "rec.csv", index=False)
    (d / "vehicle.json").write_text(json.dumps({**veh.to_dict(), "noise_std": NOISE}))
    return d / "rec.csv", d / "vehicle.json"


def _identify(rec: Path, veh: Path, out: Path, *extra: str) -> dict:
    assert main(["identify", str(rec), "--vehicle", str(veh), "--out", str(out), *extra]) == 0
    return json.loads((out / "posterior.json").read_text())


@pytest.fixture(scope="module")
def base_run(biased, tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("loop") / "base"
    _identify(*biased, out, *BASE)
    return out


@pytest.fixture(scope="module")
def effect_run(biased, tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("loop") / "with_bias"
    _identify(*biased, out, *WITH_EFFECT, "--effects", "sensor_bias")
    return out


def test_base_model_on_a_biased_drive_warns_and_points_to_diagnose(biased, base_run, capsys):
    post = json.loads((base_run / "posterior.json").read_text())
    (miss,) = [w for w in post["warnings"] if w["kind"] == "predictive_miss"]
    assert "ax" in miss["channels"] and miss["channels"]["ax"] < 0.5
    assert "omega_front" not in miss["channels"]  # what the bias does not touch is reproduced
    rec, veh = biased
    assert f"vdsbi diagnose {rec} --vehicle {veh}" in miss["message"]


def test_identify_with_the_effect_recovers_the_bias(effect_run):
    post = json.loads((effect_run / "posterior.json").read_text())
    assert post["effects"] == ["sensor_bias"]
    params = post["parameters"]
    for ch in ("ax", "ay"):
        p = params[f"sensor_bias.{ch}"]
        assert p["prior"] == [-0.5, 0.5]  # the effect's typical range
        assert p["q05"] <= BIAS[ch] <= p["q95"], (ch, p)
    # Learned, not the prior back: a flat U(-0.5, 0.5) has std 0.29.
    assert params["sensor_bias.ax"]["std"] < 0.75 * 0.289
    samples = pd.read_csv(effect_run / "samples.csv")
    assert {"sensor_bias.ax", "sensor_bias.ay", "sensor_bias.yaw_rate"} <= set(samples.columns)
    # With the bias modelled the recording falls inside the predictive band again.
    assert not [w for w in post["warnings"] if w["kind"] == "predictive_miss"]


@pytest.fixture(scope="module")
def diagnosis(biased, tmp_path_factory):
    """`vdsbi diagnose` on the biased drive, searching two effects only (cheap)."""
    out = tmp_path_factory.mktemp("loop") / "diag"
    rec, veh = biased
    args = ["diagnose", str(rec), "--vehicle", str(veh), "--out", str(out), "--final-dt", "0.005"]
    return out, [*args, "--effects", "sensor_bias,road_grade", "--top-pairs", "0"]


def test_diagnose_ends_with_the_identify_command_that_models_what_it_named(biased, diagnosis, capsys):
    import shlex

    from vdsbi.cli import build_parser

    out, args = diagnosis
    assert main(args) == 0
    last = capsys.readouterr().out.strip().splitlines()[-1]
    rec, veh = biased
    assert last == f"vdsbi identify {rec} --vehicle {veh} --out {out}-identify --effects sensor_bias"
    parsed = build_parser().parse_args(shlex.split(last)[1:])
    assert parsed.effects == "sensor_bias" and parsed.recording == str(rec)
    assert last in (out / "report.md").read_text()
    assert json.loads((out / "report.json").read_text())["identify_command"] == last
