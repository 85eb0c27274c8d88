"""A controller file for every run that predicts its held-out part, and pairs that trade reported as
a pair: the rules on synthetic inputs (a covariance with a ridge, intervals against a box, held-out
scores), then `export`, the printed table and report.html on a run's posterior.json edited to hold
them. The same on a real identify folder: test_cli_loop."""

from __future__ import annotations

import copy
import io
import json

import numpy as np
import pandas as pd
import pytest
import yaml

from vdsbi.api._held_out import held_out_verdict
from vdsbi.cli import main
from vdsbi.diagnostics import held_by_box, ridge_sentence, trading_pairs


def _cov(std, rho):
    """A covariance with the given stds and one correlation between the first two."""
    std = np.asarray(std, float)
    corr = np.eye(len(std))
    corr[0, 1] = corr[1, 0] = rho
    return corr * np.outer(std, std)


def test_two_parameters_on_a_long_ridge_trade_and_the_step_follows_its_sign():
    names = ["signal_delay.delay", "yaw_inertia.k", "C_alpha_f"]
    step = np.array([0.04, 0.2, 1e3])  # each std in its own units
    # In the logit coordinates (prior std π/√3 = 1.81) the first two move over ≥ 0.2 of it.
    (pair,) = trading_pairs(_cov([1.0, 2.0, 0.3], 0.95), names, step)
    assert pair["pair"] == ["signal_delay.delay", "yaw_inertia.k"] and pair["correlation"] == 0.95
    assert pair["direction"] == {"signal_delay.delay": 0.04, "yaw_inertia.k": 0.2}
    # Opposite signs: one up, the other down.
    (anti,) = trading_pairs(_cov([1.0, 2.0, 0.3], -0.93), names, step)
    assert anti["correlation"] == -0.93 and anti["direction"]["yaw_inertia.k"] == -0.2
    # Below the correlation threshold: no ridge.
    assert trading_pairs(_cov([1.0, 2.0, 0.3], 0.85), names, step) == []


def test_a_correlated_pair_each_pinned_far_inside_its_prior_does_not_trade():
    # l_f and C_αr on a clean drive: correlated, but each at a few per cent of its prior std.
    pair = trading_pairs(_cov([0.1, 0.01], 0.97), ["l_f", "C_alpha_r"], np.array([0.02, 300.0]))
    assert pair == []


def test_three_that_trade_where_no_two_do_are_reported_as_a_group():
    # Two friction factors and the downforce set a fast corner's grip: f + r + d fixed, no two
    # correlated beyond 0.71; a fourth parameter stands apart.
    names = ["tyre_friction.front", "tyre_friction.rear", "downforce.coef", "l_f"]
    mix = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [-1.0, -1.0, 0.1]])
    cov = np.zeros((4, 4))
    cov[:3, :3] = mix @ mix.T
    cov[3, 3] = 1.0
    step = np.sqrt(np.diag(cov))
    corr = cov / np.outer(step, step)
    assert np.max(np.abs(corr[np.triu_indices(4, 1)])) < 0.9  # the pair rule alone finds nothing
    (group,) = trading_pairs(cov, names, step, prior_std=1.0)
    assert group["pair"] == names[:3] and group["correlation"] > 0.99
    d = group["direction"]
    # along the ridge the sum barely moves, each member by about its share of the posterior
    assert abs(d[names[0]] + d[names[1]] + d[names[2]]) < 0.05 * abs(d[names[2]])
    sentence = ridge_sentence(group)
    assert sentence.startswith("tyre_friction.front, tyre_friction.rear and downforce.coef trade")
    # a pair that trades is still reported as a pair, and a member of it is not grouped again
    (pair,) = trading_pairs(_cov([1.0, 2.0, 0.3], 0.95), names[:3], np.ones(3))
    assert len(pair["pair"]) == 2


def test_a_bound_does_not_hide_a_ridge():
    # An inertia index held at the top of its box barely moves in its own units, yet far along
    # the ridge in the logit coordinates: it still trades with the lag.
    names = ["signal_delay.delay", "yaw_inertia.k"]
    (pair,) = trading_pairs(_cov([1.0, 1.2], 0.96), names, np.array([0.03, 0.01]))
    assert pair["pair"] == names


def test_an_interval_spanning_the_box_or_an_estimate_on_a_bound_is_held_by_the_box():
    # The yaw-inertia index at 1.95 against its box [0.4, 2.0]: on the upper bound.
    (why,) = held_by_box(1.95, 1.6, 1.99, 0.4, 2.0)
    assert "upper bound" in why and "1.95" in why
    # A delay whose 90 % interval covers most of [0, 0.4].
    (why,) = held_by_box(0.039, 0.01, 0.37, 0.0, 0.4)
    assert "spans 90% of its prior box" in why
    assert held_by_box(1.3, 1.25, 1.35, 0.675, 2.025) == []


def test_the_box_and_the_ridge_take_identified_away_and_say_why():
    from vdsbi.api._identify_report import _flag_box_and_ridges
    from vdsbi.problem import Box

    box = Box.from_dict({"a": (0.0, 1.0), "b": (0.0, 1.0), "c": (0.0, 1.0), "d": (0.0, 1.0)})
    params = {
        "a": {"estimate": 0.5, "q05": 0.4, "q95": 0.6, "identified": True},
        "b": {"estimate": 0.5, "q05": 0.4, "q95": 0.6, "identified": False, "not_identified_because": "x"},
        "c": {"estimate": 0.99, "q05": 0.9, "q95": 1.0, "identified": True},
        "d": {"estimate": 0.5, "q05": 0.45, "q95": 0.55, "identified": True},
    }
    pairs = [{"pair": ["a", "b"], "correlation": -0.96, "direction": {"a": 0.1, "b": -0.1}}]
    _flag_box_and_ridges(params, box, pairs)
    assert params["a"]["identified"] is False and params["b"]["identified"] is False
    assert params["a"]["not_identified_because"] == "trades with b along a ridge (ρ = -0.96)"
    assert params["b"]["not_identified_because"] == "x; trades with a along a ridge (ρ = -0.96)"
    assert params["a"]["trades_with"] == ["b"] and params["b"]["trades_with"] == ["a"]
    assert params["c"]["identified"] is False and "upper bound" in params["c"]["not_identified_because"]
    assert params["d"]["identified"] is True and "not_identified_because" not in params["d"]
    group = [{"pair": ["a", "c", "d"], "correlation": 0.97, "direction": {"a": 0.1, "c": 0.1, "d": -0.1}}]
    _flag_box_and_ridges(params, box, group)
    assert params["d"]["identified"] is False and params["d"]["trades_with"] == ["a", "c"]
    assert params["d"]["not_identified_because"] == "trades with a and c along a ridge (R = +0.97)"


def _validation(ay: float, yaw: float, npe: float = 0.3) -> dict:
    score = lambda a, r: {
        "ok": True,
        "held_out_seconds": 30.0,
        "channels": {"ay": {"nrmse": a}, "yaw_rate": {"nrmse": r}},
    }
    return {"estimate": score(ay, yaw), "npe_mean": score(npe, npe)}


def test_the_held_out_verdict():
    ok = held_out_verdict({"validation": _validation(0.06, 0.057)})
    assert ok.scored and ok.passed and ok.channels == {"ay": (0.06, 0.3), "yaw_rate": (0.057, 0.3)}
    assert "yaw_rate 0.057" in ok.describe()
    worse = held_out_verdict({"validation": _validation(0.06, 0.5)})  # > 1.25 x the neural mean's 0.3
    assert (
        worse.scored
        and not worse.passed
        and worse.failures == ("yaw_rate NRMSE 0.500 against the neural posterior mean's 0.300",)
    )
    flat = held_out_verdict({"validation": _validation(1.2, 0.05, npe=2.0)})
    assert not flat.passed and "no better than the held-out ay's own mean" in flat.failures[0]
    assert not held_out_verdict({"validation": {}}).scored
    spun = _validation(0.06, 0.057)
    spun["estimate"] |= {"ok": False, "channels": {}}
    assert not held_out_verdict({"validation": spun}).passed


# A posterior.json as identify writes it for a 25 Hz race car whose drive leaves C_alpha_r alone
# undetermined: it trades with l_f along a ridge, while the understeer gradient is determined.
PARAMS = {
    "l_f": (1.55, 0.06, 1.45, 1.65, "m", (0.8, 2.4)),
    "h_cog": (0.3, 0.1, 0.15, 0.45, "m", (0.1, 0.8)),
    "C_kappa_f": (1e5, 5e4, 3e4, 1.8e5, "N", (2e4, 3e5)),
    "C_kappa_r": (1e5, 5e4, 3e4, 1.8e5, "N", (2e4, 3e5)),
    "C_alpha_f": (9.1e4, 4e3, 8.5e4, 9.8e4, "N/rad", (2e4, 3e5)),
    "C_alpha_r": (1.21e5, 2.5e4, 8e4, 1.6e5, "N/rad", (2e4, 3e5)),
}


@pytest.fixture
def race_run(tmp_path):
    params = {}
    for n, (est, std, q05, q95, unit, prior) in PARAMS.items():
        params[n] = {"estimate": est, "mean": est, "std": std, "q05": q05, "q50": est, "q95": q95}
        params[n] |= {"unit": unit, "prior": list(prior), "identified": True}
    for n in ("C_kappa_f", "C_kappa_r"):
        params[n] |= {
            "identified": False,
            "not_identified_because": "the channels do not depend on it in this mode",
        }
    ridge = "trades with l_f along a ridge (ρ = +0.93)"
    params["C_alpha_r"] |= {"identified": False, "not_identified_because": ridge, "trades_with": ["l_f"]}
    params["l_f"] |= {
        "identified": False,
        "not_identified_because": "trades with C_alpha_r along a ridge (ρ = +0.93)",
        "trades_with": ["C_alpha_r"],
    }
    combinations = {
        "understeer_gradient": {"unit": "deg/g", "at": None, "median": 0.81, "q025": 0.7, "q975": 0.93}
        | {"std": 0.06, "std_ratio_to_prior": 0.02, "identified": True},
        "yaw_rate_gain": {"unit": "1/s", "at": 31.2, "median": 5.9, "q025": 5.7, "q975": 6.1}
        | {"std": 0.1, "std_ratio_to_prior": 0.01, "identified": True},
        "determined_directions": [],
        "trading_pairs": [
            {
                "pair": ["l_f", "C_alpha_r"],
                "correlation": 0.93,
                "direction": {"l_f": 0.06, "C_alpha_r": 25000.0},
            }
        ],
    }
    post = {
        "vdsbi_version": "test",
        "recording": "race.csv",
        "parameters": params,
        "combinations": combinations,
        "validation": _validation(0.098, 0.057, npe=0.08),
        "vehicle": {"mass": 800.0, "wheelbase": 3.1},
        "effects": [],
        "warnings": [],
        "channels": ["ay", "yaw_rate"],
        "problem": {"train_seconds": 333.0, "windows": [{"t0": 0.0, "t1": 10.0, "role": "train"}]},
    }
    run = tmp_path / "run"
    run.mkdir()
    (run / "posterior.json").write_text(json.dumps(post))
    return run, post


def _write(run, post):
    (run / "posterior.json").write_text(json.dumps(post))


def test_autoware_writes_an_unidentified_stiffness_that_predicts_the_held_out_part(race_run, tmp_path):
    run, post = race_run
    out = tmp_path / "a.yaml"
    assert main(["export", str(run), "--format", "autoware", "--out", str(out)]) == 0
    text = out.read_text()
    v = yaml.safe_load(text)["/**"]["ros__parameters"]["vehicle"]
    assert v["cf"] == pytest.approx(9.1e4) and v["cr"] == pytest.approx(1.21e5)
    assert 3.1 * (1 - (v["mass_fl"] + v["mass_fr"]) / 800.0) == pytest.approx(1.55, abs=1e-5)
    # Each parameter's own interval and status, the combinations, the pair, the held-out check.
    assert (
        "vehicle.cr = C_alpha_r 121000.0 [80000.0, 160000.0] N/rad (rear axle); NOT identified alone: "
        in text
    )
    assert "trades with l_f along a ridge (ρ = +0.93)" in text
    assert "understeer gradient = 0.81 [0.7, 0.93] deg/g (95 %); identified" in text
    assert "steady-state yaw-rate gain at 31.2 m/s = 5.9 [5.7, 6.1] 1/s" in text
    assert "l_f and C_alpha_r trade along a ridge (ρ = +0.93)" in text
    assert "Held-out check passed" in text and "yaw_rate 0.057" in text
    assert "C_kappa_f = " in text and "the channels do not depend on it" in text


def test_autoware_refuses_with_what_to_do(race_run, tmp_path, capsys):
    run, post = race_run
    out = tmp_path / "a.yaml"
    # Nothing held out to check an estimate the drive does not identify alone.
    _write(run, post | {"validation": {}})
    assert main(["export", str(run), "--format", "autoware", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "l_f: not identified by this drive alone (trades with C_alpha_r" in err
    assert "rerun identify with --holdout 0.3" in err
    # The estimate predicts the held-out yaw rate far worse than the neural posterior's mean.
    bad = copy.deepcopy(post)
    bad["validation"]["estimate"]["channels"]["yaw_rate"]["nrmse"] = 0.4
    bad["warnings"] = [{"kind": "model_error", "message": "... run `vdsbi diagnose race.csv --out d/`"}]
    _write(run, bad)
    assert main(["export", str(run), "--format", "autoware", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "validation: the estimate fails the held-out part (yaw_rate NRMSE 0.400" in err
    assert "run `vdsbi diagnose race.csv --out d/`" in err
    assert not out.exists()
    # With nothing held out, a drive that identifies l_f and both stiffnesses is still written.
    whole = copy.deepcopy(post) | {"validation": {}}
    for n in ("l_f", "C_alpha_r"):
        whole["parameters"][n] = {
            k: v for k, v in whole["parameters"][n].items() if k != "not_identified_because"
        }
        whole["parameters"][n]["identified"] = True
    _write(run, whole)
    assert main(["export", str(run), "--format", "autoware", "--out", str(out)]) == 0
    assert "Held-out check: none" in out.read_text()


def test_json_and_csv_give_every_estimate_beside_identified(race_run, capsys):
    run, post = race_run
    assert main(["export", str(run), "--format", "json", "--out", "-"]) == 0
    table = json.loads(capsys.readouterr().out)
    for n, p in post["parameters"].items():
        row = table["parameters"][n]
        assert row["value"] == p["estimate"] and row["identified"] == p["identified"]
    assert table["parameters"]["C_alpha_r"]["not_identified_because"].startswith("trades with l_f")
    assert table["combinations"]["trading_pairs"][0]["pair"] == ["l_f", "C_alpha_r"]
    assert table["held_out"]["passed"] is True
    assert main(["export", str(run), "--format", "csv", "--out", "-"]) == 0
    rows = pd.read_csv(io.StringIO(capsys.readouterr().out)).set_index("parameter")
    assert rows.loc["C_alpha_r", "value"] == pytest.approx(1.21e5) and not rows.loc["C_alpha_r", "identified"]
    assert rows.loc["C_alpha_r", "not_identified_because"].startswith("trades with l_f")


def test_the_table_and_the_page_name_the_pair_and_the_combinations(race_run):
    from vdsbi.api import IdentifyResult
    from vdsbi.api._pages import identify_page

    run, post = race_run
    result = IdentifyResult(None, np.zeros((1, 6)), post)
    table = result.table()
    # The typed fields say what the table prints.
    assert result.estimate["C_alpha_r"] == pytest.approx(1.21e5)
    assert result.identified["C_alpha_r"] is False and result.names[0] == "l_f"
    lo, hi = result.interval["C_alpha_r"]
    assert lo == post["parameters"]["C_alpha_r"]["q05"] and hi == post["parameters"]["C_alpha_r"]["q95"]
    row = next(r for r in table.splitlines() if r.startswith("C_alpha_r"))
    assert "1.21e+05" in row and "NOT identified alone" in row and "trades with l_f" in row
    assert "l_f and C_alpha_r trade along a ridge (ρ = +0.93)" in table
    page = identify_page(post, run)
    for text in ("understeer gradient", "steady-state yaw-rate gain at 31.2 m/s", "trade along a ridge"):
        assert text in page, text
    assert "none held out" not in page and "scored on the held-out part" in page
    assert "The estimate predicts the held-out 30 s" in page
