"""`vdsbi observability`: Fisher information and Cramér–Rao bounds of a maneuver."""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path


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


def _json_arg(text: str, field: str):
    from ..io import InputError

    path = Path(text)
    try:
        if path.suffix.lower() == ".json" and path.exists():
            return json.loads(path.read_text())
        return json.loads(text)
    except (OSError, json.JSONDecodeError) as err:
        raise InputError(text, field, f"not valid JSON ({err})") from None


def _theta(args):
    from ..io import InputError
    from ..simulator import PARAM_NAMES, SEED_TRUE_THETA

    values = dict(SEED_TRUE_THETA)
    if args.theta:
        given = _json_arg(args.theta, "--theta")
        if not isinstance(given, dict):
            raise InputError(args.theta, "--theta", "expected a JSON object {name: value}")
        for k, v in given.items():
            if k not in PARAM_NAMES:
                raise InputError(
                    args.theta, "--theta", f"unknown parameter '{k}' (expected {list(PARAM_NAMES)})"
                )
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                raise InputError(args.theta, "--theta", f"'{k}' must be a finite number, got {v!r}")
            values[k] = float(v)
    return [values[n] for n in PARAM_NAMES]


def run(args) -> int:
    import jax

    from ..io import InputError, read_recording, read_vehicle
    from ..simulator import CHANNELS, SEED_CHANNELS, check_theta, effect_params_from, make_model, seed_profile
    from ._output import output_dir

    vehicle = read_vehicle(args.vehicle)
    if args.inputs:
        rec = read_recording(args.inputs)
        inputs = rec.inputs()
        channels = list(args.channels or [c for c in rec.channel_names])
        v0 = args.v0
        if v0 is None:
            speed = rec.speed(vehicle.wheel_radius)
            if speed is None:
                raise InputError(args.inputs, "--v0", "recording has no vx or wheel speeds; give --v0")
            v0 = float(speed[0])
        maneuver = str(args.inputs)
    else:
        if not args.duration > 0:
            raise InputError("--duration", "value", f"must be > 0, got {args.duration}")
        inputs = seed_profile(duration=args.duration)
        channels = list(args.channels or SEED_CHANNELS)
        v0 = 10.5 if args.v0 is None else args.v0
        maneuver = f"seed profile, {args.duration:g} s"
    bad = [c for c in channels if c not in CHANNELS]
    if bad:
        raise InputError(
            "--channels", "value", f"unknown channel(s) {bad} (expected some of {list(CHANNELS)})"
        )
    if not (math.isfinite(v0) and v0 > 0):
        raise InputError("--v0", "value", f"initial speed must be > 0 m/s, got {v0}")
    dropped = []
    if args.noise == "vehicle":
        dropped = [c for c in channels if not vehicle.noise_std.get(c, 0.0) > 0]
        channels = [c for c in channels if c not in dropped]
        if not channels:
            raise InputError(
                args.vehicle,
                "noise_std",
                f"--noise vehicle needs a positive noise_std for at least one measured channel of {dropped}",
            )
    theta = _theta(args)
    try:
        check_theta(theta, vehicle)
        model = make_model(vehicle, args.effects)
        ep_values = _json_arg(args.effect_params, "--effect-params") if args.effect_params else None
        _, eparams = effect_params_from(args.effects, ep_values)
    except ValueError as err:
        if isinstance(err, InputError):
            raise
        raise InputError("arguments", "value", str(err)) from None

    from ..diagnostics import fisher_report, model_fisher, report_markdown

    with jax.enable_x64(True):
        import jax.numpy as jnp

        fisher = model_fisher(
            model,
            jnp.asarray(theta, dtype=float),
            inputs,
            v0,
            tuple(jnp.asarray(p, dtype=float) for p in eparams),
            channels=channels,
            noise=args.noise,
            noise_std=vehicle.noise_std,
        )
        rep = fisher_report(fisher)
    rep["maneuver"] = maneuver
    rep["v0"] = v0
    rep["noise"] = args.noise
    rep["channels_without_noise_std"] = dropped
    rep["effects"] = list(args.effects)
    md = report_markdown(rep, title=f"Observability: {maneuver}, v0 = {v0:.3g} m/s, {args.noise} noise")
    with output_dir(args.out, overwrite=args.overwrite) as d:
        (d / "fisher.json").write_text(json.dumps(rep, indent=2, allow_nan=True) + "\n")
        (d / "fisher.md").write_text(md)
    print(md)
    print(f"wrote {args.out}/fisher.json, fisher.md")
    return 0
