"""Mismatch discovery end to end, kept small: one quick concealed-effects run (a clean and a
sensor-bias recording, written as files and diagnosed from the files alone) shared by all tests,
plus a noise-free recovery check that reuses the same compiled kernels. `vdsbi diagnose` itself
(report, figures, the identify command it ends with): test_cli_loop."""

import json
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from vdsbi.discovery._fit import Fitter  # noqa: E402
from vdsbi.discovery._rank import verdict  # noqa: E402
from vdsbi.discovery._report import REQUIRED_KEYS  # noqa: E402
from vdsbi.io import build_recording, read_recording, read_vehicle  # noqa: E402
from vdsbi.problem import make_problem  # noqa: E402
from vdsbi.simulator import CHANNELS, PARAM_NAMES, simulate  # noqa: E402


@pytest.fixture(scope="module")
def quick(once_per_run):
    from experiments import concealed_effects

    def run(base):
        argv = ["--quick", "--data", str(base / "data"), "--out", str(base / "out")]
        assert concealed_effects.main(argv) == 0

    return once_per_run("concealed_quick", run)


def _case(quick, name):
    (folder,) = (quick / "data" / "quick").glob(f"case_*_{name}")
    return folder


def test_quick_experiment_writes_results(quick):
    out = json.loads((quick / "out" / "concealed_effects_quick.json").read_text())
    assert out["summary"]["n_recordings"] == 2 and len(out["cases"]) == 2


def test_clean_recording_is_not_flagged(quick):
    r = json.loads((_case(quick, "none") / "result.json").read_text())
    assert not r["detected"] and r["chosen"] == []


def test_names_sensor_bias_and_the_fit_improves(quick):
    folder = _case(quick, "sensor_bias")
    r = json.loads((folder / "result.json").read_text())
    assert r["detected"] and r["p_value"] < 0.01
    assert r["chosen"] == ["sensor_bias"]
    assert r["magnitude_rel_error"]["sensor_bias"] < 0.25
    assert r["mean_chi2_after"] < r["mean_chi2_before"]
    assert r["mean_chi2_after"] < 1.3


def test_after_fit_intervals_are_scored(quick):
    r = json.loads((_case(quick, "sensor_bias") / "result.json").read_text())
    for name, (lo, hi) in r["theta_q05_q95_after"].items():
        assert lo < r["theta_after"][name] < hi
    summary = json.loads((quick / "out" / "concealed_effects_quick.json").read_text())["summary"]
    inside, total = map(int, summary["theta_inside_90_after_count"].split(" of "))
    assert total == 12 and len(summary["theta_outside_90_after"]) == total - inside


def test_report_has_required_keys(quick):
    rep = json.loads((_case(quick, "sensor_bias") / "report.json").read_text())
    for k in REQUIRED_KEYS:
        assert k in rep
    assert isinstance(rep["mismatch_detected"], bool)
    assert set(rep["located"]) >= {"channels", "windows", "bands_hz"}
    assert {"name", "score", "params", "params_std"} <= set(rep["effects"][0])
    assert rep["effects"][0]["name"] == "sensor_bias" or "sensor_bias" in rep["effects"][0]["name"]
    for when in ("before", "after"):
        for ch, d in rep["fit"][when].items():
            assert ch in CHANNELS and set(d) >= {"nrmse", "rmse", "chi2_dof", "chi2_dof_predictive"}
            # the parameter uncertainty only widens the predictive distribution
            assert 0 < d["chi2_dof_predictive"] <= d["chi2_dof"]
        assert set(rep["theta"][when]) == set(PARAM_NAMES)


def test_verdict_claims_an_effect_only_when_it_accounts_for_the_mismatch(quick):
    rep = json.loads((_case(quick, "sensor_bias") / "report.json").read_text())
    # Named; claimed as the whole explanation unless the residual test still rejects (weakly, at
    # α/10 ≤ p < α) or the held-out fit stays above the noise — and then the verdict says which.
    assert "sensor_bias" in rep["verdict"]
    assert rep["explained"] is True or "weakly" in rep["verdict"] or "held-out" in rep["verdict"]
    assert verdict(False, [], 0.5, 0.05, None)["explained"] is None
    assert verdict(True, [], 0.5, 0.05, None)["explained"] is False
    assert verdict(True, ["road_bank"], 0.001, 0.05, True)["explained"] is False  # remainder
    weak = verdict(True, ["road_bank"], 0.03, 0.05, True)
    assert weak["explained"] is False and "weakly" in weak["text"]
    assert verdict(True, ["road_bank"], 0.5, 0.05, False)["explained"] is False  # absorbing
    assert verdict(True, ["road_bank"], 0.5, 0.05, True)["explained"] is True
    assert verdict(True, ["road_bank"], 0.5, 0.05, True, ("ay", 1.08))["explained"] is True
    high = verdict(True, ["road_bank"], 0.5, 0.05, True, ("ay", 1.3))  # held-out not within noise
    assert high["explained"] is False and "1.3 > 1.1 in ay" in high["text"]


def test_fit_recovers_theta_noise_free(quick, x64):
    folder = _case(quick, "none")
    truth = json.loads((folder / "truth.json").read_text())
    rec = read_recording(folder / "recording.csv")
    veh = read_vehicle(folder / "vehicle.json")
    theta = np.array([truth["theta"][n] for n in PARAM_NAMES])
    ys, ok = simulate(theta, rec.inputs(), veh, v0=truth["v0"])
    assert ok
    cols = {"t": rec.t, "steer": rec.steer, "torque_front": rec.torque_front, "torque_rear": rec.torque_rear}
    cols.update({c: ys[:, CHANNELS.index(c)] for c in rec.channel_names})
    clean = build_recording(cols, "noise-free")
    fitter = Fitter(make_problem(clean, veh), dt=0.005)
    fit = fitter.fit((), fitter.initial_z())
    # Noise-free (truth at 2.5 ms, fit at 5 ms): the whitened residual nearly vanishes and the
    # well-excited parameters come back.
    assert fit.chi2_dof < 0.02
    rel = np.abs(fit.theta - theta) / theta
    assert rel[0] < 0.01 and rel[4] < 0.02 and rel[5] < 0.02, dict(zip(PARAM_NAMES, rel))


def test_pairs_pay_a_prior_penalty_and_ranking_agrees_with_choice():
    from types import SimpleNamespace

    from vdsbi.discovery._rank import choose, rank

    def fit(chi2, k, tau=1.0):
        # one channel whose evidence is the white-noise χ² difference at τ = 1
        noise = SimpleNamespace(tau=np.array([tau]), samples=np.array([10_000.0]))
        rss = np.array([np.exp(chi2 / 10_000)])
        return SimpleNamespace(
            chi2=chi2, rss=rss, noise=noise, num_params=6 + k, num_samples=10_000, effects=()
        )

    base = fit(1000.0, 0)
    half_log_n = 0.5 * np.log(10_000)
    # a pair that adds log-evidence 2 over its single (< 3) ranks below it and is not chosen
    fits = {(): base, ("a",): fit(900.0, 1), ("a", "b"): fit(900.0 - 2 * (2 + half_log_n), 2)}
    ranked = rank(fits, base)
    assert ranked[0].effects == ("a",) and choose(ranked, True) == ("a",)
    pair = next(r for r in ranked if r.effects == ("a", "b"))
    assert pair.score == pytest.approx(pair.log_bayes_factor - 3.0)
    # one that adds 4 (> 3) wins, and the choice is the top of the ranking
    fits[("a", "b")] = fit(900.0 - 2 * (4 + half_log_n), 2)
    ranked = rank(fits, base)
    assert ranked[0].effects == ("a", "b") and choose(ranked, True) == ("a", "b")
    assert choose(ranked, False) == ()
    assert sum(r.probability for r in ranked) == pytest.approx(1.0)
    # The same gain on a residual correlated over 40 samples (model error on a real drive) is
    # worth 40 times fewer independent samples: no longer strong evidence.
    coloured = {(): fit(1000.0, 0, tau=40.0), ("a",): fit(900.0, 1, tau=40.0)}
    row = next(r for r in rank(coloured, coloured[()]) if r.effects == ("a",))
    assert row.log_bayes_factor == pytest.approx(50.0 / 40.0 - 0.5 * np.log(10_000 / 40.0))
    assert choose(rank(coloured, coloured[()]), True) == ()
