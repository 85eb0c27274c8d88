"""`vdsbi simulate`: drive the simulator with a recording's inputs or a built-in profile and
write the result as a recording in the contract format."""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import tempfile
from collections.abc import Mapping
from pathlib import Path

import numpy as np

from ..io._errors import InputError
from ..simulator._vehicle import CHANNELS, NOMINAL_THETA, PARAM_NAMES

#: Initial speed of the built-in profiles, m/s (the middle of the seed's U[10, 11]).
PROFILE_V0 = 10.5
PROFILES = ("seed",)
UNITS = {
    "ax": "m/s²",
    "ay": "m/s²",
    "yaw_rate": "rad/s",
    "omega_front": "rad/s",
    "omega_rear": "rad/s",
    "vx": "m/s",
}


def add_parser(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        "simulate",
        help="simulate a drive and write it as a recording (CSV)",
        description="Drive the vehicle model with a recording's inputs (--inputs) or a built-in "
        "profile (--profile) and write t, the inputs used and the simulated channels "
        "(ax, ay, yaw_rate, omega_front, omega_rear, vx) as a contract CSV.",
    )
    p.add_argument("--vehicle", required=True, metavar="V", help="vehicle constants (.json or .yaml)")
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("--inputs", metavar="REC", help="recording whose steer/torque inputs drive the model")
    src.add_argument("--profile", choices=PROFILES, help="built-in maneuver (seed: the seed paper's, 5 s)")
    p.add_argument(
        "--theta",
        metavar="JSON",
        help="JSON object or file {param: value}; missing params default to the seed's Table II "
        "truth with --profile seed, else to the Table I nominal values",
    )
    p.add_argument("--effects", metavar="JSON", help="JSON object or file {effect: {param: value}}")
    p.add_argument(
        "--v0",
        type=float,
        metavar="M_PER_S",
        help="initial speed, m/s (default: the recording's first speed, or 10.5 with --profile)",
    )
    p.add_argument("--noise", choices=("none", "seed", "vehicle"), default="none", help="sensor noise")
    p.add_argument("--seed", type=int, default=0, help="random seed of the noise (default 0)")
    p.add_argument("--out", required=True, metavar="OUT.csv", help="recording to write")
    p.add_argument("--plot", metavar="PNG", help="also write a figure of the inputs and channels")
    return p


def _json_arg(text: str, flag: str) -> Mapping:
    """A JSON object given inline or as a file name."""
    source = flag
    if not text.lstrip().startswith("{"):
        path = Path(text)
        if not path.is_file():
            raise InputError(flag, "value", f"'{text}' is neither a JSON object nor an existing file")
        source = str(path)
        try:
            text = path.read_text(encoding="utf-8")
        except OSError as err:
            raise InputError(source, "file", f"cannot read ({type(err).__name__})") from None
    try:
        data = json.loads(text)
    except json.JSONDecodeError as err:
        raise InputError(source, "value", f"invalid JSON at column {err.colno}: {err.msg}") from None
    if not isinstance(data, Mapping):
        raise InputError(source, "value", f"expected a JSON object, got {type(data).__name__}")
    return data


def _number(value, source: str, field: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise InputError(source, field, f"must be a finite number, got {value!r}")
    return float(value)


def parse_theta(text: str | None, defaults: Mapping[str, float], vehicle) -> np.ndarray:
    """θ in PARAM_NAMES order from --theta over `defaults`; InputError naming the parameter."""
    from ..simulator import check_theta

    values = dict(defaults)
    if text is not None:
        given = _json_arg(text, "--theta")
        for name, value in given.items():
            if name not in PARAM_NAMES:
                raise InputError(
                    "--theta", str(name), f"unknown parameter; expected one of {list(PARAM_NAMES)}"
                )
            values[name] = _number(value, "--theta", name)
    theta = np.array([values[n] for n in PARAM_NAMES])
    try:
        check_theta(theta, vehicle)
    except ValueError as err:
        name = next((n for n in PARAM_NAMES if f"'{n}'" in str(err)), "theta")
        raise InputError("--theta", name, str(err).removeprefix("theta: ")) from None
    return theta


def parse_effects(text: str | None) -> tuple[list[str], dict[str, dict[str, float]]]:
    """(effect names, {effect: {param: value}}) from --effects; InputError naming the field."""
    from ..simulator import EFFECTS

    if text is None:
        return [], {}
    given = _json_arg(text, "--effects")
    names, values = [], {}
    for name, params in given.items():
        if name not in EFFECTS:
            raise InputError("--effects", str(name), f"unknown effect; expected one of {list(EFFECTS)}")
        cls = EFFECTS[name]
        if params is None:
            params = {}
        if not isinstance(params, Mapping):
            raise InputError("--effects", name, f"expected {{param: value}}, got {params!r}")
        clean = {}
        for p, v in params.items():
            if p not in cls.param_names:
                raise InputError(
                    "--effects", f"{name}.{p}", f"unknown parameter; '{name}' has {list(cls.param_names)}"
                )
            clean[p] = _number(v, "--effects", f"{name}.{p}")
        names.append(name)
        values[name] = clean
    return names, values


def initial_speed(args, rec, vehicle) -> float:
    if args.v0 is not None:
        v0 = args.v0
    elif rec is None:
        v0 = PROFILE_V0
    else:
        speed = rec.speed(vehicle.wheel_radius)
        if speed is None:
            raise InputError(rec.source, "v0", "the recording has neither vx nor wheel speeds; give --v0")
        v0 = float(speed[0])
        if not (math.isfinite(v0) and v0 > 0):
            raise InputError(rec.source, "v0", f"initial speed {v0:g} m/s is not > 0; give --v0")
        return v0
    if not (math.isfinite(v0) and v0 > 0):
        raise InputError("--v0", "v0", f"initial speed must be > 0 m/s, got {v0}")
    return float(v0)


def run(args) -> int:
    import jax

    from ..io import Recording, read_recording, read_vehicle
    from ..simulator import SEED_TRUE_THETA, seed_profile, sensor_noise, simulate

    vehicle = read_vehicle(args.vehicle)
    out = Path(args.out)
    if out.suffix.lower() != ".csv":
        raise InputError(args.out, "--out", "expected a .csv file name")
    if out.is_dir():
        raise InputError(args.out, "--out", "is a directory; expected a .csv file name")
    if args.plot and Path(args.plot).suffix.lower() != ".png":
        raise InputError(args.plot, "--plot", "expected a .png file name")
    rec = None
    if args.inputs:
        rec = read_recording(args.inputs)
        inputs = rec.inputs()
        defaults = NOMINAL_THETA
    else:
        inputs = seed_profile()
        defaults = SEED_TRUE_THETA
    theta = parse_theta(args.theta, defaults, vehicle)
    effects, effect_params = parse_effects(args.effects)
    v0 = initial_speed(args, rec, vehicle)
    if args.noise == "vehicle" and not vehicle.noise_std:
        raise InputError(args.vehicle, "noise_std", "--noise vehicle needs noise_std in the vehicle file")

    ys, ok = simulate(theta, inputs, vehicle, v0=v0, effects=effects, effect_params=effect_params)
    if not ok:
        print(
            "vdsbi: error: the simulation left the model's domain (non-finite state or reversing "
            "wheels); check --theta, --effects and the inputs",
            file=sys.stderr,
        )
        return 1
    noise = sensor_noise(args.noise, vehicle.noise_std)
    ys = np.asarray(noise(jax.random.key(args.seed), ys), dtype=float)

    # the inputs as given (float64), not their float32 copies inside the simulator
    given = rec if rec is not None else inputs
    t = float(inputs.t0) + inputs.dt * np.arange(inputs.num_samples)
    rate = 1.0 / inputs.dt
    result = Recording(
        t=t,
        steer=np.asarray(given.steer, dtype=float),
        torque_front=np.asarray(given.torque_front, dtype=float),
        torque_rear=np.asarray(given.torque_rear, dtype=float),
        channels={c: ys[:, i] for i, c in enumerate(CHANNELS)},
        source=str(out),
        rate=rate,
        original_rate=rate,
    )
    _write_atomically(out, result.to_csv)
    src = f"inputs of {args.inputs}" if args.inputs else f"profile '{args.profile}'"
    print(f"wrote {out}: {result.num_samples} samples, {result.duration:.2f} s, {src}, v0 {v0:.2f} m/s")
    print("  theta   " + ", ".join(f"{n} {v:.4g}" for n, v in zip(PARAM_NAMES, theta)))
    if effects:
        print("  effects " + "; ".join(f"{e} {effect_params[e] or '(null)'}" for e in effects))
    print(f"  noise   {args.noise}" + (f" (seed {args.seed})" if args.noise != "none" else ""))
    if args.plot:
        _write_atomically(Path(args.plot), lambda p: plot(result, theta, effects, p))
        print(f"wrote {args.plot}")
    return 0


def _write_atomically(path: Path, write) -> None:
    """Write via a temporary sibling renamed into place: no partial file on failure."""
    path.absolute().parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(
        prefix=f".{path.name}.partial-", suffix=path.suffix, dir=path.absolute().parent
    )
    os.close(fd)
    try:
        write(tmp)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def plot(rec, theta, effects, path) -> None:
    """Inputs and the six channels against time, one panel each."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(4, 2, figsize=(11, 9), sharex=True)
    ax = axes[0, 0]
    ax.plot(rec.t, rec.steer, color="k")
    ax.set_ylabel("steer [rad]")
    ax = axes[0, 1]
    ax.plot(rec.t, rec.torque_front, label="front")
    ax.plot(rec.t, rec.torque_rear, label="rear")
    ax.set_ylabel("axle torque [N·m]")
    ax.legend(loc="best", fontsize=8)
    for ax, c in zip(axes[1:].ravel(), CHANNELS):
        ax.plot(rec.t, rec.channels[c], lw=0.8)
        ax.set_ylabel(f"{c} [{UNITS[c]}]")
    for ax in axes[-1]:
        ax.set_xlabel("t [s]")
    for ax in axes.ravel():
        ax.grid(alpha=0.3)
    title = "simulated drive: " + ", ".join(f"{n}={v:.3g}" for n, v in zip(PARAM_NAMES, theta))
    if effects:
        title += "\neffects: " + ", ".join(effects)
    fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110, format="png")
    plt.close(fig)
