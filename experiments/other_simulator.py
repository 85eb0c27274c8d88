"""Drives from another simulator, identified as a real drive is, and scored against their truth.

    python experiments/other_simulator.py [--quick] [--cases TEXT ...]

The other simulator is `linear_baseline`'s single-track model (numpy, nothing of vdsbi's): linear
tyres, or for a race car magic-formula tyres cornering at up to ~1.4 g, or on a scripted lap with
downforce (`DownforceLap`: the tyres' D = μ·F_z at axle loads that grow with v² by an aero
balance and shift under braking); a yaw inertia that is not m·l_f·l_r, the car responding `lag` s
after the logged steer (or its road-wheel angle following the logged steer through a
first-order lag: `write_drive(lag_kind=...)`), white sensor noise on a_y, yaw rate, speed and
steer, sampled at `rate` Hz (10 to 250), no wheel speeds and no torques. Each `CASES` drive
(90 s: a smooth random steer, the speed swinging between 12 and 22 m/s; a race car's steer
scaled to its speed for a lateral acceleration near the grip, between 13 and 31 m/s; the
downforce lap's first 70 % cornering at up to 1.2 g near 27 m/s, its last 30 % at 1.5 g near
37 m/s with braking) goes through `real_drives.run_one`: vdsbi's default `identify` on the first
70 %, held-out NRMSE of yaw rate and a_y on the rest against the least-squares fit of the linear
model (the linear cars' own model class, with the true l_f and I_z: without a delay, with the
steer delay its training cost picks, and at the true lag), the 90 % band's coverage, each truth
(l_f, C_αf, C_αr, the lag, the yaw-inertia index; a race car's friction factors, downforce and CoG
height) against its 95 % interval (held, or flagged as not identified or as moved by model
error), the pairs identify reports as trading, and `vdsbi predict --band` on the held-out part:
its windows beyond the fitted envelope and its band's coverage there.

Writes experiments/results/other_simulator{_quick}.json and .md; with `--cases`, only the cases
named, their rows merged into those files.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import tempfile
from pathlib import Path
from types import SimpleNamespace
from typing import Literal

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

import linear_baseline  # noqa: E402
import real_drives  # noqa: E402


@dataclasses.dataclass(frozen=True)
class Aero:
    """Downforce coef·m·g·(v/`AERO_SPEED`)², a share `balance_front` of it on the front axle."""

    coef: float
    balance_front: float


#: Speed at which `Aero.coef` is stated, m/s.
AERO_SPEED = 50.0


@dataclasses.dataclass(frozen=True)
class DownforceLap:
    """A scripted lap (`LAP_SPEED`, `LAP_CORNERS`) of a race car on magic-formula tyres of peak
    grip `mu` with downforce `aero` and its load moving between the axles under a_x (CoG height
    `h_cog`, m): the steer is what holds each corner's lateral acceleration in steady state,
    plus small driver corrections."""

    mu: float
    aero: Aero
    h_cog: float


@dataclasses.dataclass(frozen=True)
class Case:
    """One drive: sampled at `rate` Hz, the steer lagging by `lag` s (`lag_kind`: a pure delay or
    a first-order lag), the car's C_αf and C_αr (N/rad per axle), the seed of its steer and
    noise. `race`: magic-formula tyres (`MAGIC`), the steer scaled to the speed for ~1.4 g; `lap`:
    the scripted downforce lap instead (its own length); `friction`: the μ vehicle.json gives."""

    rate: float
    lag: float
    car: linear_baseline.Car
    cf: float
    cr: float
    seed: int
    race: bool = False
    lag_kind: Literal["delay", "first_order"] = "delay"
    friction: float = 1.0
    lap: DownforceLap | None = None


#: Race cars' tyres are magic-formula curves with the case's cornering stiffnesses; the new race
#: cars' lie inside vdsbi's default prior box (at most 30 × m·g/2 per axle), so that their intervals
#: test the lag and the downforce rather than the box.
CASES = {
    "linear car @ 50 Hz, 0.1 s lag": Case(
        50.0, 0.1, linear_baseline.Car(1600.0, 1.2, 1.5, 2400.0), 90e3, 110e3, 3
    ),
    "linear car @ 25 Hz, 0.2 s lag": Case(
        25.0, 0.2, linear_baseline.Car(1450.0, 1.1, 1.55, 2300.0), 70e3, 95e3, 4
    ),
    "linear car @ 10 Hz, 0.1 s lag": Case(
        10.0, 0.1, linear_baseline.Car(1500.0, 1.15, 1.5, 2600.0), 80e3, 100e3, 11
    ),
    "linear car @ 100 Hz, no lag": Case(
        100.0, 0.0, linear_baseline.Car(1900.0, 1.35, 1.45, 3600.0), 120e3, 140e3, 5
    ),
    "race car @ 250 Hz, magic-formula tyres, 1.4 g": Case(
        250.0, 0.0, linear_baseline.Car(850.0, 1.25, 1.8, 1100.0), 110e3, 150e3, 7, race=True
    ),
    # vehicle.json gives the tyres' μ: the lag, not a wrong μ, is what this drive asks about.
    "race car @ 25 Hz, 0.2 s first-order steer lag, 1.4 g": Case(
        25.0,
        0.2,
        linear_baseline.Car(900.0, 1.35, 1.65, 1250.0),
        105e3,
        125e3,
        13,
        race=True,
        lag_kind="first_order",
        friction=1.6,
    ),
    # vehicle.json gives the tyres' μ without downforce (what a data sheet would).
    "race car @ 250 Hz, downforce, fit part to 1.2 g, held-out to 1.5 g": Case(
        250.0,
        0.0,
        linear_baseline.Car(780.0, 1.5, 1.3, 1000.0),
        100e3,
        112e3,
        17,
        friction=1.25,
        lap=DownforceLap(mu=1.25, aero=Aero(coef=0.9, balance_front=0.42), h_cog=0.3),
    ),
}
NOISE = {"ay": 0.15, "yaw_rate": 0.004, "vx": 0.05, "steer": 0.0005}
#: The race car's tyres: F = D·sin(C·atan(Bα − E(Bα − atan Bα))), D = μ·F_z, B·C·D = C_α.
MAGIC = {"mu": 1.6, "C": 1.35, "E": -0.5}


def axle_loads(car, vx, ax=0.0, aero: Aero | None = None, h_cog: float = 0.0):
    """(front, rear) vertical load, N: the weight's static split, plus `aero`'s downforce at the
    speed `vx` (m/s) split by its balance, shifted rearwards by m·h·a_x/L under a_x (m/s²)."""
    g, L = 9.81, car.a + car.b
    down = 0.0 if aero is None else aero.coef * car.mass * g * (np.asarray(vx) / AERO_SPEED) ** 2
    front_share = 0.0 if aero is None else aero.balance_front
    shift = car.mass * h_cog * np.asarray(ax) / L
    return (
        car.mass * g * car.b / L + front_share * down - shift,
        car.mass * g * car.a / L + (1.0 - front_share) * down + shift,
    )


def magic_formula_force(alpha, cs: float, load, mu: float):
    """Lateral force (N) of the magic-formula tyre at slip angle `alpha` (rad): D = μ·`load`,
    B·C·D = `cs` (N/rad)."""
    d = mu * load
    x = cs / (MAGIC["C"] * d) * alpha
    return d * np.sin(MAGIC["C"] * np.arctan(x - MAGIC["E"] * (x - np.arctan(x))))


def magic_formula_drive(
    car,
    cf: float,
    cr: float,
    t,
    vx,
    delta,
    *,
    mu: float = MAGIC["mu"],
    aero: Aero | None = None,
    h_cog: float = 0.0,
):
    """(yaw rate, a_y) of the single-track car on magic-formula tyres of peak grip `mu` (D = μ·F_z
    at each axle's load: `axle_loads`, a_x the derivative of `vx`), RK4 at the sample interval."""
    ax = np.gradient(vx, t) if h_cog else 0.0
    fz_f, fz_r = (np.broadcast_to(f, np.shape(t)) for f in axle_loads(car, vx, ax, aero, h_cog))

    tyre = lambda alpha, cs, load: magic_formula_force(alpha, cs, load, mu)

    def rhs(y, k):
        v = vx[k]
        fyf = tyre(delta[k] - (y[0] + car.a * y[1]) / v, cf, fz_f[k])
        fyr = tyre(-(y[0] - car.b * y[1]) / v, cr, fz_r[k])
        return np.array([(fyf + fyr) / car.mass - v * y[1], (car.a * fyf - car.b * fyr) / car.iz]), (
            fyf + fyr
        ) / car.mass

    dt, y = float(t[1] - t[0]), np.zeros(2)
    r, ay = np.empty(len(t)), np.empty(len(t))
    for k in range(len(t)):
        k1, ay[k] = rhs(y, k)
        r[k] = y[1]
        k2 = rhs(y + 0.5 * dt * k1, k)[0]
        k3 = rhs(y + 0.5 * dt * k2, k)[0]
        k4 = rhs(y + dt * k3, k)[0]
        y = y + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    return r, ay


def magic_formula_slip(force, cs: float, load, mu: float):
    """The slip angle (rad) at which the magic-formula tyre gives `force` (N), on its rising
    branch: `force` is clipped to 98 % of the peak μ·`load`."""
    d = mu * load
    ratio = np.clip(np.abs(force) / d, 0.0, 0.98)
    # sin(C·atan(g)) = ratio on the rising branch, g(x) = (1 − E)·x + E·atan(x) rising in x.
    target = np.tan(np.arcsin(ratio) / MAGIC["C"])
    x = np.array(target, float)
    for _ in range(30):
        x = x - ((1 - MAGIC["E"]) * x + MAGIC["E"] * np.arctan(x) - target) / (
            1 - MAGIC["E"] + MAGIC["E"] / (1 + x**2)
        )
    return np.sign(force) * x * MAGIC["C"] * d / cs


#: The downforce lap's speed, m/s, through these (time s, speed) knots, eased between them:
#: launch, a straight, corner 1, a left-hander, fast sweepers, a hairpin (the first 63 s, what
#: `real_drives` fits on); then corner 1 a lap later, turns 2 and 3 faster and harder.
LAP_SPEED = (
    (0.0, 10.0),
    (8.0, 44.0),
    (10.0, 44.0),
    (12.5, 27.0),
    (18.5, 27.0),
    (24.0, 40.0),
    (26.0, 30.0),
    (31.5, 30.0),
    (38.0, 46.0),
    (47.0, 46.0),
    (50.5, 18.0),
    (56.0, 18.0),
    (63.0, 40.0),
    (65.5, 27.0),
    (70.5, 27.0),
    (74.5, 42.0),
    (76.5, 37.0),
    (81.0, 37.0),
    (82.5, 33.0),
    (87.5, 33.0),
    (90.0, 40.0),
)
#: The lap's corners: (start s, end s, steady lateral acceleration in g, left positive, ramp s).
LAP_CORNERS = (
    (12.0, 18.5, -1.2, 2.0),
    (26.5, 31.5, 1.05, 1.8),
    (39.0, 43.0, 0.5, 1.5),
    (43.5, 47.5, -0.55, 1.5),
    (50.0, 56.0, -1.15, 1.8),
    (64.8, 70.5, -1.2, 1.8),
    (75.8, 81.0, -1.5, 1.8),
    (82.0, 87.5, 1.45, 1.8),
)
LAP_SECONDS = LAP_SPEED[-1][0]


def lap_inputs(car, cf: float, cr: float, lap: DownforceLap, seed: int):
    """(speed, steer): functions of time (s) of the downforce lap; the steer holds each corner's
    lateral acceleration in steady state (at the loads of its speed and a_x), plus driver
    corrections worth up to 1 m/s² of lateral acceleration at any speed."""
    knots = np.array(LAP_SPEED)
    ease = lambda x: x**3 * (10 - 15 * x + 6 * x**2)  # C² between knots: a_x stays continuous

    def speed(s):
        out = np.full(np.shape(s), knots[0, 1])
        for (t0, v0), (t1, v1) in zip(knots[:-1], knots[1:]):
            out += (v1 - v0) * ease(np.clip((s - t0) / (t1 - t0), 0.0, 1.0))
        return out

    def lateral(s):
        out = np.zeros(np.shape(s))
        for t0, t1, g_level, ramp in LAP_CORNERS:
            up = np.clip((s - t0) / ramp, 0.0, 1.0)
            down = np.clip((t1 - s) / ramp, 0.0, 1.0)
            out += 9.81 * g_level * np.sin(0.5 * np.pi * np.minimum(up, down)) ** 2
        return out

    rng = np.random.default_rng(seed)
    freq, phase, amp = rng.uniform(0.3, 1.5, 6), rng.uniform(0, 2 * np.pi, 6), rng.uniform(0.5, 1.0, 6)
    L = car.a + car.b

    def steer(s):
        s = np.asarray(s, float)
        v, ay = speed(s), lateral(s)
        ax = (speed(s + 1e-3) - speed(s - 1e-3)) / 2e-3
        fz_f, fz_r = axle_loads(car, v, ax, lap.aero, lap.h_cog)
        steady = (
            L * ay / v**2
            + magic_formula_slip(car.mass * ay * car.b / L, cf, fz_f, lap.mu)
            - magic_formula_slip(car.mass * ay * car.a / L, cr, fz_r, lap.mu)
        )
        wobble = np.sum(amp * np.sin(2 * np.pi * freq * s[..., None] + phase), axis=-1) / np.sum(amp)
        return steady + L * wobble / v**2

    return speed, steer


def first_order_lag(t, steer, tau: float):
    """The road-wheel angle δ with τ·δ̇ = steer − δ, from δ = steer at t[0]: exact for a steer
    linear between the samples of the (fine, uniform) grid `t`."""
    from scipy.signal import lfilter

    if tau <= 0.0:
        return np.asarray(steer, float)
    h = float(t[1] - t[0])
    a = np.exp(-h / tau)
    # δ_{k+1} = a·δ_k + c·u_{k+1} + (1 − a − c)·u_k solves the ODE exactly for u linear in [t_k, t_{k+1}].
    c = 1.0 - tau / h * (1.0 - a)
    y, _ = lfilter([c, 1.0 - a - c], [1.0, -a], steer, zi=[(1.0 - c) * steer[0]])
    return y


def write_drive(
    folder: Path,
    rate: float,
    lag: float,
    car,
    cf: float,
    cr: float,
    seed: int,
    duration: float,
    race: bool = False,
    lag_kind: Literal["delay", "first_order"] = "delay",
    *,
    friction: float = 1.0,
    lap: DownforceLap | None = None,
) -> dict[str, float]:
    """recording.csv, vehicle.json and reference.json (the truth) of one drive in `folder`; the
    truth. `race`: magic-formula tyres, the steer scaled to the speed for ~1.4 g. `lag_kind`:
    the car responds to the steer `lag` s after it is logged ("delay"), or its road-wheel angle
    follows the logged steer with time constant `lag` ("first_order": τ·δ̇ = δ_logged − δ).
    `lap`: the downforce lap (`LAP_SECONDS` long, `duration` unused). `friction`: vehicle.json's μ."""
    import pandas as pd

    if lap is not None:
        duration = LAP_SECONDS
    t = np.arange(0.0, duration, 1.0 / rate)
    rng = np.random.default_rng(seed)
    # Integrated finely, then sampled.
    fine = np.arange(0.0, duration, 0.002 if race or lap else 0.005)
    delay = lag if lag_kind == "delay" else 0.0

    def acting(steer):
        if lag_kind == "delay":
            return steer(fine - delay)
        return first_order_lag(fine, steer(fine), lag)

    if lap is not None:
        speed, steer = lap_inputs(car, cf, cr, lap, seed)
        vx = speed(t)
        r, ay = magic_formula_drive(
            car, cf, cr, fine, speed(fine), acting(steer), mu=lap.mu, aero=lap.aero, h_cog=lap.h_cog
        )
    elif race:
        freq, phase, amp = rng.uniform(0.05, 0.35, 6), rng.uniform(0, 2 * np.pi, 6), rng.uniform(0.4, 1, 6)
        speed = lambda s: 22.0 + 7.0 * np.sin(2 * np.pi * s / 23.0) + 2.0 * np.sin(2 * np.pi * s / 7.1)
        shape = lambda s: np.tanh(1.5 * np.sum(amp * np.sin(2 * np.pi * freq * s[:, None] + phase), axis=1))
        steer = lambda s: 16.5 * (car.a + car.b) * shape(s) / speed(s) ** 2
        vx = speed(t)
        r, ay = magic_formula_drive(car, cf, cr, fine, speed(fine), acting(steer))
    else:
        freq, phase, amp = rng.uniform(0.05, 0.5, 8), rng.uniform(0, 2 * np.pi, 8), rng.uniform(0.3, 1.0, 8)
        steer = lambda s: 0.012 * np.sum(amp * np.sin(2 * np.pi * freq * s[:, None] + phase), axis=1)
        vx = 17.0 + 5.0 * np.sin(2 * np.pi * t / 45.0)
        r, ay = linear_baseline.simulate(car, cf, cr, fine, np.interp(fine, t, vx), acting(steer), 0.0)
    cols = {
        "t": t,
        "steer": steer(t) + rng.normal(0, NOISE["steer"], t.size),
        "ay": np.interp(t, fine, ay) + rng.normal(0, NOISE["ay"], t.size),
        "yaw_rate": np.interp(t, fine, r) + rng.normal(0, NOISE["yaw_rate"], t.size),
        "vx": vx + rng.normal(0, NOISE["vx"], t.size),
    }
    folder.mkdir(parents=True, exist_ok=True)
    pd.DataFrame(cols).to_csv(folder / "recording.csv", index=False, float_format="%.8g")
    vehicle = {
        "mass": car.mass,
        "wheelbase": car.a + car.b,
        "wheel_radius": 0.31,
        "wheel_inertia": 1.5,
        "tire_vertical_stiffness": 250000.0,
        "friction": friction,
        # The other simulator's tyres make force at once (no relaxation); 0.3 m here would be a
        # lag of 0.3/v s that the fitted delay or lag then gives back.
        "relaxation_length": 0.05,
    }
    (folder / "vehicle.json").write_text(json.dumps(vehicle, indent=2) + "\n")
    truth = {
        "l_f": car.a,
        "C_alpha_f": cf,
        "C_alpha_r": cr,
        ("signal_delay.delay" if lag_kind == "delay" else "steering_lag.tau"): lag,
        "yaw_inertia.dynamic_index": car.iz / (car.mass * car.a * car.b),
    }
    if race or lap is not None:
        # The magic formula's peak μ·F_z is Dugoff's limit at the same μ.
        mu = MAGIC["mu"] if lap is None else lap.mu
        truth |= {"tyre_friction.scale_front": mu / friction, "tyre_friction.scale_rear": mu / friction}
        truth["downforce.coef"] = 0.0 if lap is None else lap.aero.coef
    if lap is not None:
        truth |= {"downforce.balance_front": lap.aero.balance_front, "h_cog": lap.h_cog}
    ref = {"l_f": car.a, "I_z": car.iz, "source": "the truth", "truth": truth}
    (folder / "reference.json").write_text(json.dumps(ref, indent=2) + "\n")
    return truth


#: A first-order lag τ delays a slow steer by τ: where identify models the lag as a pure delay,
#: that delay is scored against τ.
STAND_INS = {"steering_lag.tau": "signal_delay.delay"}


def fitted_name(row: dict, name: str) -> str | None:
    """The parameter of `row`'s estimate that stands for the true parameter `name`, if any."""
    if name in row["interval95"]:
        return name
    other = STAND_INS.get(name)
    return other if other in row["interval95"] else None


def truth_check(row: dict, truth: dict) -> dict[str, str]:
    """Per true parameter: "held" (inside the 95 % interval), "flagged" (reported as not identified
    or as moved by model error, as `calibration.py` counts) or "missed"."""
    flagged = {*row["not_identified"], *row["model_error"]}
    out = {}
    for name, value in truth.items():
        fitted = fitted_name(row, name)
        if fitted is None:
            continue
        lo, hi = row["interval95"][fitted]
        out[name] = "held" if lo <= value <= hi else ("flagged" if fitted in flagged else "missed")
    return out


def run_record(run_dir: Path, drive: Path) -> dict:
    """What identify's posterior.json says beyond `real_drives.run_one`'s row (each parameter's
    `identified` and `trades_with`, the trading pairs, the fitted envelope and identify's own
    held-out windows beyond it), and `vdsbi predict --band` on the held-out part of `drive`: its
    windows beyond the envelope and the band's coverage there (widened where beyond)."""
    from vdsbi import api
    from vdsbi.io import load_drive

    post = json.loads((run_dir / "posterior.json").read_text())
    rec, _ = load_drive(drive / "recording.csv", drive / "vehicle.json")
    cut = rec.t[0] + real_drives.TRAIN_FRACTION * rec.duration
    held = api.predict(run_dir, real_drives.without_torques(rec, cut, rec.t[-1]), band=True)
    windows = int(held.frame["window"].nunique())
    params = post["parameters"]
    return {
        "identified": {n: p["identified"] for n, p in params.items()},
        "trades_with": {n: p["trades_with"] for n, p in params.items() if p.get("trades_with")},
        "trading_pairs": [
            {"pair": q["pair"], "correlation": q["correlation"]}
            for q in post["combinations"]["trading_pairs"]
        ],
        "envelope": post["envelope"]["peaks"],
        "identify_extrapolation": (post.get("validation") or {}).get("extrapolation"),
        "predict": {
            "windows": windows,
            "beyond": [
                {
                    "t0": f["t0"],
                    "t1": f["t1"],
                    "beyond": f["beyond"],
                    "grip_from_prior": "grip_from_prior" in f,
                }
                for f in held.extrapolation or ()
            ],
            "coverage": held.coverage,
            "nrmse": {c: v["nrmse"] for c, v in held.scores.items() if c in real_drives.CHANNELS},
        },
    }


def lag_check(row: dict, truth: dict) -> str | None:
    """The lag's estimate and 95 % interval against the truth, and whether it trades with the yaw
    inertia (flagged as a pair); None where the drive has no lag."""
    name = next((n for n in truth if n in ("signal_delay.delay", "steering_lag.tau")), None)
    if name is None or truth[name] == 0.0:
        return None
    fitted = fitted_name(row, name)
    if fitted is None:
        return "no lag fitted"
    lo, hi = row["interval95"][fitted]
    text = f"{fitted} {row['estimate'][fitted]:.3f} [{lo:.3f}, {hi:.3f}] vs {truth[name]:g} s"
    held = lo <= truth[name] <= hi
    partners = row["record"]["trades_with"].get(fitted, [])
    if held:
        return text + ": held"
    if partners:
        return text + f": not held, flagged as trading with {', '.join(partners)}"
    if fitted in row["not_identified"]:
        return text + ": not held, flagged not identified"
    return text + ": missed"


def markdown(rows: list[dict]) -> str:
    f = lambda d, c: "–" if not d or c not in d else f"{d[c]:.3f}"
    pct = lambda v: "–" if v is None else f"{v:.0%}"
    L = [
        "# Drives from another simulator (a single-track model, linear or magic-formula tyres): vdsbi "
        "identify (defaults) on "
        "the first 70 %, scored on the rest and against the truth",
        "",
        "| drive | held-out NRMSE yaw rate / a_y: vdsbi estimate | LS fit (linear tyres, true l_f, I_z) | "
        "LS fit + steer delay | LS fit at the true lag | inside 90 % band (yaw rate / a_y) | "
        "held-out windows beyond the fitted envelope; predict's band there | "
        "truth inside 95 % interval (else flagged) | "
        "identify wall s |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        checks = r["truth_check"]
        held = sum(v == "held" for v in checks.values())
        flagged = sum(v == "flagged" for v in checks.values())
        missed = [k for k, v in checks.items() if v == "missed"]
        cov = r["band_coverage"]
        L.append(
            f"| {r['drive']} | {f(r['ours'], 'yaw_rate')} / {f(r['ours'], 'ay')} | "
            f"{f(r['ls']['nrmse'], 'yaw_rate')} / {f(r['ls']['nrmse'], 'ay')} | "
            f"{f(r['ls_delay']['nrmse'], 'yaw_rate')} / {f(r['ls_delay']['nrmse'], 'ay')} "
            f"(d = {r['ls_delay']['delay']:.2f} s) | "
            f"{f(r['ls_true_delay']['nrmse'], 'yaw_rate')} / {f(r['ls_true_delay']['nrmse'], 'ay')} | "
            f"{pct(cov.get('yaw_rate'))} / {pct(cov.get('ay'))} | "
            f"{_beyond_text(r.get('record'))} | "
            f"{held} of {len(checks)}"
            + (f", {flagged} flagged" if flagged else "")
            + (f" (missed: {', '.join(missed)})" if missed else "")
            + f" | {r['wall_s']:.0f} |"
        )
    L += [
        "",
        "Held-out NRMSE and the band: `real_drives.run_one` (10-s windows, the band of identify's draws). "
        "Beyond the envelope: `vdsbi predict --band` on the held-out part against the peaks of the "
        "driving identify fitted (posterior.json `envelope`), its windows flagged and its band's "
        "coverage (the grip drawn from its prior where flagged).",
        "",
    ]
    for r in rows:
        L.append(f"## {r['drive']}")
        L.append("")
        L.append(
            f"effects: {', '.join(r['effects']) or 'none'}; not identified: {', '.join(r['not_identified']) or 'none'}"
        )
        L.append("")
        for name, value in r["truth"].items():
            fitted = fitted_name(r, name)
            if fitted is not None:
                lo, hi = r["interval95"][fitted]
                est = r["estimate"][fitted]
                shown = name if fitted == name else f"{name} (as {fitted})"
                L.append(
                    f"- {shown}: {est:.4g} [{lo:.4g}, {hi:.4g}] vs {value:.4g}: {r['truth_check'][name]}"
                )
            else:
                L.append(f"- {name}: not in the fitted model (truth {value:.4g})")
        rec = r.get("record")
        if rec:
            lag = lag_check(r, r["truth"])
            if lag:
                L.append(f"- the lag: {lag}")
            pairs = "; ".join(
                f"{' ↔ '.join(q['pair'])} (ρ = {q['correlation']:+.2f})" for q in rec["trading_pairs"]
            )
            L.append(f"- pairs that trade: {pairs or 'none'}")
            env = ", ".join(f"{k} {v:.3g}" for k, v in rec["envelope"].items())
            L.append(f"- fitted envelope (peaks of the fitted driving): {env}")
            own = rec["identify_extrapolation"]
            L.append(
                "- identify's own held-out windows beyond its training envelope: "
                + ("not recorded" if own is None else str(len(own)))
            )
            pr = rec["predict"]
            L.append(
                f"- `predict --band` on the held-out part: {len(pr['beyond'])} of {pr['windows']} windows beyond "
                "the envelope"
                + "".join(
                    f"; {b['t0']:.1f}–{b['t1']:.1f} s: "
                    + ", ".join(f"{q} {lo:.3g} → {hi:.3g}" for q, (lo, hi) in b["beyond"].items())
                    for b in pr["beyond"]
                )
                + f"; NRMSE yaw rate / a_y {f(pr['nrmse'], 'yaw_rate')} / {f(pr['nrmse'], 'ay')}; "
                f"inside its 90 % band {pct(pr['coverage'].get('yaw_rate'))} / {pct(pr['coverage'].get('ay'))}"
            )
        L.append("")
    return "\n".join(L) + "\n"


def _beyond_text(rec: dict | None) -> str:
    if not rec:
        return "–"
    pr = rec["predict"]
    quantities = sorted({q for b in pr["beyond"] for q in b["beyond"]})
    pct = lambda v: "–" if v is None else f"{v:.0%}"
    cov = pr["coverage"]
    return (
        f"{len(pr['beyond'])} of {pr['windows']}"
        + (f" ({', '.join(quantities)})" if quantities else "")
        + f"; {pct(cov.get('yaw_rate'))} / {pct(cov.get('ay'))}"
    )


def merged(stem: str, rows: list[dict]) -> list[dict]:
    """`rows` over those results/<stem>.json holds for other drives, in `CASES`' order."""
    path = real_drives.RESULTS / f"{stem}.json"
    old = json.loads(path.read_text()) if path.is_file() else []
    by_name = {r["drive"]: r for r in old} | {r["drive"]: r for r in rows}
    order = {name: i for i, name in enumerate(CASES)}
    return sorted(by_name.values(), key=lambda r: order.get(r["drive"], len(order)))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="40 s drives, 300 simulations (a smoke test)")
    ap.add_argument(
        "--cases",
        nargs="+",
        default=None,
        metavar="TEXT",
        help="run only the cases whose name contains one of these; their rows replace those of the "
        "same drives in the result files (default: all cases; with --quick, the first)",
    )
    args = ap.parse_args(argv)
    if args.cases:
        cases = {k: v for k, v in CASES.items() if any(c in k for c in args.cases)}
        if not cases:
            ap.error(f"--cases: no case name contains any of {args.cases}; cases: {list(CASES)}")
    else:
        cases = dict(list(CASES.items())[:1]) if args.quick else CASES
    duration = 40.0 if args.quick else 90.0
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        settings = SimpleNamespace(
            real=Path(tmp), rounds=1 if args.quick else 2, sims=300 if args.quick else 1000
        )
        for k, (name, c) in enumerate(cases.items()):
            folder = Path(tmp) / name
            truth = write_drive(
                folder,
                c.rate,
                c.lag,
                c.car,
                c.cf,
                c.cr,
                c.seed,
                duration,
                c.race,
                c.lag_kind,
                friction=c.friction,
                lap=c.lap,
            )
            runs = Path(tmp) / f"runs{k}"
            row = real_drives.run_one(name, settings, runs, true_delay=c.lag)
            row["record"] = run_record(next(runs.rglob("posterior.json")).parent, folder)
            rows.append(row | {"truth": truth, "truth_check": truth_check(row, truth)})
    stem = "other_simulator" + ("_quick" if args.quick else "")
    real_drives.write_rows(stem, merged(stem, rows) if args.cases else rows, markdown)
    return 0


if __name__ == "__main__":
    sys.exit(main())
