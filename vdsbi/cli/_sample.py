"""`vdsbi sample DIR --n K`: draw from a saved estimator (any process, any time)."""

from __future__ import annotations

import argparse
import sys

from .. import api


def add_parser(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        "sample",
        help="draw K posterior samples from the estimator `identify` saved in DIR",
        description="Reload DIR/estimator.npz and print (or write) K samples as CSV.",
    )
    p.add_argument("dir", metavar="DIR", help="an `identify` output directory")
    p.add_argument("--n", type=int, required=True, metavar="K", help="number of samples")
    p.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    p.add_argument("--out", metavar="CSV", help="write here instead of stdout")
    return p


def run(args) -> int:
    df = api.sample(args.dir, args.n, seed=args.seed)
    df.to_csv(args.out or sys.stdout, index=False, float_format="%.9g")
    return 0
