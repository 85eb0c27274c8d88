"""Simulated drives written as recording files, for the tests that run commands on files, and
the fleet's one-drive setup its per-drive tests share."""

from __future__ import annotations

import json
from pathlib import Path

import jax
import numpy as np
import pandas as pd

from vdsbi.simulator import (
    CHANNELS,
    SEED_TRUE_THETA,
    default_vehicle,
    random_profile,
    simulate,
    theta_from_dict,
)
from vdsbi.simulator.effects import EffectSettings


def drive_csv(
    path: Path,
    seed: int,
    effects: dict,
    noise: dict[str, float],
    *,
    duration: float = 4.0,
    torques: bool = True,
) -> Path:
    """A drive of the built-in vehicle at the seed's truth with `effects` ({effect: {param: value}})
    concealed: a random profile from `seed`, the `noise` channels with their sensor noise, and the
    wheel torques where `torques`."""
    inp = random_profile(jax.random.key(seed), duration)
    ys, ok = simulate(
        theta_from_dict(SEED_TRUE_THETA),
        inp,
        default_vehicle(),
        v0=10.0,
        effects=EffectSettings(enabled=list(effects), params=effects),
    )
    assert ok
    rng = np.random.default_rng(seed)
    df = pd.DataFrame({"t": np.asarray(inp.ts), "steer": np.asarray(inp.steer)})
    if torques:
        df["torque_front"], df["torque_rear"] = np.asarray(inp.torque_front), np.asarray(inp.torque_rear)
    for c, s in noise.items():
        df[c] = np.asarray(ys)[:, CHANNELS.index(c)] + rng.normal(0.0, s, len(df))
    df.to_csv(path, index=False)
    return path


def fleet_drive(folder: Path, seconds: float) -> tuple[Path, Path, dict]:
    """A simulated fleet of one car and one drive of `seconds` in `folder`: the drive's recording,
    its vehicle file and its true values."""
    from vdsbi.fleet import simulated_fleet

    manifest = simulated_fleet(folder, cars=1, drives=1, duration=seconds, changes=(), seed=2)
    root = manifest.parent
    truth = json.loads((root / "truth.json").read_text())["car01/drive0.csv"]["values"]
    return root / "car01" / "drive0.csv", root / "vehicle.json", truth


def crude_proposal(box, truth: dict):
    """A Gaussian 1.5 prior std off the truth in every coordinate: its check fails, a fit follows."""
    from vdsbi.estimation import PRIOR_Z_STD
    from vdsbi.fleet._amortized import Proposal

    centre = np.asarray(box.to_unbounded(np.asarray([truth.get(n, np.nan) for n in box.names])), float)
    centre = np.where(np.isfinite(centre), centre, 0.0) + 1.5 * PRIOR_Z_STD * np.where(centre > 0, -1, 1)
    return Proposal(centre, np.eye(box.dim) * (0.5 * PRIOR_Z_STD) ** 2, 1)


def answer_crude(recording: Path, vehicle: Path, platform, truth: dict, tmp_path: Path, monkeypatch):
    """The fleet's answer for one drive whose amortized posterior is `crude_proposal`."""
    from vdsbi.fleet import _drive

    monkeypatch.setattr(_drive, "_estimator", lambda *a: None)
    monkeypatch.setattr(_drive, "drive_proposal", lambda *a: crude_proposal(platform.box, truth))
    drive = type("Drive", (), {"recording": recording, "vehicle": vehicle})()
    where = (platform, tmp_path, None)
    return _drive._answer(jax.random.key(0), drive, where, tmp_path / "out", _drive.Escalation(), 10, {})
