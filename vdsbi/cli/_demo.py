"""`vdsbi demo`: simulate a drive with a concealed effect, identify it (flagged), diagnose it,
identify again with the named effect, and a before/after page."""

from __future__ import annotations

import argparse
import sys

from .. import api


def add_parser(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        "demo",
        help="the whole loop on a drive with a hidden effect: identify, diagnose, re-identify (start here)",
        description="Build a recording of the built-in vehicle at the seed's true parameters with a "
        "concealed sensor bias; `identify` it with the base model (the posterior is flagged); "
        "`diagnose` it (names the effect); `identify` again with the named effect; and write a "
        "before/after page (report.html) with everything else to a folder named at the end.",
    )
    p.add_argument("--out", metavar="DIR", help="output folder (default: vdsbi-demo-<time>)")
    p.add_argument(
        "--quick",
        action="store_true",
        help="10 s drive, 2 x 300 simulations per identify, no diagnosis plots",
    )
    p.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    p.add_argument("--no-diagnose", action="store_true", help="skip the diagnosis and the second identify")
    p.add_argument("--quiet", action="store_true", help="only the final lines")
    return p


def run(args) -> int:
    res = api.demo(
        args.out,
        quick=args.quick,
        seed=args.seed,
        run_diagnosis=not args.no_diagnose,
        progress=not args.quiet and sys.stderr.isatty(),
        log=None if args.quiet else (lambda s: print(s, flush=True)),
    )
    if not args.quiet:
        print(f"diagnosis: {res.diagnosis}", flush=True)
    print(f"demo finished in {res.seconds:.0f} s; results in {res.out}; open {res.out / 'report.html'}")
    return 0
