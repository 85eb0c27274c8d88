"""`vdsbi observability`: Fisher information and Cramér–Rao bounds of a maneuver."""

from __future__ import annotations

import argparse

from .. import api
from ..io import InputError, output_dir, read_recording
from ..simulator import SEED_TRUE_THETA, seed_profile
from ..simulator.effects import EffectSettings
from . import _args


def add_parser(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        "observability",
        help="Fisher information, Cramér-Rao bounds and weakest direction of a maneuver",
        description="Compute the Fisher information of the parameters (and of enabled effects' "
        "parameters) for a maneuver, by forward-mode autodiff through the noise-free simulator in "
        "float64, and write DIR/fisher.json and DIR/fisher.md.",
    )
    p.add_argument("--vehicle", required=True, metavar="V.json", help="vehicle constants (.json or .yaml)")
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("--inputs", metavar="REC", help="take the maneuver (inputs) from this recording")
    src.add_argument("--profile", choices=["seed"], help="built-in maneuver")
    p.add_argument("--duration", type=float, default=5.0, help="--profile only: length, s (default 5)")
    p.add_argument(
        "--theta",
        metavar="JSON",
        help="parameter values {name: value} (JSON text or file); default: the seed's Table II truth",
    )
    p.add_argument(
        "--v0", type=float, metavar="M_PER_S", help="initial speed (default: 10.5, or the recording's)"
    )
    p.add_argument(
        "--noise",
        choices=["seed", "vehicle"],
        default="seed",
        help="seed: 10 %%/5 %% relative noise (floored at zero crossings); vehicle: additive noise_std "
        "of the vehicle file (channels without one are left out)",
    )
    p.add_argument(
        "--channels",
        nargs="+",
        metavar="CH",
        help="measured channels (default: the seed's five, or those present in the recording)",
    )
    p.add_argument(
        "--effects",
        nargs="+",
        default=[],
        metavar="EFFECT",
        help="enable effects; their parameters join the Fisher matrix",
    )
    p.add_argument("--effect-params", metavar="JSON", help="{effect: {param: value}} (JSON text or file)")
    p.add_argument("--out", required=True, metavar="DIR", help="output directory")
    p.add_argument("--overwrite", action="store_true", help="replace DIR if it exists")
    return p


def run(args) -> int:
    theta = _args.theta(args.theta, SEED_TRUE_THETA)
    effects = _args.effect_names(args.effects)
    params = _args.effects(args.effect_params, "--effect-params")[1] if args.effect_params else {}
    if args.inputs:
        maneuver, label = read_recording(args.inputs), str(args.inputs)
    else:
        if not args.duration > 0:
            raise InputError("--duration", "value", f"must be > 0, got {args.duration}")
        maneuver, label = seed_profile(duration=args.duration), f"seed profile, {args.duration:g} s"
    res = api.observability(
        args.vehicle,
        maneuver,
        theta=theta,
        v0=args.v0,
        channels=args.channels,
        noise=args.noise,
        effects=EffectSettings(enabled=effects, params=params),
        label=label,
    )
    with output_dir(args.out, overwrite=args.overwrite) as d:
        res.save(d)
    print(res.markdown())
    print(f"wrote {args.out}/fisher.json, fisher.md")
    return 0
