"""`vdsbi identify REC --vehicle V --out DIR`: posterior over the vehicle's parameters."""

from __future__ import annotations

import argparse
import sys

from .. import api
from ..io import InputError
from . import _args


def add_parser(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        "identify",
        help="identify the vehicle's parameters from a recording (posterior with uncertainty)",
        description="Pick the usable driving of REC, train a neural posterior (APT), fit the likelihood "
        "posterior from it (best fit through the simulator, model error in the noise model), validate "
        "on the held-out part, refit on all of it, and write posterior.json, samples.csv, plots and "
        "the estimator into DIR. "
        "Each finished round is checkpointed in DIR; --resume continues an interrupted run.",
    )
    _add_files(p)
    _add_training(p)
    _add_driving(p)
    _add_parameters(p)
    _add_validation(p)
    return p


def _add_files(p: argparse.ArgumentParser) -> None:
    """The recordings, the vehicle, and where the results go."""
    p.add_argument(
        "recording",
        metavar="REC",
        nargs="+",
        help="recording: .csv, .parquet or ROS2 bag; several recordings of one car are identified jointly",
    )
    p.add_argument("--vehicle", required=True, metavar="V", help="vehicle constants (.json or .yaml)")
    p.add_argument("--out", required=True, metavar="DIR", help="output directory")


def _add_training(p: argparse.ArgumentParser) -> None:
    """The neural posterior's rounds, simulations and training, and the run itself."""
    p.add_argument("--rounds", type=int, default=2, help="APT rounds (default 2)")
    p.add_argument("--sims", type=int, default=1000, help="simulations per round (default 1000)")
    p.add_argument("--embedding", choices=("cnn", "stats"), default="stats", help="default stats")
    p.add_argument("--epochs", type=int, default=None, help="max epochs per round (default 30 stats, 20 cnn)")
    p.add_argument("--samples", type=int, default=1000, help="posterior samples written (default 1000)")
    p.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    p.add_argument("--resume", action="store_true", help="continue from DIR's checkpoint")
    p.add_argument("--quiet", action="store_true", help="no progress bars or messages")


def _add_driving(p: argparse.ArgumentParser) -> None:
    """Which driving is used and how it is compared with the simulations."""
    p.add_argument("--segment", type=_args.segment, metavar="T0:T1", help="use this stretch, s")
    p.add_argument(
        "--max-duration",
        type=float,
        default=None,
        help="longest window, s (default 20 with torques, 10 following the speed)",
    )
    _args.add_longitudinal(p)
    p.add_argument(
        "--bandwidth",
        type=float,
        default=None,
        metavar="HZ",
        help="low-pass both the recording and the simulations at HZ before comparing (default: none "
        "with torques, 5 Hz following the speed: real IMUs carry vibration above the body dynamics)",
    )


def _add_parameters(p: argparse.ArgumentParser) -> None:
    """The parameters identified (effects joining θ), reference values and prior ranges."""
    p.add_argument(
        "--effects",
        default=None,
        metavar="NAME[,NAME...]",
        help="effects whose parameters join θ (default: tyre_friction when the drive uses more "
        "than half the grip, yaw_inertia and signal_delay when following the speed with a yaw rate); "
        "'+NAME,...' adds to the defaults, 'none' for none",
    )
    p.add_argument(
        "--compare",
        default=None,
        metavar="VALUES.json",
        help="reference values {param: value} (e.g. a lab's) scored on the held-out driving too",
    )
    p.add_argument(
        "--prior",
        action="append",
        default=[],
        metavar="NAME=LO:HI",
        help="uniform prior range of one parameter (e.g. signal_delay.delay=0.1:0.3, as `vdsbi diagnose` "
        "prints it); repeatable",
    )


def _add_validation(p: argparse.ArgumentParser) -> None:
    """The held-out share validated on, and the model rate the fits simulate at."""
    p.add_argument(
        "--holdout",
        type=float,
        default=0.3,
        metavar="FRACTION",
        help="share of the usable driving held out to validate on (default 0.3; 0: none). The "
        "estimate is always refit on all of it",
    )
    p.add_argument("--rate", type=float, default=200.0, help="model rate, Hz (default 200)")


def run(args) -> int:
    from ..inference import OBSERVATIONS

    quiet = args.quiet
    effects, add_effects = _effects(args.effects)
    options = api.IdentifyOptions(
        drive=api.DriveOptions(
            segment=args.segment,
            max_duration=args.max_duration,
            longitudinal=args.longitudinal,
            bandwidth="auto" if args.bandwidth is None else args.bandwidth,
            holdout=args.holdout,
            rate=args.rate,
        ),
        model=api.ModelOptions(effects=effects, add_effects=add_effects, priors=_priors(args.prior) or {}),
        budget=api.Budget(
            rounds=args.rounds,
            sims=args.sims,
            epochs=args.epochs,
            embedding=OBSERVATIONS[args.embedding],
            num_samples=args.samples,
        ),
        seed=args.seed,
        compare=_compare(args.compare),
    )
    progress = None if quiet else api.Progress(say=lambda s: print(s, flush=True), bars=sys.stderr.isatty())
    res = api.identify(
        args.recording if len(args.recording) > 1 else args.recording[0],
        args.vehicle,
        options,
        out_dir=args.out,
        resume=args.resume,
        progress=progress,
    )
    if quiet:
        for w in res.summary["warnings"]:
            print(f"vdsbi: warning: {w['message']}", file=sys.stderr)
    else:
        print(res.table())
        print(
            f"wrote {args.out}/posterior.json, samples.csv, {api.outputs.PREDICTIVE}, pairplot.png, ppc.png, "
            f"{api.outputs.ESTIMATOR}"
        )
    return 0


def _effects(text: str | None) -> tuple[list[str] | None, list[str]]:
    """(effects, added effects): "a,b" replaces the defaults, "+a,b" adds to them, "none" is none."""
    if text is None:
        return None, []
    text = text.strip()
    if text == "none":
        return [], []
    if text.startswith("+"):
        return None, _args.effect_names(text[1:].split(","))
    return _args.effect_names(text.split(",")), []


def _priors(items: list[str]) -> dict[str, tuple[float, float]] | None:
    out = {}
    for item in items:
        name, _, rng = item.partition("=")
        lo, sep, hi = rng.partition(":")
        if not name or not sep:
            raise InputError("--prior", item, "expected NAME=LO:HI")
        name = name.strip()
        out[name] = (_args.number_text(lo, "--prior", name), _args.number_text(hi, "--prior", name))
    return out or None


def _compare(text: str | None) -> dict[str, float] | None:
    if text is None:
        return None
    return {
        str(k): _args.number(v, "--compare", str(k)) for k, v in _args.json_object(text, "--compare").items()
    }
