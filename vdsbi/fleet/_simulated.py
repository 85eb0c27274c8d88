"""A simulated fleet with known truth: cars of one platform, drives over time, and the changes a
fleet operator wants caught (a tyre set that loses stiffness, a load that moves the centre of
gravity, a steering signal that starts to lag)."""

from __future__ import annotations

import dataclasses
import json
import os
from pathlib import Path

import numpy as np

#: Sensor noise of the simulated drives, per channel (channel units; the demo's).
NOISE_STD = {"ax": 0.05, "ay": 0.05, "yaw_rate": 0.003, "omega_front": 0.1, "omega_rear": 0.1, "vx": 0.03}
#: The platform's true θ before any change (a car's own draw scatters around it).
BASE_THETA = {
    "l_f": 1.35,
    "h_cog": 0.5,
    "C_kappa_f": 1.2e5,
    "C_kappa_r": 1.2e5,
    "C_alpha_f": 7.0e4,
    "C_alpha_r": 8.0e4,
}
#: Every car's steer-to-motion latency before a lag develops, s.
BASE_DELAY = 0.04


@dataclasses.dataclass(frozen=True)
class TrueChange:
    """A change on one car from its drive `at` (0-based) on: parameters multiplied by `scale`,
    shifted by `shift` (both {name: value}, θ's names or ``signal_delay.delay``)."""

    car: str
    at: int
    scale: dict = dataclasses.field(default_factory=dict)
    shift: dict = dataclasses.field(default_factory=dict)


#: The must-show changes: tyres lose a quarter of their cornering stiffness, a load moves the
#: centre of gravity 0.2 m back, the steer signal lags 0.15 s more.
TRUE_CHANGES = (
    TrueChange("car01", 2, scale={"C_alpha_f": 0.75, "C_alpha_r": 0.75}),
    TrueChange("car02", 2, shift={"l_f": 0.2}),
    TrueChange("car03", 2, shift={"signal_delay.delay": 0.15}),
)


def simulated_fleet(
    out: str | os.PathLike,
    *,
    cars: int = 6,
    drives: int = 4,
    duration: float = 40.0,
    changes: tuple[TrueChange, ...] = TRUE_CHANGES,
    seed: int = 0,
) -> Path:
    """Write a fleet of `cars` × `drives` simulated drives under `out`: one vehicle.json (the
    platform), car*/drive*.csv without torque columns (steer, IMU, wheel speeds, vx), a
    manifest.csv (car, recording, vehicle, time) and truth.json (each drive's θ and delay).
    Returns the manifest's path. Deterministic in `seed`."""
    import jax
    import pandas as pd

    from ..simulator import CHANNELS, PARAM_NAMES, default_vehicle, random_profile, simulate
    from ..simulator.effects import EffectSettings

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    veh = default_vehicle()
    (out / "vehicle.json").write_text(json.dumps({**veh.to_dict(), "noise_std": NOISE_STD}, indent=2) + "\n")
    rng = np.random.default_rng(seed)
    rows, truth = [], {}
    for c in range(1, cars + 1):
        car = f"car{c:02d}"
        own = {n: v * float(rng.uniform(0.95, 1.05)) for n, v in BASE_THETA.items()}
        (out / car).mkdir(exist_ok=True)
        for d in range(drives):
            values = dict(own) | {"signal_delay.delay": BASE_DELAY}
            for ch in changes:
                if ch.car == car and d >= ch.at:
                    values = {n: v * ch.scale.get(n, 1.0) + ch.shift.get(n, 0.0) for n, v in values.items()}
            theta = np.array([values[n] for n in PARAM_NAMES])
            key = jax.random.key(seed * 100_003 + c * 101 + d)
            for attempt in range(50):
                inp = random_profile(jax.random.fold_in(key, attempt), duration=duration, max_steer=0.03)
                delay = {"signal_delay": {"delay": values["signal_delay.delay"]}}
                effects = EffectSettings(enabled=["signal_delay"], params=delay)
                ys, ok = simulate(theta, inp, veh, v0=15.0, effects=effects)
                ys = np.asarray(ys)
                if ok and float(ys[:, CHANNELS.index("vx")].min()) > 5.0:
                    break
            else:
                raise RuntimeError(f"{car} drive {d}: no drivable random maneuver in 50 draws")
            frame = pd.DataFrame({"t": np.asarray(inp.ts), "steer": np.asarray(inp.steer)})
            for i, ch in enumerate(CHANNELS):
                frame[ch] = ys[:, i] + rng.normal(0.0, NOISE_STD[ch], len(frame))
            name = f"{car}/drive{d}.csv"
            frame.to_csv(out / name, index=False, float_format="%.9g")
            time = f"2025-03-{d + 1:02d}T{8 + c % 10:02d}:00:00"
            rows.append({"car": car, "recording": name, "vehicle": "vehicle.json", "time": time})
            truth[name] = {"car": car, "drive": d, "time": time, "values": values}
    pd.DataFrame(rows).to_csv(out / "manifest.csv", index=False)
    (out / "truth.json").write_text(json.dumps(truth, indent=1) + "\n")
    return out / "manifest.csv"
