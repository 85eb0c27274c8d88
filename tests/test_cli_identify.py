"""End-to-end `vdsbi identify` / `vdsbi sample` on a tiny budget: files, reload in a new process,
determinism, and an interrupted run resumed to the identical result."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from vdsbi import api
from vdsbi.cli import main
from vdsbi.inference import StatisticsMLP
from vdsbi.simulator import (
    CHANNELS,
    PARAM_NAMES,
    SEED_TRUE_THETA,
    default_vehicle,
    seed_profile,
    simulate,
    theta_from_dict,
)

#: Tiny budget: 2 rounds x 100 simulations, 3 epochs, stats embedding.
BUDGET = ["--rounds", "2", "--sims", "100", "--epochs", "3", "--samples", "200", "--embedding", "stats"]
NOISE = {"ax": 0.05, "ay": 0.05, "yaw_rate": 0.005, "omega_front": 0.1, "omega_rear": 0.1, "vx": 0.05}


@pytest.fixture(scope="module")
def drive(tmp_path_factory) -> tuple[Path, Path]:
    """A 3 s recording of the built-in vehicle at the seed's truth, with noise_std in vehicle.json."""
    d = tmp_path_factory.mktemp("drive")
    veh = default_vehicle()
    inp = seed_profile(duration=3.0)
    ys, ok = simulate(theta_from_dict(SEED_TRUE_THETA), inp, veh, v0=10.0)
    assert ok
    rng = np.random.default_rng(0)
    df = pd.DataFrame(
        {
            "t": np.asarray(inp.ts),
            "steer": np.asarray(inp.steer),
            "torque_front": np.asarray(inp.torque_front),
            "torque_rear": np.asarray(inp.torque_rear),
        }
    )
    for i, c in enumerate(CHANNELS):
        df[c] = np.asarray(ys)[:, i] + rng.normal(0.0, NOISE[c], len(df))
    df.to_csv(d / "rec.csv", index=False)
    (d / "vehicle.json").write_text(json.dumps({**veh.to_dict(), "noise_std": NOISE}))
    return d / "rec.csv", d / "vehicle.json"


@pytest.fixture(scope="module")
def full_run(drive, tmp_path_factory) -> Path:
    rec, veh = drive
    out = tmp_path_factory.mktemp("runs") / "full"
    compare = ["--compare", '{"l_f": 1.3, "C_alpha_f": 60000}']
    assert (
        main(["identify", str(rec), "--vehicle", str(veh), "--out", str(out), *BUDGET, *compare, "--quiet"])
        == 0
    )
    return out


def test_identify_writes_all_files(full_run):
    for name in ("posterior.json", "samples.csv", "pairplot.png", "ppc.png", api.outputs.ESTIMATOR):
        assert (full_run / name).stat().st_size > 0, name
    post = json.loads((full_run / "posterior.json").read_text())
    assert set(post["parameters"]) == set(PARAM_NAMES)
    for name, p in post["parameters"].items():
        lo, hi = p["prior"]
        assert lo <= p["q05"] <= p["q50"] <= p["q95"] <= hi, name
        assert p["std"] > 0
    assert post["channels"] == list(CHANNELS)
    prob = post["problem"]
    assert prob["noise_std"] == NOISE and set(prob["noise_source"].values()) == {"vehicle file"}
    (window,) = prob["windows"]  # a 3-s drive: one window, all of it fitted for the estimate ...
    assert window["t0"] == 0.0 and window["t1"] == pytest.approx(3.0) and "held_from" not in window
    # ... after the fit of its first 70 % was scored on the last 30 %.
    assert post["validation"]["estimate"]["held_out_seconds"] == pytest.approx(0.3 * 3.0, abs=0.05)
    assert post["not_identified"] == [n for n in PARAM_NAMES if not post["parameters"][n]["identified"]]
    # The estimate (fitted on the training part) and the neural posterior's mean are scored on the
    # held-out part; the estimate written is the refit on everything, at the posterior's mode.
    assert set(post["validation"]["estimate"]["channels"]) == set(CHANNELS)
    assert set(post["validation"]["npe_mean"]["channels"]) == set(CHANNELS)
    assert set(post["estimate"]["values"]) == set(PARAM_NAMES)
    for n, p in post["parameters"].items():
        assert p["estimate"] == post["estimate"]["values"][n]
        assert p["prior"][0] <= p["estimate"] <= p["prior"][1]
    assert set(post["noise_model"]) == set(CHANNELS)
    assert post["npe_check"]["reported"] == "likelihood"
    assert {"understeer_gradient", "yaw_rate_gain"} <= set(post["combinations"])
    assert post["settings"]["rounds"] == 2 and post["settings"]["sims_per_round"] == 100
    assert post["vdsbi_version"]
    # A clean drive: no mass at the prior's edges, and the band covers the channels the fitted
    # 2.1 s inform (not the wheel speeds: their slip stiffnesses are not informed there).
    warned = [w for w in post["warnings"] if w["kind"] in ("prior_edge", "predictive_miss")]
    assert not [
        w for w in warned if w["kind"] == "prior_edge" or set(w["channels"]) - {"omega_front", "omega_rear"}
    ]
    samples = pd.read_csv(full_run / "samples.csv")
    assert list(samples.columns) == list(PARAM_NAMES) and len(samples) == 200
    np.testing.assert_allclose(
        samples.mean().to_numpy(), [post["parameters"][n]["mean"] for n in PARAM_NAMES], rtol=1e-6
    )


def _sample_in_new_process(run_dir: Path, seed: int, **env_vars: str) -> str:
    env = {**os.environ, "JAX_PLATFORMS": "cpu", **env_vars}
    cmd = [sys.executable, "-m", "vdsbi.cli", "sample", str(run_dir), "--n", "50", "--seed", str(seed)]
    out = subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=300)
    assert out.returncode == 0, out.stderr
    return out.stdout


def test_sample_reloads_in_new_process(full_run, tmp_path):
    import io

    import jax

    from vdsbi.inference import Posterior

    text = _sample_in_new_process(full_run, seed=3)
    df = pd.read_csv(io.StringIO(text))
    assert list(df.columns) == list(PARAM_NAMES) and len(df) == 50
    # The same draws as this process gets from the saved estimator with the same key.
    here = np.asarray(Posterior.load(full_run / api.outputs.ESTIMATOR).sample(jax.random.key(3), 50))
    np.testing.assert_allclose(df.to_numpy(), here, rtol=1e-6)
    # --out writes the same thing; another seed gives other draws.
    assert main(["sample", str(full_run), "--n", "50", "--seed", "3", "--out", str(tmp_path / "s.csv")]) == 0
    np.testing.assert_allclose(pd.read_csv(tmp_path / "s.csv").to_numpy(), here, rtol=1e-6)
    assert main(["sample", str(full_run), "--n", "50", "--seed", "4", "--out", str(tmp_path / "t.csv")]) == 0
    assert not np.allclose(pd.read_csv(tmp_path / "t.csv").to_numpy(), here)


def test_the_command_keeps_its_compiled_programs_for_the_next_run(full_run, tmp_path):
    """A second `vdsbi` process finds every program the first compiled (it adds no entry to the
    cache folder, where each compilation that missed would add one) and prints the same draws."""
    cache = tmp_path / "cache"
    env = {"VDSBI_COMPILATION_CACHE": str(cache), "JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS": "0"}
    first = _sample_in_new_process(full_run, 5, **env)
    entries = sorted(p.name for p in cache.iterdir())
    assert entries  # the sampler's programs were written
    assert _sample_in_new_process(full_run, 5, **env) == first
    assert sorted(p.name for p in cache.iterdir()) == entries


def test_compilation_cache_folder_from_the_environment(tmp_path):
    from vdsbi.cli._main import compilation_cache_dir

    assert compilation_cache_dir({"VDSBI_COMPILATION_CACHE": "off"}) is None
    assert compilation_cache_dir({"VDSBI_COMPILATION_CACHE": str(tmp_path)}) == tmp_path
    assert compilation_cache_dir({"XDG_CACHE_HOME": str(tmp_path)}) == tmp_path / "vdsbi" / "jax"
    # The user's own JAX setting wins: JAX reads it itself.
    jax_own = {"JAX_COMPILATION_CACHE_DIR": str(tmp_path), "VDSBI_COMPILATION_CACHE": "/elsewhere"}
    assert compilation_cache_dir(jax_own) is None


def test_the_command_adds_its_xla_flags_and_keeps_the_users():
    from vdsbi.cli._main import xla_flags

    added = "--xla_cpu_use_fusion_emitters=false --xla_backend_optimization_level=1"
    assert xla_flags({}) == added
    own = "--xla_force_host_platform_device_count=4"
    assert xla_flags({"XLA_FLAGS": own}) == f"{own} {added}"
    mine = "--xla_cpu_use_fusion_emitters=true --xla_backend_optimization_level=3"
    assert xla_flags({"XLA_FLAGS": mine}) == mine


def test_the_xla_flags_reach_a_command_started_by_entry():
    """A `vdsbi check --help` process started through `entry` runs with them, and importing the
    command starts no JAX backend (XLA would read its flags before `entry` sets them)."""
    code = "import os, sys; from vdsbi.cli._main import entry; sys.argv = ['vdsbi', 'check', '--help']\n"
    code += "from jax._src import xla_bridge; assert not xla_bridge._backends, 'a backend started'\n"
    code += "import atexit; atexit.register(lambda: print('FLAGS=' + os.environ['XLA_FLAGS']))\nentry()"
    env = {k: v for k, v in os.environ.items() if k != "XLA_FLAGS"}
    proc = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=120)
    added = "--xla_cpu_use_fusion_emitters=false --xla_backend_optimization_level=1"
    assert f"FLAGS={added}" in proc.stdout, proc.stderr[-2000:]


def _numbers(run_dir: Path) -> tuple[np.ndarray, dict]:
    post = json.loads((run_dir / "posterior.json").read_text())
    return pd.read_csv(run_dir / "samples.csv").to_numpy(), post["parameters"]


def test_interrupted_run_resumes_to_identical_result(drive, full_run, tmp_path):
    """Killed after round 1 and resumed: bit-identical to the uninterrupted run with the same seed
    (which is also the determinism check: two separate computations, one result)."""
    rec, veh = drive
    out = tmp_path / "resumed"

    def interrupt(state):
        if state.round == 1:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        budget = api.Budget(rounds=2, sims=100, epochs=3, num_samples=200, embedding=StatisticsMLP())
        api.identify(
            rec,
            veh,
            api.IdentifyOptions(budget=budget),
            out_dir=out,
            progress=api.Progress(say=lambda s: None, on_round_end=interrupt),
        )
    # Interrupted after round 1: only the checkpoint and the run settings are there.
    assert sorted(p.name for p in out.iterdir()) == [api.outputs.CHECKPOINT, api.outputs.RUN_FILE]
    # Without --resume the directory is refused (exit 2), and left as it was.
    args = ["identify", str(rec), "--vehicle", str(veh), "--out", str(out), *BUDGET, "--quiet"]
    assert main(args) == 2
    assert main([*args, "--resume"]) == 0
    s_res, p_res = _numbers(out)
    s_full, p_full = _numbers(full_run)
    np.testing.assert_array_equal(s_res, s_full)
    assert p_res == p_full
    # Resuming with other settings is refused.
    assert main([*args[:-1], "--resume", "--sims", "110"]) == 2


@pytest.mark.parametrize(
    "case",
    ["missing_column", "bad_vehicle"],
)
def test_bad_input_exits_2_without_output(drive, tmp_path, case, capsys):
    rec, veh = drive
    if case == "missing_column":
        df = pd.read_csv(rec).drop(columns=["steer"])
        rec = tmp_path / "rec.csv"
        df.to_csv(rec, index=False)
    else:
        bad = json.loads(Path(veh).read_text())
        bad["mass"] = -1.0
        veh = tmp_path / "vehicle.json"
        veh.write_text(json.dumps(bad))
    out = tmp_path / "out"
    assert main(["identify", str(rec), "--vehicle", str(veh), "--out", str(out), *BUDGET, "--quiet"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("vdsbi: error:") and "\n" not in err
    assert ("steer" if case == "missing_column" else "mass") in err
    assert not out.exists()


def test_compare_scores_reference_values_on_the_held_out_part(full_run):
    post = json.loads((full_run / "posterior.json").read_text())
    ref = post["validation"]["reference"]
    assert ref["given"] == {"l_f": 1.3, "C_alpha_f": 60000.0}
    assert ref["theta"]["l_f"] == pytest.approx(1.3) and ref["theta"]["C_alpha_f"] == pytest.approx(60000.0)
    # Parameters the reference does not give come from the fit it is compared with.
    fitted = post["validation"]["estimate"]["theta"]["C_alpha_r"]
    assert ref["theta"]["C_alpha_r"] == pytest.approx(fitted, rel=1e-5)
    for scores in (ref["channels"], post["validation"]["estimate"]["channels"]):
        assert set(scores) == set(CHANNELS)
        assert all(v["nrmse"] >= 0 and v["chi2_dof"] >= 0 and v["samples"] > 0 for v in scores.values())


def test_predict_simulates_another_drive_at_the_estimate_with_the_held_out_code(
    full_run, drive, tmp_path, capsys
):
    rec, _ = drive
    out = tmp_path / "pred.csv"
    assert main(["predict", str(full_run), "--inputs", str(rec), "--out", str(out), "--band"]) == 0
    printed = capsys.readouterr().out
    pred = pd.read_csv(out)
    post = json.loads((full_run / "posterior.json").read_text())
    for c in post["channels"]:
        assert {c, f"{c}_predicted", f"{c}_q05", f"{c}_q95"} <= set(pred.columns)
        assert np.all(pred[f"{c}_q05"] <= pred[f"{c}_q95"])
        assert f"{c}: NRMSE" in printed
    # The same drive, the same code: predict's yaw-rate error is the fit's, far below the signal.
    err = pred["yaw_rate_predicted"] - pred["yaw_rate"]
    assert np.sqrt(np.mean(err**2)) < 0.5 * np.std(pred["yaw_rate"])


@pytest.mark.parametrize("bad", ["C_alpha_f", "C_alpha_f=1:", "nonsense.x=0:1", "C_alpha_f=9:1"])
def test_a_bad_prior_exits_2_before_any_work(drive, tmp_path, bad, capsys):
    rec, veh = drive
    args = [
        "identify",
        str(rec),
        "--vehicle",
        str(veh),
        "--out",
        str(tmp_path / "o"),
        "--prior",
        bad,
        "--quiet",
    ]
    assert main(args) == 2
    assert "prior" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()
