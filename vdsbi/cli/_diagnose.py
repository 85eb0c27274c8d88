"""`vdsbi diagnose REC --vehicle V --out DIR`: find, name and fix model mismatch."""

from __future__ import annotations

import argparse

from .. import api
from ..discovery import effect_names
from ..io import load_drive, output_dir
from . import _args


def add_parser(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        "diagnose",
        help="locate where a recording and the model disagree, name the missing physics, fix it",
        description="Identify θ with the base model, test it for misspecification (calibrated "
        "p-value), locate the mismatch (channels, time windows, bands), rank the simulator's "
        "effects by evidence, adding them one at a time while it supports them, re-identify with "
        "the chosen effect(s) and compare the fit before/after on a held-out part of the "
        "recording. Writes report.json, report.md and figures to DIR.",
    )
    p.add_argument(
        "recording",
        metavar="REC",
        nargs="+",
        help="recording: .csv, .parquet or ROS2 bag; several drives of one car are diagnosed together",
    )
    p.add_argument("--vehicle", required=True, metavar="V", help="vehicle constants (.json or .yaml)")
    p.add_argument("--out", required=True, metavar="DIR", help="output directory (new or empty)")
    p.add_argument("--overwrite", action="store_true", help="replace DIR if it exists")
    p.add_argument("--alpha", type=float, default=0.05, help="level of the misspecification test")
    p.add_argument("--seed", type=int, default=0, help="seed of the test's simulated null")
    p.add_argument(
        "--max-effects", type=int, default=3, help="most effects the forward search adds (default 3)"
    )
    p.add_argument(
        "--max-terms",
        type=int,
        default=3,
        help="most candidate terms written for what the library leaves (default 3; 0: none)",
    )
    p.add_argument("--effects", default=None, help="comma-separated effects to consider (default all)")
    p.add_argument(
        "--max-windows", type=int, default=None, help="most windows fitted (default: the whole drive)"
    )
    p.add_argument(
        "--max-window",
        type=float,
        default=None,
        help="longest window, s (default 20 with torques, 10 following the speed)",
    )
    _args.add_longitudinal(p)
    p.add_argument(
        "--final-dt",
        type=float,
        default=0.0025,
        help="RK4 step, s, of the base/final fits and the test (default 0.0025; the search uses 0.005)",
    )
    p.add_argument("--no-plots", action="store_true", help="skip the figures")
    p.add_argument("--quiet", action="store_true", help="no progress lines")
    return p


def run(args) -> int:
    candidates = (
        None if args.effects is None else _args.effect_names(args.effects.split(","), known=effect_names())
    )
    drives = [load_drive(r, args.vehicle) for r in args.recording]
    rec, vehicle = [r for r, _ in drives], drives[0][1]
    rec = rec if len(rec) > 1 else rec[0]
    with output_dir(args.out, overwrite=args.overwrite) as d:
        res = api.diagnose(
            rec,
            vehicle,
            d,
            seed=args.seed,
            alpha=args.alpha,
            max_effects=args.max_effects,
            max_terms=args.max_terms,
            candidates=candidates,
            max_windows=args.max_windows,
            longitudinal=args.longitudinal,
            **({} if args.max_window is None else {"max_window": args.max_window}),
            final_dt=args.final_dt,
            quiet=args.quiet,
            plots=not args.no_plots,
            names=(args.recording if len(args.recording) > 1 else args.recording[0], args.vehicle, args.out),
        )
    rep = res.report
    if not args.quiet:
        det = "detected" if rep["mismatch_detected"] else "not detected"
        print(f"mismatch {det} (p = {rep['p_value']:.3g}); chosen: {', '.join(rep['chosen']) or 'none'}")
        print(f"verdict: {rep['verdict']}")
        for ch, b in rep["fit"]["before"].items():
            a = rep["fit"]["after"][ch]
            print(f"  {ch:12s} held-out χ²/dof {b['chi2_dof']:8.3f} -> {a['chi2_dof']:8.3f}")
        print(f"wrote {args.out}/report.json, report.md, report.html")
        if rep["identify_command"]:
            print("next, the posterior with what was named modelled:")
    if rep["identify_command"]:
        print(rep["identify_command"])
    elif rep.get("not_claimed"):
        print(rep["not_claimed"])
    return 0
