"""`vdsbi design`: a maneuver optimised to make a parameter (or all of them) observable."""

from __future__ import annotations

import argparse

from .. import api
from ..io import InputError, output_dir
from ..simulator import PARAM_NAMES, SEED_TRUE_THETA
from . import _args


def add_parser(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        "design",
        help="design a test maneuver that maximises Fisher information within driving limits",
        description="Gradient ascent through the simulator on the maneuver's parameters (steer sines, "
        "pedal levels and timing, initial speed) to minimise the Cramér-Rao bound of --target (or "
        "maximise log det F with --target D), within |ay| <= 0.6·μ·g, steer/torque limits and a speed "
        "window. Writes DIR/maneuver.csv (recording format: inputs plus the noise-free simulated "
        "channels), DIR/bounds.json and DIR/bounds.md (bounds of the seed's maneuver and of the designed "
        "one) and DIR/design.json (parameters, limits, optimiser history).",
    )
    p.add_argument("--vehicle", required=True, metavar="V.json", help="vehicle constants (.json or .yaml)")
    p.add_argument(
        "--target",
        default="C_kappa_r",
        choices=[*PARAM_NAMES, "D"],
        help="parameter whose bound to minimise, or D for D-optimal (default C_kappa_r)",
    )
    p.add_argument("--theta", metavar="JSON", help="parameter values (default: the seed's Table II truth)")
    p.add_argument("--noise", choices=["seed", "vehicle"], default="seed", help="sensor-noise model")
    p.add_argument("--steps", type=int, default=150, help="optimiser steps (default 150)")
    p.add_argument("--learning-rate", type=float, default=0.05, help="Adam step size (default 0.05)")
    p.add_argument("--duration", type=float, default=5.0, help="maneuver length, s (default 5, as the seed)")
    p.add_argument("--max-steer", type=float, default=0.1, help="|steer| limit, rad (default 0.1)")
    p.add_argument(
        "--max-drive", type=float, default=900.0, help="front drive torque limit, N·m (default 900)"
    )
    p.add_argument(
        "--max-brake", type=float, default=1800.0, help="total brake torque limit, N·m (default 1800)"
    )
    p.add_argument("--brake-front-share", type=float, default=0.65, help="brake balance (default 0.65)")
    p.add_argument(
        "--speed-window",
        type=float,
        nargs=2,
        default=[5.0, 20.0],
        metavar=("LOW", "HIGH"),
        help="vx window, m/s (default 5 20)",
    )
    p.add_argument("--out", required=True, metavar="DIR", help="output directory")
    p.add_argument("--overwrite", action="store_true", help="replace DIR if it exists")
    return p


def run(args) -> int:
    res = api.design(
        args.vehicle,
        target=args.target,
        theta=_args.theta(args.theta, SEED_TRUE_THETA),
        noise=args.noise,
        steps=args.steps,
        learning_rate=args.learning_rate,
        limits=_limits(args),
        log=lambda s: print(s, flush=True),
    )
    with output_dir(args.out, overwrite=args.overwrite) as d:
        res.save(d)
    print(res.markdown())
    print(f"wrote {args.out}/maneuver.csv, bounds.json, bounds.md, design.json")
    return 0


def _limits(args):
    """The limits the options give: the speed window bounds the speed throughout and at the start."""
    from ..diagnostics import Limits

    lo, hi = args.speed_window
    try:
        return Limits(
            duration=args.duration,
            max_steer=args.max_steer,
            max_drive=args.max_drive,
            max_brake=args.max_brake,
            brake_front_share=args.brake_front_share,
            v_min=lo,
            v_max=hi,
            v0_min=lo,
            v0_max=hi,
        )
    except ValueError as err:
        raise InputError("arguments", "value", str(err)) from None
