"""Simulated drives written as recording files, for the tests that run commands on files."""

from __future__ import annotations

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
        effects=list(effects),
        effect_params=effects,
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
