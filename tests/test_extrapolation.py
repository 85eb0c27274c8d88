"""Extrapolation said out loud: driving beyond the envelope of what identify fitted is flagged per
window (the held-out part in posterior.json, another drive by `predict`), and its predictive band
draws the tyres' grip from its prior there and only there."""

from __future__ import annotations

import contextlib
import io
import json
import shutil
from pathlib import Path

import jax
import numpy as np
import pandas as pd
import pytest

from vdsbi import api
from vdsbi.api._extrapolation import extrapolation
from vdsbi.cli import main
from vdsbi.cli._predict import extrapolation_lines
from vdsbi.io import read_recording
from vdsbi.problem import ProblemSettings, make_problem
from vdsbi.problem.validation import beyond_envelope, envelope, predictive_band
from vdsbi.simulator import (
    CHANNELS,
    SEED_TRUE_THETA,
    Inputs,
    default_vehicle,
    seed_profile,
    simulate,
    theta_from_dict,
)

NOISE = {"ax": 0.05, "ay": 0.05, "yaw_rate": 0.005, "omega_front": 0.1, "omega_rear": 0.1, "vx": 0.05}
#: Steer amplitudes, rad: the fitted drive's corners (its last 2 s harder), and two drives to predict.
FIT, FIT_END, MILD, HARD = 0.03, 0.12, 0.03, 0.1


def _drive(path: Path, amplitude: float, end_amplitude: float | None = None) -> Path:
    """6 s of the seed's gas/brake at the truth, steering sin(π t) (the last 2 s at `end_amplitude`,
    switched at a zero crossing), with sensor noise."""
    base = seed_profile(duration=6.0)
    t = np.asarray(base.ts)
    steer = np.where(t >= 4.0, end_amplitude or amplitude, amplitude) * np.sin(np.pi * t)
    inp = Inputs(0.0, base.dt, steer, base.torque_front, base.torque_rear)
    ys, ok = simulate(theta_from_dict(SEED_TRUE_THETA), inp, default_vehicle(), v0=10.0)
    assert ok
    rng = np.random.default_rng(0)
    df = pd.DataFrame(
        {"t": t, "steer": steer, "torque_front": base.torque_front, "torque_rear": base.torque_rear}
    )
    for i, c in enumerate(CHANNELS):
        df[c] = np.asarray(ys)[:, i] + rng.normal(0.0, NOISE[c], len(df))
    df.to_csv(path, index=False)
    return path


@pytest.fixture(scope="module")
def drives(tmp_path_factory) -> dict[str, Path]:
    d = tmp_path_factory.mktemp("drives")
    (d / "vehicle.json").write_text(json.dumps({**default_vehicle().to_dict(), "noise_std": NOISE}))
    return {
        "vehicle": d / "vehicle.json",
        "fit": _drive(d / "fit.csv", FIT, FIT_END),
        "mild": _drive(d / "mild.csv", MILD),
        "hard": _drive(d / "hard.csv", HARD),
    }


@pytest.fixture(scope="module")
def run(drives, tmp_path_factory) -> Path:
    """identify on the fitted drive, on a tiny budget; its last 30 % (the harder end) held out."""
    out = tmp_path_factory.mktemp("runs") / "run"
    budget = api.Budget(rounds=1, sims=100, epochs=3, num_samples=200)
    api.identify(drives["fit"], drives["vehicle"], api.IdentifyOptions(budget=budget), out_dir=out)
    return out


@pytest.fixture(scope="module")
def predicted(run, drives, tmp_path_factory) -> dict:
    """Each drive predicted with the band by the command (its printout and file) and by the API
    on a copy of the run without its envelope (the band as it would be without the check); one
    fixture, so that the programs compile once."""
    bare = tmp_path_factory.mktemp("runs") / "bare"
    shutil.copytree(run, bare)
    post = json.loads((bare / "posterior.json").read_text())
    del post["envelope"]
    (bare / "posterior.json").write_text(json.dumps(post))
    out = {}
    for name in ("mild", "hard"):
        csv = bare.parent / f"{name}.pred.csv"
        printed = io.StringIO()
        with contextlib.redirect_stdout(printed):
            code = main(["predict", str(run), "--inputs", str(drives[name]), "--out", str(csv), "--band"])
        assert code == 0
        out[name] = {
            "printed": printed.getvalue(),
            "frame": pd.read_csv(csv),
            "bare": api.predict(bare, drives[name], band=True),
        }
    return out


def test_the_envelope_is_the_peaks_of_the_driving_and_flags_only_what_goes_beyond(drives):
    whole = ProblemSettings(held_out=0.0)
    fit, mild, hard = (
        make_problem(read_recording(drives[n]), default_vehicle(), whole) for n in ("fit", "mild", "hard")
    )
    fitted = envelope(fit, fit.train)
    assert set(fitted) == {"ay", "speed", "steer_rate", "ax"}
    # The harder end corners at ≈ 2.7 m/s² (v·r, the measured ay's kinematics, agrees).
    assert 2.0 < fitted["ay"] < 3.5
    assert beyond_envelope(fitted, mild, mild.valid) == []
    (flag,) = beyond_envelope(fitted, hard, hard.valid)
    assert flag["window"] == 0 and set(flag["beyond"]) == {"ay"}
    fit_peak, this_peak = flag["beyond"]["ay"]
    assert fit_peak == fitted["ay"] and this_peak > 1.5 * fit_peak


def test_identify_stores_the_envelope_and_flags_the_harder_held_out_end(run):
    post = json.loads((run / "posterior.json").read_text())
    peaks = post["envelope"]["peaks"]
    assert set(peaks) == {"ay", "speed", "steer_rate", "ax"}
    assert post["envelope"]["units"]["ay"] == "m/s²"
    held = post["validation"]["estimate"]["held_out_seconds"]
    (flag,) = post["validation"]["extrapolation"]
    assert flag["window"] == 0 and flag["t0"] == pytest.approx(6.0 - held, abs=0.1) and flag["t1"] == 6.0
    fit_peak, this_peak = flag["beyond"]["ay"]
    # The training part saw the mild corners only; the envelope kept is all the fitted driving's.
    assert this_peak > 1.3 * fit_peak and peaks["ay"] == pytest.approx(this_peak, rel=0.01)
    # Below half the grip the tyres are linear and the run has no friction factors: band unchanged.
    assert "grip_from_prior" not in flag and "tyre_friction" not in post["effects"]


def test_predict_warns_of_a_harder_drive_and_not_of_a_milder_one(predicted, run):
    hard, mild = predicted["hard"], predicted["mild"]
    assert "warning: window 0" in hard["printed"] and "goes beyond the driving" in hard["printed"]
    assert "|a_y|" in hard["printed"] and "grip from the prior" in hard["printed"]
    assert hard["frame"]["beyond_envelope"].all()
    assert "warning" not in mild["printed"] and not mild["frame"]["beyond_envelope"].any()
    # A run without an envelope is not checked, and says so.
    assert mild["bare"].extrapolation is None
    assert extrapolation_lines(None, str(run))[0].startswith("note:")


def test_the_band_widens_beyond_the_envelope_and_only_there(predicted):
    width = lambda f, c: (f[f"{c}_q95"] - f[f"{c}_q05"]).to_numpy()
    for c in ("ay", "yaw_rate"):
        mild, bare_mild = predicted["mild"]["frame"], predicted["mild"]["bare"].frame
        np.testing.assert_allclose(width(mild, c), width(bare_mild, c), rtol=1e-6)  # the file's 9 digits
        hard, bare_hard = predicted["hard"]["frame"], predicted["hard"]["bare"].frame
        assert np.mean(width(hard, c)) > 2.0 * np.mean(width(bare_hard, c))
        # Wider where the grip is used, not everywhere: the straight running keeps its band.
        assert np.min(width(hard, c) / width(bare_hard, c)) < 1.5


def test_friction_factors_in_the_model_are_drawn_from_their_prior_beyond_the_envelope(run, drives):
    post = json.loads((run / "posterior.json").read_text())
    cutoff = (post["problem"].get("filter") or {}).get("cutoff_hz")
    settings = ProblemSettings(longitudinal=post["problem"]["longitudinal"], held_out=0.0, bandwidth=cutoff)
    hard = make_problem(read_recording(drives["hard"]), default_vehicle(), settings)
    names = list(post["parameters"])
    # The run's draws with friction factors at 1 (a model that has them, fitted to the same driving).
    draws = pd.read_csv(run / "predictive_draws.csv")[names].to_numpy()[:100]
    draws = np.concatenate([draws, np.ones((len(draws), 2))], axis=1)
    noise = np.array([post["noise_model"][c]["residual_rms"] for c in hard.channels])
    effects = ("tyre_friction",)
    key = jax.random.key(0)
    band = predictive_band(key, hard, draws, noise, effects)
    wide, (flag,) = extrapolation(
        jax.random.fold_in(key, 1), hard, hard.valid, post["envelope"]["peaks"], band, draws, noise, effects
    )
    assert set(flag["grip_from_prior"]) == {"tyre_friction.scale_front", "tyre_friction.scale_rear"}
    width = lambda b: b["q95"] - b["q05"]
    assert np.mean(width(wide)[hard.valid]) > 2.0 * np.mean(width(band)[hard.valid])
