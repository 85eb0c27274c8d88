"""`vdsbi design`: a maneuver optimised to make a parameter (or all of them) observable."""

from __future__ import annotations

import argparse
import json
import time

import numpy as np


def add_parser(subparsers) -> argparse.ArgumentParser:
    from ..simulator import PARAM_NAMES

    p = subparsers.add_parser(
        "design",
        help="design a test maneuver that maximises Fisher information within driving limits",
        description="Gradient ascent through the simulator on the maneuver's parameters (steer sines, "
        "pedal levels and timing, initial speed) to minimise the Cramér-Rao bound of --target (or "
        "maximise log det F with --target D), within |ay| <= 0.6·μ·g, steer/torque limits and a speed "
        "window. Writes DIR/maneuver.csv (recording format: inputs plus the noise-free simulated "
        "channels), DIR/bounds.json and DIR/bounds.md (bounds of the seed's maneuver and of the designed "
        "one) and DIR/design.json (parameters, limits, optimiser history).",
    )
    p.add_argument("--vehicle", required=True, metavar="V.json", help="vehicle constants (.json or .yaml)")
    p.add_argument(
        "--target",
        default="C_kappa_r",
        choices=[*PARAM_NAMES, "D"],
        help="parameter whose bound to minimise, or D for D-optimal (default C_kappa_r)",
    )
    p.add_argument("--theta", metavar="JSON", help="parameter values (default: the seed's Table II truth)")
    p.add_argument("--noise", choices=["seed", "vehicle"], default="seed", help="sensor-noise model")
    p.add_argument("--steps", type=int, default=150, help="optimiser steps (default 150)")
    p.add_argument("--learning-rate", type=float, default=0.05, help="Adam step size (default 0.05)")
    p.add_argument("--duration", type=float, default=5.0, help="maneuver length, s (default 5, as the seed)")
    p.add_argument("--max-steer", type=float, default=0.1, help="|steer| limit, rad (default 0.1)")
    p.add_argument(
        "--max-drive", type=float, default=900.0, help="front drive torque limit, N·m (default 900)"
    )
    p.add_argument(
        "--max-brake", type=float, default=1800.0, help="total brake torque limit, N·m (default 1800)"
    )
    p.add_argument("--brake-front-share", type=float, default=0.65, help="brake balance (default 0.65)")
    p.add_argument(
        "--speed-window",
        type=float,
        nargs=2,
        default=[5.0, 20.0],
        metavar=("LOW", "HIGH"),
        help="vx window, m/s (default 5 20)",
    )
    p.add_argument("--out", required=True, metavar="DIR", help="output directory")
    p.add_argument("--overwrite", action="store_true", help="replace DIR if it exists")
    return p


def _recording(model, theta, inputs, v0):
    import jax.numpy as jnp

    from ..io import Recording
    from ..simulator import CHANNELS, solve

    ys, _ = solve(model, jnp.asarray(theta, dtype=float), inputs, jnp.asarray(v0, dtype=float))
    ys = np.asarray(ys, dtype=float)
    return Recording(
        t=np.asarray(inputs.ts, dtype=float),
        steer=np.asarray(inputs.steer, dtype=float),
        torque_front=np.asarray(inputs.torque_front, dtype=float),
        torque_rear=np.asarray(inputs.torque_rear, dtype=float),
        channels={c: ys[:, i] for i, c in enumerate(CHANNELS)},
        source="designed maneuver (noise-free simulation)",
        rate=1.0 / inputs.dt,
        original_rate=1.0 / inputs.dt,
    )


def bounds_markdown(bounds: dict) -> str:
    names = list(bounds["before"]["crb_std"])
    lines = [
        f"# Designed maneuver: target {bounds['target']}",
        "",
        f"Noise: {bounds['noise']}. Before: {bounds['before']['maneuver']}. After: designed maneuver "
        f"(v0 = {bounds['after']['v0']:.3g} m/s). Limits respected: {bounds['limits_check']['respected']}.",
        "",
        "| parameter | CRB std before | CRB std after | improvement (before/after) |",
        "|---|---|---|---|",
    ]
    for n in names:
        b, a = bounds["before"]["crb_std"][n], bounds["after"]["crb_std"][n]
        lines.append(f"| {n} | {b:.4g} | {a:.4g} | {b / a:.2f}× |")
    lines += [
        "",
        "log det F (scaled): before {:.3f}, after {:.3f}.".format(
            bounds["before"]["logdet_scaled"], bounds["after"]["logdet_scaled"]
        ),
    ]
    c = bounds["limits_check"]
    lo, hi = c["vx_range"]
    lines += [
        "",
        f"Limits: max |ay| {c['max_abs_ay']:.3f} ≤ {c['ay_limit']:.3f} m/s²; "
        f"vx {lo:.2f}..{hi:.2f} in [{c['speed_window'][0]:g}, {c['speed_window'][1]:g}] m/s; "
        f"|steer| {c['max_abs_steer']:.4f} ≤ {c['steer_limit']:g} rad; "
        f"drive {c['max_drive_torque']:.0f} ≤ {c['drive_limit']:g} N·m; "
        f"brake {c['max_brake_torque']:.0f} ≤ {c['brake_limit']:g} N·m.",
    ]
    return "\n".join(lines) + "\n"


def run(args) -> int:
    import jax

    from ..io import InputError, read_vehicle
    from ._observability import _theta
    from ._output import output_dir

    vehicle = read_vehicle(args.vehicle)
    theta = _theta(args)
    if args.steps < 0:
        raise InputError("--steps", "value", "must be >= 0")
    with jax.enable_x64(True):
        import jax.numpy as jnp

        from ..diagnostics import fisher_report, model_fisher
        from ..diagnostics._design import Limits, Maneuver, check_limits, design, design_problem
        from ..simulator import SEED_CHANNELS, check_theta, make_model, seed_profile

        try:
            check_theta(theta, vehicle)
            lo, hi = args.speed_window
            limits = Limits(
                duration=args.duration,
                max_steer=args.max_steer,
                max_drive=args.max_drive,
                max_brake=args.max_brake,
                brake_front_share=args.brake_front_share,
                v_min=lo,
                v_max=hi,
                v0_min=lo,
                v0_max=hi,
            )
        except ValueError as err:
            raise InputError("arguments", "value", str(err)) from None
        channels = list(SEED_CHANNELS)
        if args.noise == "vehicle":
            channels = [c for c in channels if vehicle.noise_std.get(c, 0.0) > 0]
            if not channels:
                raise InputError(
                    args.vehicle, "noise_std", "--noise vehicle needs a positive noise_std for a channel"
                )
        model = make_model(vehicle)
        th = jnp.asarray(theta, dtype=float)
        target = None if args.target == "D" else args.target
        problem = design_problem(
            model,
            th,
            limits,
            target=target,
            channels=channels,
            noise=args.noise,
            noise_std_map=vehicle.noise_std,
        )
        start = Maneuver.seed_like(limits)
        t0 = time.perf_counter()

        def progress(i, obj):
            if i % 10 == 0 or i == args.steps:
                print(
                    f"  step {i:4d}  objective {float(obj.value):9.4f}  penalty {float(obj.penalty):.2e}  "
                    f"[{time.perf_counter() - t0:.0f} s]",
                    flush=True,
                )

        try:
            res = design(
                problem, start, num_steps=args.steps, learning_rate=args.learning_rate, callback=progress
            )
        except ValueError as err:
            raise InputError("limits", "value", str(err)) from None
        kw = dict(channels=channels, noise=args.noise, noise_std=vehicle.noise_std)
        seed_inputs = seed_profile(duration=args.duration)
        reports = {}
        for key, inputs, v0, label in (
            ("before", seed_inputs, 10.5, f"seed profile, {args.duration:g} s, v0 = 10.5 m/s"),
            (
                "start",
                start.inputs(limits),
                float(start.initial_speed(limits)),
                "optimiser start (seed-like)",
            ),
            ("after", res.maneuver.inputs(limits), float(res.maneuver.initial_speed(limits)), "designed"),
        ):
            rep = fisher_report(model_fisher(model, th, inputs, v0, **kw))
            rep["maneuver"], rep["v0"] = label, v0
            rep["logdet_scaled"] = float(np.sum(np.log(rep["eigenvalues"])))
            reports[key] = rep
        designed = res.maneuver.inputs(limits)
        v0_design = float(res.maneuver.initial_speed(limits))
        chk = check_limits(model, th, designed, v0_design, limits)
        bounds = {
            "target": args.target,
            "noise": args.noise,
            "channels": channels,
            "before": reports["before"],
            "start": reports["start"],
            "after": reports["after"],
            "improvement": {
                n: reports["before"]["crb_std"][n] / reports["after"]["crb_std"][n]
                for n in reports["before"]["crb_std"]
            },
            "limits_check": chk,
        }
        rec = _recording(model, th, designed, v0_design)
        described = res.maneuver.describe(limits)
    info = {
        "target": args.target,
        "maneuver": described,
        "limits": {k: getattr(limits, k) for k in limits.__dataclass_fields__},
        "steps": args.steps,
        "best_step": res.best_step,
        "history": {k: v.tolist() for k, v in res.history.items()},
    }
    md = bounds_markdown(bounds)
    with output_dir(args.out, overwrite=args.overwrite) as d:
        rec.to_csv(d / "maneuver.csv")
        (d / "bounds.json").write_text(json.dumps(bounds, indent=2) + "\n")
        (d / "bounds.md").write_text(md)
        (d / "design.json").write_text(json.dumps(info, indent=2) + "\n")
    print(md)
    print(f"wrote {args.out}/maneuver.csv, bounds.json, bounds.md, design.json")
    return 0
