"""The user's loop on a drive with a concealed IMU bias, on small budgets: `diagnose` ends with the
`identify --effects` command; `identify --effects sensor_bias` recovers the bias; `export`; the
written files name only the folders the user gave (the base model's warning: test_cli_demo)."""

from __future__ import annotations

import contextlib
import io
import json
import shlex
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from report_checks import check_folder

from vdsbi.cli import main
from vdsbi.simulator import (
    CHANNELS,
    SEED_TRUE_THETA,
    default_vehicle,
    seed_profile,
    simulate,
    theta_from_dict,
)
from vdsbi.simulator.effects import EffectSettings

NOISE = {"ax": 0.05, "ay": 0.05, "yaw_rate": 0.005, "omega_front": 0.1, "omega_rear": 0.1, "vx": 0.05}
BIAS = {"ax": 0.3, "ay": -0.25, "yaw_rate": 0.0}


@pytest.fixture(scope="module")
def biased(tmp_path_factory) -> tuple[Path, Path]:
    """A 3 s drive of the built-in vehicle at the seed's truth with a concealed sensor bias."""
    d = tmp_path_factory.mktemp("biased")
    veh = default_vehicle()
    inp = seed_profile(duration=3.0)
    eff = {"sensor_bias": BIAS}
    effects = EffectSettings(enabled=list(eff), params=eff)
    ys, ok = simulate(theta_from_dict(SEED_TRUE_THETA), inp, veh, v0=10.0, effects=effects)
    assert ok
    rng = np.random.default_rng(0)
    df = pd.DataFrame({"t": np.asarray(inp.ts), "steer": np.asarray(inp.steer)})
    df["torque_front"], df["torque_rear"] = np.asarray(inp.torque_front), np.asarray(inp.torque_rear)
    for i, c in enumerate(CHANNELS):
        df[c] = np.asarray(ys)[:, i] + rng.normal(0.0, NOISE[c], len(df))
    df.to_csv(d / "rec.csv", index=False)
    (d / "vehicle.json").write_text(json.dumps({**veh.to_dict(), "noise_std": NOISE}))
    return d / "rec.csv", d / "vehicle.json"


@pytest.fixture(scope="module")
def effect_run(diagnosis) -> Path:
    """The identify command diagnose printed, pasted into the command line as it was printed
    (`--quiet` only silences it) and run to the end."""
    _, printed = diagnosis
    argv = shlex.split(printed.strip().splitlines()[-1])
    assert argv[0] == "vdsbi"
    assert main([*argv[1:], "--quiet"]) == 0
    return Path(argv[argv.index("--out") + 1])


def test_the_printed_identify_command_runs_and_recovers_the_bias(effect_run, diagnosis):
    post = json.loads((effect_run / "posterior.json").read_text())
    assert post["effects"] == ["sensor_bias"]
    params = post["parameters"]
    # The priors are the ranges the diagnosis measured and printed.
    _, printed = diagnosis
    argv = shlex.split(printed.strip().splitlines()[-1])
    priors = [argv[i + 1] for i, a in enumerate(argv) if a == "--prior"]
    assert priors
    for item in priors:
        name, rng = item.split("=")
        assert params[name]["prior"] == pytest.approx([float(v) for v in rng.split(":")])
    # ax's bias is what this 3 s drive determines (the ay bias trades against the start state).
    p = params["sensor_bias.ax"]
    assert p["q05"] <= BIAS["ax"] <= p["q95"], p
    assert abs(p["estimate"] - BIAS["ax"]) < 0.05
    # Learned, not the prior back: a flat U(-0.5, 0.5) has std 0.29.
    assert params["sensor_bias.ax"]["std"] < 0.75 * 0.289
    samples = pd.read_csv(effect_run / "samples.csv")
    assert {"sensor_bias.ax", "sensor_bias.ay", "sensor_bias.yaw_rate"} <= set(samples.columns)
    # With the bias modelled the recording falls inside the predictive band again.
    assert not [w for w in post["warnings"] if w["kind"] == "predictive_miss"]


@pytest.fixture(scope="module")
def diagnosis(biased, tmp_path_factory) -> tuple[Path, str]:
    """`vdsbi diagnose` on the biased drive, searching two effects only and no terms (cheap; what
    it names and the command it prints come before the term search): its folder and what it
    printed."""
    out = tmp_path_factory.mktemp("loop") / "diag"
    rec, veh = biased
    args = ["diagnose", str(rec), "--vehicle", str(veh), "--out", str(out), "--final-dt", "0.005"]
    args += ["--effects", "sensor_bias,road_grade", "--max-effects", "1", "--max-terms", "0"]
    printed = io.StringIO()
    with contextlib.redirect_stdout(printed):
        assert main(args) == 0
    return out, printed.getvalue()


def test_diagnose_ends_with_the_identify_command_that_models_what_it_named(biased, diagnosis):
    import shlex

    from vdsbi.cli import build_parser

    out, printed = diagnosis
    last = printed.strip().splitlines()[-1]
    rec, veh = biased
    target = out.parent / "identify-sensor_bias"
    head = f"vdsbi identify {rec} --vehicle {veh} --out {target} --effects +sensor_bias"
    assert last.startswith(head)
    parsed = build_parser().parse_args(shlex.split(last)[1:])
    assert parsed.effects == "+sensor_bias" and parsed.recording == [str(rec)]
    # The priors are the ranges the diagnosis measured: each holds the value it reports.
    rep = json.loads((out / "report.json").read_text())
    priors = dict(p.split("=") for p in parsed.prior)
    assert set(priors) == {f"sensor_bias.{k}" for k in rep["effect_params"]["sensor_bias"]}
    for k, v in rep["effect_params"]["sensor_bias"].items():
        lo, hi = map(float, priors[f"sensor_bias.{k}"].split(":"))
        assert lo < v < hi
    assert last in (out / "report.md").read_text()
    assert json.loads((out / "report.json").read_text())["identify_command"] == last


def test_diagnose_names_the_bias_writes_its_figures_and_leaves_the_precision_alone(diagnosis):
    import jax

    out, _ = diagnosis
    assert json.loads((out / "report.json").read_text())["chosen"] == ["sensor_bias"]
    for f in ("report.md", "residual_heatmap.png", "overlay.png", "residual_spectra.png"):
        assert (out / f).stat().st_size > 0, f
    assert jax.config.jax_enable_x64 is False  # diagnose leaves the global precision alone


def test_every_folder_has_a_report_page_and_names_no_temporary_folder(effect_run, diagnosis):
    out, _ = diagnosis
    for folder in (effect_run, out):
        check_folder(folder)
    assert "sensor_bias.ax" in (effect_run / "report.html").read_text()


def test_the_report_says_what_was_held_out_and_what_the_drive_determines(effect_run):
    page = (effect_run / "report.html").read_text()
    # Its overlay greys the held-out part; its header says so.
    assert "none held out" not in page and "the last 30% of each held out" in page
    assert "understeer gradient" in page and "steady-state yaw-rate gain at" in page
    post = json.loads((effect_run / "posterior.json").read_text())
    # Pairs that trade are named as pairs, and neither member is identified alone.
    for pair in post["combinations"]["trading_pairs"]:
        assert abs(pair["correlation"]) >= 0.9 and set(pair["direction"]) == set(pair["pair"])
        for a, b in (pair["pair"], pair["pair"][::-1]):
            assert post["parameters"][a]["identified"] is False and b in post["parameters"][a]["trades_with"]
    # Nor is one its prior box holds: an interval over 80 % of the box, an estimate on a bound.
    for p in post["parameters"].values():
        lo, hi = p["prior"]
        spans = p["q95"] - p["q05"] >= 0.8 * (hi - lo)
        on_bound = min(p["estimate"] - lo, hi - p["estimate"]) <= 0.05 * (hi - lo)
        assert not ((spans or on_bound) and p["identified"]), p


def test_export_autoware_keys_as_the_mpc_lateral_controller_reads_them(effect_run, tmp_path):
    import yaml

    from vdsbi.simulator import default_vehicle

    # The keys and units on the run's own numbers.
    post = json.loads((effect_run / "posterior.json").read_text())
    # What the drive says about the steer signal travels as comments.
    like = post["parameters"]["l_f"]
    post["parameters"]["signal_delay.delay"] = like | {"estimate": 0.123, "q05": 0.1, "q95": 0.15}
    post["parameters"]["steer_offset.offset"] = like | {"estimate": -0.00123, "q05": -0.002, "q95": 0.0}
    run = tmp_path / "run"
    run.mkdir()
    (run / "posterior.json").write_text(json.dumps(post))
    assert main(["export", str(run), "--format", "autoware", "--out", str(tmp_path / "a.yaml")]) == 0
    text = (tmp_path / "a.yaml").read_text()
    doc = yaml.safe_load(text)["/**"]["ros__parameters"]
    assert doc["vehicle_model_type"] == "dynamics"
    v = doc["vehicle"]
    assert set(v) == {"cf", "cr", "mass_fl", "mass_fr", "mass_rl", "mass_rr"}
    p = post["parameters"]
    # Per-axle cornering stiffness in both: written unconverted.
    assert v["cf"] == pytest.approx(p["C_alpha_f"]["estimate"], abs=1e-3)
    assert v["cr"] == pytest.approx(p["C_alpha_r"]["estimate"], abs=1e-3)
    veh = default_vehicle()
    front = v["mass_fl"] + v["mass_fr"]
    assert front + v["mass_rl"] + v["mass_rr"] == pytest.approx(veh.mass, abs=0.01)
    # Autoware's DynamicsBicycleModel: l_f = L (1 - m_front / m) gives back our l_f.
    assert veh.wheelbase * (1 - front / veh.mass) == pytest.approx(p["l_f"]["estimate"], abs=1e-4)
    assert post["recording"] in text and "90 %" in text and "sensor_bias" in text
    assert "delay = 0.123 [0.100, 0.150] s" in text and "input_delay" in text
    assert "offset = -0.00123 [-0.00200, 0.00000] rad" in text


def test_export_writes_an_unidentified_stiffness_whose_estimate_predicts_the_held_out_part(
    effect_run, tmp_path, capsys
):
    import yaml

    post = json.loads((effect_run / "posterior.json").read_text())
    assert post["validation"]["estimate"]["channels"]  # the run held its last 30 % out
    car = post["parameters"]["C_alpha_r"]
    car |= {"identified": False, "not_identified_because": "trades with l_f along a ridge (ρ = +0.93)"}
    run = tmp_path / "run"
    run.mkdir()
    (run / "posterior.json").write_text(json.dumps(post))
    assert main(["export", str(run), "--format", "autoware", "--out", str(tmp_path / "a.yaml")]) == 0
    text = (tmp_path / "a.yaml").read_text()
    v = yaml.safe_load(text)["/**"]["ros__parameters"]["vehicle"]
    assert v["cr"] == pytest.approx(car["estimate"], abs=1e-3)
    assert v["cf"] == pytest.approx(post["parameters"]["C_alpha_f"]["estimate"], abs=1e-3)
    assert "(rear axle); NOT identified alone: trades with l_f along a ridge (ρ = +0.93)" in text
    assert "Held-out check passed" in text and "understeer gradient = " in text
    # json and csv: a number, beside identified.
    capsys.readouterr()
    assert main(["export", str(run), "--format", "json", "--out", "-"]) == 0
    row = json.loads(capsys.readouterr().out)["parameters"]["C_alpha_r"]
    assert row["value"] == car["estimate"] and row["identified"] is False
    # Nothing held out to check it on: refused, with what to do.
    (run / "posterior.json").write_text(json.dumps(post | {"validation": {}}))
    assert main(["export", str(run), "--format", "autoware", "--out", str(tmp_path / "b.yaml")]) == 2
    err = capsys.readouterr().err
    assert "C_alpha_r: not identified by this drive alone" in err and "--holdout 0.3" in err
    assert not (tmp_path / "b.yaml").exists()


def test_export_json_and_csv_carry_every_parameter_with_its_interval(effect_run, tmp_path, capsys):
    post = json.loads((effect_run / "posterior.json").read_text())
    assert main(["export", str(effect_run), "--format", "json"]) == 0
    table = json.loads((effect_run / "parameters.json").read_text())["parameters"]
    assert set(table) == set(post["parameters"])
    capsys.readouterr()
    assert main(["export", str(effect_run), "--format", "csv", "--out", "-"]) == 0
    rows = pd.read_csv(io.StringIO(capsys.readouterr().out)).set_index("parameter")
    for n, p in post["parameters"].items():
        assert rows.loc[n, "q05"] == pytest.approx(p["q05"], rel=1e-5)
        # Every parameter's estimate, identified or not: what `predict` simulates.
        assert table[n]["value"] == pytest.approx(p["estimate"])
        assert table[n]["identified"] == p["identified"] and rows.loc[n, "identified"] == p["identified"]


def test_export_bad_input_exits_2(tmp_path, capsys):
    with pytest.raises(SystemExit) as exc:
        main(["export", str(tmp_path), "--format", "excel"])
    assert exc.value.code == 2
    assert main(["export", str(tmp_path)]) == 2
    assert "no posterior.json" in capsys.readouterr().err


def test_effect_priors_come_from_fit_bounds_and_vehicle_json_overrides_them(tmp_path):
    from vdsbi.io import read_vehicle
    from vdsbi.problem import prior_box
    from vdsbi.simulator.effects import get_effect

    data = {**default_vehicle().to_dict(), "prior": {"sensor_bias.ay": [-1.0, 0.2]}}
    (tmp_path / "v.json").write_text(json.dumps(data))
    box = prior_box(read_vehicle(tmp_path / "v.json"), ["sensor_bias"])
    assert box["sensor_bias.ax"] == get_effect("sensor_bias").bounds[0]
    assert box["sensor_bias.ay"] == (-1.0, 0.2)
    data["prior"] = {"sensor_bias.roll": [0.0, 1.0]}
    (tmp_path / "w.json").write_text(json.dumps(data))
    with pytest.raises(Exception, match="sensor_bias.roll"):
        read_vehicle(tmp_path / "w.json")
