"""diagnose claims a fix only where it improves the held-out fit: then it prints the identify command
that models it (the whole effect set where it dropped one of identify's defaults); otherwise it
prints what it found, with the ranges it measured, and no command."""

from __future__ import annotations

import dataclasses
import shlex
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

import vdsbi.discovery
from vdsbi import api
from vdsbi.cli import build_parser, main
from vdsbi.discovery._data import _blocks
from vdsbi.discovery._held_out import held_out_improves


def _held(ay, yaw):
    return {"ay": {"chi2_dof": ay, "nrmse": 0.1}, "yaw_rate": {"chi2_dof": yaw, "nrmse": 0.1}}


def test_held_out_improves_only_if_no_channel_gets_worse():
    assert held_out_improves(_held(4.0, 3.0), _held(2.0, 3.05))  # within the 2 % slack
    assert not held_out_improves(_held(4.0, 3.0), _held(1.0, 3.2))  # traded one channel for another
    assert not held_out_improves(_held(4.0, 3.0), _held(4.0, 3.0))
    assert not held_out_improves(_held(4.0, 3.0), _held(3.95, 3.0))  # 0.7 %: within the noise
    assert held_out_improves(_held(4.0, 3.0), _held(3.8, 3.0))  # 2.9 %
    # on a short held-out part a channel's χ²/dof moves by its sampling noise: 2·√(2/N)
    few = lambda ay, yaw: {c: v | {"samples": 200} for c, v in _held(ay, yaw).items()}
    assert held_out_improves(few(40.0, 1.0), few(1.0, 1.15))
    assert not held_out_improves(few(40.0, 1.0), few(1.0, 1.25))


def test_a_fall_every_held_out_block_shows_counts_though_each_mean_is_noisy():
    # A real drive's residual is correlated over tens of samples: each channel's held-out χ²/dof
    # is known to ±35 % alone, but both fits are scored on the same samples, block by block.
    def held(ay, yaw, blocks):
        out = _held(ay, yaw)
        for c in out:
            out[c] |= {"samples": 640, "chi2_blocks": list(blocks)}
        return out

    tau = {"ay": 40.0, "yaw_rate": 40.0}
    rng = np.random.default_rng(0)
    level = rng.uniform(20.0, 80.0, 8)  # the blocks' misfit varies far more than the fix moves it
    consistent = 0.8 * level + rng.normal(0.0, 1.0, 8)
    assert held_out_improves(held(51.7, 51.7, level), held(41.3, 41.3, consistent), tau)
    # the same fall in the mean, made of blocks much better and blocks worse: within the noise
    mixed = level * np.where(np.arange(8) % 2 == 0, 0.4, 1.3)
    assert 0.75 < mixed.mean() / level.mean() < 0.9
    assert not held_out_improves(held(51.7, 51.7, level), held(41.3, 41.3, mixed), tau)
    # three blocks are too few to pair: each mean's own noise (±50 % here) is allowed for
    assert not held_out_improves(held(51.7, 51.7, level[:3]), held(41.3, 41.3, consistent[:3]), tau)


def test_held_out_blocks_are_runs_of_held_samples_within_each_window():
    held = np.zeros((3, 10), bool)
    held[0, 6:] = True  # 4 samples: one block of 3 with the short rest joined to it
    held[2, :] = True  # 10 samples: blocks of 3, 3 and 4
    blocks = _blocks(held, 3)
    assert [(w, k.tolist()) for w, k in blocks] == [
        (0, [6, 7, 8, 9]),
        (2, [0, 1, 2]),
        (2, [3, 4, 5]),
        (2, [6, 7, 8, 9]),
    ]


def _fake(improved: bool, chosen=("steering_lag",), dropped=()):
    report = {
        "source": "rec.csv",
        "mismatch_detected": True,
        "p_value": 0.001,
        "chosen": list(chosen),
        "dropped": list(dropped),
        "base_effects": ["yaw_inertia", "signal_delay"],
        "effect_params": {"steering_lag": {"tau": 0.2}},
        "effect_params_std": {"steering_lag": {"tau": 0.01}},
        "verdict": "the verdict",
        "fit": {"before": _held(4.0, 3.0), "after": _held(2.0, 2.0)},
    }
    verdict = SimpleNamespace(held_out_improved=improved, text="the verdict")
    return SimpleNamespace(report=report, verdict=verdict)


@dataclasses.dataclass
class _Found:
    report: dict
    verdict: object


@pytest.mark.parametrize("improved", [True, False])
def test_the_command_is_printed_only_for_a_fix_that_improves_the_held_out_fit(
    improved, monkeypatch, capsys, tmp_path
):
    fake = _fake(improved)
    monkeypatch.setattr(
        vdsbi.discovery, "diagnose_mismatch", lambda *a, **k: _Found(fake.report, fake.verdict)
    )
    found = api.diagnose("rec.csv", "vehicle.json", None, names=("rec.csv", "vehicle.json", "diag"))
    rep = found.report
    if improved:
        argv = shlex.split(rep["identify_command"])
        args = build_parser().parse_args(argv[1:])
        assert args.effects == "+steering_lag" and "not_claimed" not in rep
        lo, hi = map(float, args.prior[0].split("=")[1].split(":"))
        assert lo < 0.2 < hi
    else:
        assert rep["identify_command"] is None
        assert "steering_lag" in rep["not_claimed"] and "steering_lag.tau in [" in rep["not_claimed"]
        assert "does not improve the held-out fit" in rep["not_claimed"]


def test_a_dropped_default_makes_the_command_list_the_whole_set(monkeypatch):
    fake = _fake(True, dropped=("signal_delay",))
    monkeypatch.setattr(
        vdsbi.discovery, "diagnose_mismatch", lambda *a, **k: _Found(fake.report, fake.verdict)
    )
    rep = api.diagnose("rec.csv", "vehicle.json", None, names=("rec.csv", "vehicle.json", "diag")).report
    args = build_parser().parse_args(shlex.split(rep["identify_command"])[1:])
    assert args.effects == "yaw_inertia,steering_lag"
    assert args.out.endswith("identify-steering_lag-no-signal_delay")


def test_the_cli_prints_what_it_found_and_no_command(monkeypatch, capsys, tmp_path):
    fake = _fake(False)
    fake.report |= {"identify_command": None, "not_claimed": "found steering_lag (…), but not claimed"}
    monkeypatch.setattr(api, "diagnose", lambda *a, **k: fake)
    rec = tmp_path / "rec.csv"
    good = Path(__file__).parent / "data" / "good"
    rec.write_bytes((good / "recording.csv").read_bytes())
    out = tmp_path / "diag"
    assert main(["diagnose", str(rec), "--vehicle", str(good / "vehicle.json"), "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert printed.strip().splitlines()[-1] == "found steering_lag (…), but not claimed"
    assert "vdsbi identify" not in printed
