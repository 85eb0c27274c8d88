"""Batch experiment with the Python API: many true parameter sets, one script, one table.

    python docs/batch_example.py [--n 4] [--sims 300] [--rounds 2]

For each true θ (drawn from the built-in vehicle's prior) it simulates a 4 s drive with the
vehicle's sensor noise (`vdsbi.api.simulate`), identifies θ from it with `vdsbi.api.identify`,
and prints truth, estimate and whether the 90 % interval covers the truth.
"""

from __future__ import annotations

import argparse

import jax
import numpy as np

from vdsbi import api
from vdsbi.simulator import PARAM_NAMES, Vehicle, default_vehicle, seed_profile

NOISE = {"ax": 0.05, "ay": 0.05, "yaw_rate": 0.005, "omega_front": 0.1, "omega_rear": 0.1, "vx": 0.05}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--n", type=int, default=4, help="true parameter sets")
    ap.add_argument("--sims", type=int, default=300)
    ap.add_argument("--rounds", type=int, default=2)
    args = ap.parse_args()

    vehicle = Vehicle.from_dict({**default_vehicle().to_dict(), "noise_std": NOISE})
    box = vehicle.default_prior()
    lo = np.array([box[n][0] for n in PARAM_NAMES])
    hi = np.array([box[n][1] for n in PARAM_NAMES])
    # Stay off the prior's edges, where no interval can cover the truth.
    thetas = lo + (hi - lo) * np.asarray(
        jax.random.uniform(jax.random.key(1), (args.n, 6), minval=0.2, maxval=0.8)
    )
    inputs = seed_profile(duration=4.0)
    rows = []
    for i, theta in enumerate(thetas):
        sim = api.simulate(theta, inputs, vehicle, v0=10.0, noise="vehicle", seed=i)
        rec = sim.to_recording(f"batch-{i}")
        budget = api.Budget(rounds=args.rounds, sims=args.sims)
        res = api.identify(rec, vehicle, api.IdentifyOptions(budget=budget, seed=i))
        for name, t in zip(PARAM_NAMES, theta):
            p = res.summary["parameters"][name]
            rows.append((i, name, t, p["estimate"], p["std"], p["q05"] <= t <= p["q95"]))
        print(f"set {i} done", flush=True)

    print(f"\n{'set':>3} {'param':<10} {'true':>11} {'estimate':>11} {'std':>10}  90% covers")
    for i, name, t, m, s, cov in rows:
        print(f"{i:>3} {name:<10} {t:>11.4g} {m:>11.4g} {s:>10.3g}  {'yes' if cov else 'no'}")
    cover = np.mean([r[-1] for r in rows])
    print(f"\n90 % intervals covering the truth: {cover:.0%} of {len(rows)}")


if __name__ == "__main__":
    main()
