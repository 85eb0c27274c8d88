"""`vdsbi predict DIR --inputs REC --out PRED.csv [--band]`: another drive at an identify run's estimate."""

from __future__ import annotations

import argparse
from pathlib import Path

from .. import api
from ..io import InputError, write_atomically


def add_parser(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        "predict",
        help="simulate another recording at an identify run's estimate (and its 90 %% band)",
        description="Simulate REC's usable driving window by window, each from its own measured "
        "state, at DIR's estimate with DIR's effects, as identify scores its held-out part; write "
        "the measured and predicted channels (and with --band the 90 % posterior-predictive band, "
        "model error included) and print the NRMSE per channel.",
    )
    p.add_argument("run_dir", metavar="DIR", help="an identify output folder")
    p.add_argument("--inputs", required=True, metavar="REC", help="recording to predict")
    p.add_argument("--out", required=True, metavar="PRED.csv", help="where to write the prediction")
    p.add_argument("--band", action="store_true", help="add the 90 %% posterior-predictive band")
    p.add_argument("--seed", type=int, default=0, help="random seed of the band (default 0)")
    return p


def run(args) -> int:
    if Path(args.out).suffix.lower() != ".csv":
        raise InputError(args.out, "--out", "expected a .csv file name")
    res = api.predict(args.run_dir, args.inputs, band=args.band, seed=args.seed)
    write_atomically(args.out, lambda tmp: res.frame.to_csv(tmp, index=False, float_format="%.9g"))
    for c, s in res.scores.items():
        inside = f", {res.coverage[c]:.0%} inside the 90 % band" if c in res.coverage else ""
        print(f"{c}: NRMSE {s['nrmse']:.3f} over {s['samples']} samples{inside}")
    print(f"wrote {args.out}")
    return 0
