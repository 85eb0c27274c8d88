"""`export`: an identify folder's result in the keys other tools read (Autoware's MPC lateral
controller, plain JSON, CSV).

Units. vdsbi's `C_alpha_f`/`C_alpha_r` are per axle: the simulator's Dugoff model takes the axle
load and returns the axle's lateral force (`vdsbi/simulator/_tire.py`), both tyres together. Autoware's
`vehicle.cf`/`vehicle.cr` (and Apollo's `cf`/`cr`) are the same per-axle cornering stiffness of a
single-track model (its lateral equation divides cf + cr by the whole mass), so they are written
unconverted, in N/rad. Autoware has no l_f: its dynamics model derives
l_f = L·(1 − m_front/m) from the corner masses, so vdsbi writes mass_fl = mass_fr = m·l_r/(2L) and
mass_rl = mass_rr = m·l_f/(2L), which give back vdsbi's l_f exactly (and its I_z = m·l_f·l_r).
"""

from __future__ import annotations

import csv
import io
import json
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from ..io import InputError

EXPORT_FORMATS = ("autoware", "json", "csv")
#: What each format's file is called.
FILE_NAMES = {"autoware": "vdsbi.autoware.param.yaml", "json": "parameters.json", "csv": "parameters.csv"}


def load_run(run_dir: str | os.PathLike) -> dict[str, Any]:
    """An identify folder's posterior.json.

    Raises:
        InputError: no readable posterior.json in `run_dir`.
    """
    path = Path(run_dir) / "posterior.json"
    if not path.is_file():
        raise InputError(path, "DIR", "no posterior.json here; run `vdsbi identify` first")
    try:
        return json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as err:
        raise InputError(path, "posterior.json", f"cannot be read ({type(err).__name__})") from None


def corner_masses(mass: float, wheelbase: float, l_f: float) -> dict[str, float]:
    """Autoware's corner masses, kg: the static axle loads m·l_r/L (front) and m·l_f/L (rear),
    split evenly left/right."""
    front = mass * (wheelbase - l_f) / wheelbase
    return {
        "mass_fl": front / 2,
        "mass_fr": front / 2,
        "mass_rl": (mass - front) / 2,
        "mass_rr": (mass - front) / 2,
    }


def export(
    run_dir: str | os.PathLike, fmt: str = "autoware", vehicle: Mapping[str, Any] | None = None
) -> str:
    """The text of `run_dir`'s result in format `fmt` (estimates; intervals in comments or
    columns).

    Args:
        fmt: "autoware" (a ROS 2 parameter file for Autoware's mpc_lateral_controller with
            `vehicle_model_type: dynamics`), "json" or "csv" (every parameter with its interval).
        vehicle: mass and wheelbase (default: those posterior.json recorded).

    Raises:
        InputError: unknown format, no result in `run_dir`, l_f or a stiffness not identified
            (autoware), or no vehicle mass/wheelbase.
    """
    if fmt not in EXPORT_FORMATS:
        raise InputError(
            "settings", "--format", f"unknown format {fmt!r}; known: {', '.join(EXPORT_FORMATS)}"
        )
    post = load_run(run_dir)
    if fmt == "json":
        return json.dumps(_table(post), indent=2) + "\n"
    if fmt == "csv":
        return _csv(_table(post))
    return autoware(post, vehicle or post.get("vehicle"), Path(run_dir))


def _table(post: Mapping[str, Any]) -> dict[str, Any]:
    """Per parameter: value (identify's estimate), std, 5/95 % quantiles, unit, identified."""
    rows = {
        n: {
            "value": None if p.get("identified") is False else _value(p),
            "std": p["std"],
            "q05": p["q05"],
            "q95": p["q95"],
            "unit": p["unit"],
            "identified": p.get("identified", True),
        }
        for n, p in post["parameters"].items()
    }
    return {"recording": post["recording"], "effects": post.get("effects", []), "parameters": rows}


def _csv(table: Mapping[str, Any]) -> str:
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    keys = ("value", "std", "q05", "q95")
    w.writerow(["parameter", *keys, "unit", "identified"])
    for n, r in table["parameters"].items():
        w.writerow([n, *("" if r[k] is None else f"{r[k]:.6g}" for k in keys), r["unit"], r["identified"]])
    return buf.getvalue()


def autoware(post: Mapping[str, Any], vehicle: Mapping[str, Any] | None, run_dir: Path) -> str:
    """A ROS 2 parameter file (YAML) with `vehicle.cf`, `vehicle.cr` and `vehicle.mass_fl/_fr/_rl/_rr`
    as Autoware's mpc_lateral_controller reads them with `vehicle_model_type: dynamics`."""
    params = post["parameters"]
    missing = [n for n in ("l_f", "C_alpha_f", "C_alpha_r") if params[n].get("identified") is False]
    if missing:
        raise InputError(
            run_dir / "posterior.json", missing[0], "not identified by this drive: nothing to export"
        )
    if not vehicle or not {"mass", "wheelbase"} <= set(vehicle):
        raise InputError(run_dir / "posterior.json", "vehicle", "no mass/wheelbase recorded; pass --vehicle")
    m, L = float(vehicle["mass"]), float(vehicle["wheelbase"])
    lf = params["l_f"]
    masses = corner_masses(m, L, _value(lf))
    lo, hi = corner_masses(m, L, lf["q95"]), corner_masses(m, L, lf["q05"])  # front mass falls as l_f grows
    caf, car = params["C_alpha_f"], params["C_alpha_r"]
    effects = ", ".join(post.get("effects", [])) or "none"
    front, rear = f"{masses['mass_fl']:.1f}", f"{masses['mass_rl']:.1f}"
    head = [
        f"# Identified by vdsbi {post.get('vdsbi_version', '?')} from {post['recording']}",
        f"# (identify folder {run_dir}; effects in the model: {effects}).",
        "# Estimates (the best fit of the drive); 90 % posterior intervals [q05, q95]:",
        f"#   vehicle.cf = C_alpha_f {_interval(caf, '.1f')} N/rad (front axle, both tyres: no conversion)",
        f"#   vehicle.cr = C_alpha_r {_interval(car, '.1f')} N/rad (rear axle)",
        f"#   l_f = {_interval(lf, '.4f')} m (CoG to front axle; wheelbase {L:g} m, mass {m:g} kg)",
        f"#   mass_fl = mass_fr = m*l_r/(2L) = {front} kg [{lo['mass_fl']:.1f}, {hi['mass_fl']:.1f}]",
        f"#   mass_rl = mass_rr = m*l_f/(2L) = {rear} kg [{hi['mass_rl']:.1f}, {lo['mass_rl']:.1f}]",
        "#   (Autoware derives l_f = L*(1 - (mass_fl + mass_fr)/m) from these: the value above.)",
    ]
    head += _steering_notes(params)
    head += [f"# WARNING: {w['message']}" for w in post.get("warnings", [])]
    body = [
        "/**:",
        "  ros__parameters:",
        '    vehicle_model_type: "dynamics"',
        "    vehicle:",
        *(f"      {k}: {v:.3f}" for k, v in masses.items()),
        f"      cf: {_value(caf):.3f}",
        f"      cr: {_value(car):.3f}",
    ]
    return "\n".join(head + body) + "\n"


def _steering_notes(params: Mapping[str, Any]) -> list[str]:
    """Comments for what the run found about the steer signal and Autoware has no key for: its
    `input_delay` is the command → actuator delay and its steering offset is estimated online, so
    neither is the logged-steer → response delay or offset vdsbi measures."""
    notes = []
    if "signal_delay.delay" in params:
        d = params["signal_delay.delay"]
        notes += [
            f"#   logged steer -> response delay = {_interval(d, '.3f')} s (signal_delay): if the",
            "#   logged steer is the commanded angle, this is Autoware's input_delay.",
        ]
    if "steer_offset.offset" in params:
        o = params["steer_offset.offset"]
        notes += [
            f"#   steer zero offset = {_interval(o, '.5f')} rad (acting = logged + offset; Autoware",
            "#   removes an offset online: steering_offset.enable_auto_steering_offset_removal).",
        ]
    return notes


def _value(p: Mapping[str, Any]) -> float:
    """The exported value of a parameter: identify's estimate."""
    return float(p["estimate"])


def _interval(p: Mapping[str, Any], f: str) -> str:
    return f"{_value(p):{f}} [{p['q05']:{f}}, {p['q95']:{f}}]"
