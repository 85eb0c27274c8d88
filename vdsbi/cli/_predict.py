"""`vdsbi predict DIR --inputs REC --out PRED.csv [--band]`: another drive at an identify run's estimate."""

from __future__ import annotations

import argparse
from pathlib import Path

from .. import api
from ..io import InputError, write_atomically
from ..problem.validation import ENVELOPE_UNITS

#: How the warnings name the envelope's quantities.
LABELS = {"ay": "|a_y|", "speed": "speed", "steer_rate": "|steer rate|", "ax": "|a_x|"}


def add_parser(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        "predict",
        help="simulate another recording at an identify run's estimate (and its 90 %% band)",
        description="Simulate REC's usable driving window by window, each from its own measured "
        "state, at DIR's estimate with DIR's effects, as identify scores its held-out part; write "
        "the measured and predicted channels (and with --band the 90 % posterior-predictive band, "
        "model error included) and print the NRMSE per channel. A window that goes beyond the "
        "driving DIR was fitted on (peak |a_y|, speed, |steer rate|, |a_x|) is warned about and "
        "marked in the beyond_envelope column; where it uses the tyres' grip, its band draws the "
        "friction factors from their prior.",
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
    for line in extrapolation_lines(res.extrapolation, args.run_dir):
        print(line)
    print(f"wrote {args.out}")
    return 0


def extrapolation_lines(flagged: list[dict] | None, run_dir: str) -> list[str]:
    """One warning per window beyond the fitted driving's envelope (a note where the run stores none)."""
    if flagged is None:
        return [f"note: {run_dir} stores no envelope of its fitted driving: extrapolation not checked"]
    lines = []
    for f in flagged:
        what = ", ".join(
            f"{LABELS[q]} {this:.3g} {ENVELOPE_UNITS[q]} (fitted up to {fit:.3g})"
            for q, (fit, this) in f["beyond"].items()
        )
        band = "; its band draws the tyres' grip from the prior" if "grip_from_prior" in f else ""
        lines.append(
            f"warning: window {f['window']} ({f['t0']:.1f}-{f['t1']:.1f} s) goes beyond the driving "
            f"{run_dir} was fitted on: {what}; the prediction extrapolates{band}"
        )
    return lines
