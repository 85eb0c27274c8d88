"""`vdsbi fleet MANIFEST --out DIR`: every drive of a fleet, on a local or an existing Dask cluster."""

from __future__ import annotations

import argparse
import dataclasses
import sys

from ..io import InputError


def add_parser(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        "fleet",
        help="answer every drive of a fleet (one amortized estimator per platform, checked, escalated)",
        description="Read MANIFEST (CSV: car, recording, vehicle, time; paths relative to it), train one "
        "amortized estimator per vehicle platform on windows simulated with the fleet's own recorded inputs "
        "(once; reused by later runs into DIR), answer each drive with it, check each answer against the "
        "likelihood by Pareto-smoothed importance sampling, escalate a failing drive to a likelihood fit "
        "and then to the full identify, and follow each car's parameters over time. Writes "
        "DIR/estimates.csv as drives finish, then changes.csv, the diagnosis of each platform's pooled "
        "drives (misfit.json) and report.html. A re-run skips the drives already answered; a killed "
        "worker's drive is retried.",
    )
    p.add_argument("manifest", metavar="MANIFEST", help="CSV with columns car, recording, vehicle, time")
    p.add_argument(
        "--out", required=True, metavar="DIR", help="output directory (re-use it to skip what is done)"
    )
    p.add_argument("--address", default=None, help="an existing Dask scheduler (default: a local cluster)")
    p.add_argument("--workers", type=int, default=None, help="local worker processes (default: one per core)")
    p.add_argument(
        "--sims",
        type=int,
        default=None,
        help="windows simulated to train each platform's estimator (default 20000)",
    )
    p.add_argument(
        "--epochs", type=int, default=None, help="max training epochs of the estimator (default 100)"
    )
    p.add_argument(
        "--identify-rounds", type=int, default=2, help="identify's rounds for escalated drives (default 2)"
    )
    p.add_argument(
        "--identify-sims", type=int, default=1000, help="identify's simulations per round (default 1000)"
    )
    p.add_argument("--retrain", action="store_true", help="train the platforms' estimators again")
    p.add_argument(
        "--no-diagnose",
        action="store_true",
        help="skip diagnosing the pooled drives of each platform (and of a car whose misfit stands out)",
    )
    p.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    p.add_argument("--quiet", action="store_true", help="no progress lines")
    return p


def _settings(args):
    from ..fleet import AmortizedSettings, Escalation, FleetSettings, MisfitSettings

    amortized = AmortizedSettings()
    try:
        if args.sims is not None:
            amortized = dataclasses.replace(amortized, simulations=args.sims)
        if args.epochs is not None:
            training = dataclasses.replace(amortized.training, max_epochs=args.epochs)
            amortized = dataclasses.replace(amortized, training=training)
        escalation = Escalation(rounds=args.identify_rounds, sims=args.identify_sims)
    except ValueError as err:
        raise InputError("settings", "--sims/--epochs", str(err)) from None
    return FleetSettings(
        amortized=amortized,
        escalation=escalation,
        misfit=None if args.no_diagnose else MisfitSettings(),
        seed=args.seed,
    )


def run(args) -> int:
    try:
        from ..fleet import Cluster, fleet
    except ImportError as err:  # the optional engine is not installed
        raise InputError(
            "settings", "fleet", f"needs the fleet extra: pip install 'vdsbi[fleet]' ({err})"
        ) from None
    from ._main import compilation_cache_dir, xla_flags

    if args.workers is not None and args.workers < 1:
        raise InputError("settings", "--workers", f"must be >= 1, got {args.workers}")
    cluster = Cluster(
        address=args.address,
        workers=args.workers,
        compilation_cache=compilation_cache_dir(),
        xla_flags=xla_flags(),
    )
    say = (lambda s: None) if args.quiet else (lambda s: print(s, file=sys.stderr, flush=True))
    result = fleet(args.manifest, args.out, _settings(args), cluster, retrain=args.retrain, log=say)
    methods = ", ".join(f"{m} {n}" for m, n in sorted(result.methods().items()))
    print(
        f"{len(result.records)} drives ({result.answered} answered now, {result.skipped} earlier): "
        f"{methods}; "
        f"{len(result.changes)} changes; {result.seconds:.0f} s"
    )
    for m in result.misfits:
        scope = f"platform {m.platform}" if m.car is None else f"car {m.car}"
        found = ", ".join(m.named) or "nothing named"
        print(f"{scope}: misfit {'detected' if m.detected else 'not detected'}; {found}")
        if m.identify_command:
            print(f"  {m.identify_command}")
    print(f"wrote {result.out / 'estimates.csv'}, changes.csv, misfit.json, report.html")
    return 0
