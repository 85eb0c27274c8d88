"""`vdsbi export DIR --format autoware|json|csv`: an identify result in the keys other tools read."""

from __future__ import annotations

import argparse
import sys

from .. import api


def add_parser(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        "export",
        help="write an identify result for other tools (Autoware MPC parameters, JSON, CSV)",
        description="Read DIR/posterior.json (an identify folder) and write the estimates with "
        "their 90 % intervals: --format autoware writes a ROS 2 parameter file with vehicle.cf, "
        "vehicle.cr and vehicle.mass_fl/_fr/_rl/_rr as Autoware's mpc_lateral_controller reads them "
        "(vehicle_model_type: dynamics; cf/cr per axle, N/rad, as vdsbi's C_alpha_f/C_alpha_r), "
        "the intervals and the recording in a comment block; json and csv list every parameter.",
    )
    p.add_argument("run_dir", metavar="DIR", help="an identify output folder")
    formats = api.outputs.EXPORT_FORMATS
    p.add_argument("--format", choices=formats, default="autoware", help="default autoware")
    p.add_argument(
        "--out", metavar="FILE", default=None, help="where to write ('-': standard output; default: in DIR)"
    )
    p.add_argument(
        "--vehicle",
        metavar="V",
        default=None,
        help="vehicle file for mass and wheelbase (default: those posterior.json recorded)",
    )
    return p


def run(args) -> int:
    vehicle = None
    if args.vehicle is not None:
        from ..io import read_vehicle

        vehicle = read_vehicle(args.vehicle).to_dict()
    if args.out == "-":
        sys.stdout.write(api.export(args.run_dir, args.format, vehicle=vehicle))
        return 0
    path = api.outputs.write_export(args.run_dir, args.format, args.out, vehicle=vehicle)
    print(f"wrote {path}")
    return 0
