"""`vdsbi simulate`: drive the simulator with a recording's inputs or a built-in profile and
write the result as a recording in the contract format."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from .. import api
from ..io import InputError, read_recording, write_atomically
from ..simulator import NOMINAL_THETA, PARAM_NAMES, SEED_TRUE_THETA
from ..simulator.effects import EffectSettings
from . import _args

PROFILES = ("seed",)


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
    _args.add_longitudinal(p)
    return p


def run(args) -> int:
    out = Path(args.out)
    if out.suffix.lower() != ".csv":
        raise InputError(args.out, "--out", "expected a .csv file name")
    if out.is_dir():
        raise InputError(args.out, "--out", "is a directory; expected a .csv file name")
    if args.plot and Path(args.plot).suffix.lower() != ".png":
        raise InputError(args.plot, "--plot", "expected a .png file name")
    rec = read_recording(args.inputs) if args.inputs else None
    theta = _args.theta(args.theta, NOMINAL_THETA if rec is not None else SEED_TRUE_THETA)
    effects, effect_params = _args.effects(args.effects)
    res = api.simulate(
        theta,
        rec,
        args.vehicle,
        v0=args.v0,
        effects=EffectSettings(enabled=effects, params=effect_params),
        noise=args.noise,
        seed=args.seed,
        longitudinal=args.longitudinal,
    )
    if not res.ok:
        print(
            "vdsbi: error: the simulation left the model's domain (non-finite state or reversing "
            "wheels); check --theta, --effects and the inputs",
            file=sys.stderr,
        )
        return 1
    result = res.to_recording(str(out))
    write_atomically(out, result.to_csv)
    src = f"inputs of {args.inputs}" if args.inputs else f"profile '{args.profile}'"
    print(f"wrote {out}: {result.num_samples} samples, {result.duration:.2f} s, {src}, v0 {res.v0:.2f} m/s")
    print("  theta   " + ", ".join(f"{n} {v:.4g}" for n, v in zip(PARAM_NAMES, res.theta)))
    if effects:
        print("  effects " + "; ".join(f"{e} {effect_params[e] or '(null)'}" for e in effects))
    print(f"  noise   {args.noise}" + (f" (seed {args.seed})" if args.noise != "none" else ""))
    if args.plot:
        write_atomically(args.plot, lambda p: api.plots.drive_plot(result, res.theta, effects, p))
        print(f"wrote {args.plot}")
    return 0
