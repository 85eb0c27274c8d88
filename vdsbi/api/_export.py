"""`export`: an identify folder's result in the keys other tools read (Autoware's MPC lateral
controller, plain JSON, CSV).

Units. vdsbi's `C_alpha_f`/`C_alpha_r` are per axle: the simulator's Dugoff model takes the axle
load and returns the axle's lateral force (`vdsbi/simulator/_tire.py`), both tyres together. Autoware's
`vehicle.cf`/`vehicle.cr` (and Apollo's `cf`/`cr`) are the same per-axle cornering stiffness of a
single-track model (its lateral equation divides cf + cr by the whole mass), so they are written
unconverted, in N/rad. Autoware has no l_f: its dynamics model derives
l_f = L·(1 − m_front/m) from the corner masses, so vdsbi writes mass_fl = mass_fr = m·l_r/(2L) and
mass_rl = mass_rr = m·l_f/(2L), which give back vdsbi's l_f exactly (and its I_z = m·l_f·l_r).

What is written. Every format carries identify's estimate of every parameter — what `predict`
simulates — beside whether the drive identifies it alone: a parameter set assembled from the
identified values and something else predicts worse than either. The Autoware file is written
when the estimate predicts the run's held-out part (`held_out_verdict`), or, with nothing held
out, when the drive identifies l_f and both cornering stiffnesses; the intervals, the
combinations the drive determines and the pairs that trade travel as comments.
"""

from __future__ import annotations

import csv
import io
import json
import os
import re
from collections.abc import Mapping
from pathlib import Path
from typing import Any, Literal

from ..diagnostics import ridge_sentence
from ..io import InputError
from ._held_out import HeldOutVerdict, held_out_verdict

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


#: The controller files `export` writes.
ExportFormat = Literal["autoware", "json", "csv"]


def export(
    run_dir: str | os.PathLike, fmt: ExportFormat = "autoware", vehicle: Mapping[str, Any] | None = None
) -> str:
    """The text of `run_dir`'s result in format `fmt` (estimates; intervals in comments or
    columns).

    Args:
        fmt: "autoware" (a ROS 2 parameter file for Autoware's mpc_lateral_controller with
            `vehicle_model_type: dynamics`), "json" or "csv" (every parameter with its interval).
        vehicle: mass and wheelbase (default: those posterior.json recorded).

    Raises:
        InputError: unknown format, no result in `run_dir`, no vehicle mass/wheelbase, or
            (autoware) an estimate that fails the held-out part, or one not identified by a run
            that held nothing out to check it on.
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
    """Per parameter: value (identify's estimate, identified or not), std, 5/95 % quantiles, unit,
    identified and why not; beside them the combinations the drive determines and the held-out
    verdict."""
    rows = {}
    for n, p in post["parameters"].items():
        rows[n] = {
            "value": _value(p),
            "std": p["std"],
            "q05": p["q05"],
            "q95": p["q95"],
            "unit": p["unit"],
            "identified": p.get("identified", True),
        }
        if "not_identified_because" in p:
            rows[n]["not_identified_because"] = p["not_identified_because"]
    return {
        "recording": post["recording"],
        "effects": post.get("effects", []),
        "parameters": rows,
        "combinations": post.get("combinations", {}),
        "held_out": held_out_verdict(post).to_dict(),
    }


def _csv(table: Mapping[str, Any]) -> str:
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    keys = ("value", "std", "q05", "q95")
    w.writerow(["parameter", *keys, "unit", "identified", "not_identified_because"])
    for n, r in table["parameters"].items():
        why = r.get("not_identified_because", "")
        w.writerow([n, *(f"{r[k]:.6g}" for k in keys), r["unit"], r["identified"], why])
    return buf.getvalue()


#: The parameters the Autoware file's keys carry.
EXPORTED = ("l_f", "C_alpha_f", "C_alpha_r")


def autoware(post: Mapping[str, Any], vehicle: Mapping[str, Any] | None, run_dir: Path) -> str:
    """A ROS 2 parameter file (YAML) with `vehicle.cf`, `vehicle.cr` and `vehicle.mass_fl/_fr/_rl/_rr`
    as Autoware's mpc_lateral_controller reads them with `vehicle_model_type: dynamics`.

    Raises:
        InputError: the estimate fails the held-out part, or nothing was held out and one of
            l_f, C_alpha_f, C_alpha_r is not identified; no vehicle mass/wheelbase.
    """
    params = post["parameters"]
    verdict = held_out_verdict(post)
    _check_exportable(post, verdict, run_dir)
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
        _held_out_note(verdict),
        "# Estimates (the best fit of the drive: what `vdsbi predict` simulates); 90 % posterior",
        "# intervals [q05, q95], each parameter's own, and whether the drive identifies it alone:",
        f"#   vehicle.cf = C_alpha_f {_interval(caf, '.1f')} N/rad (front axle, both tyres: no conversion);"
        f" {identified_status(caf)}",
        f"#   vehicle.cr = C_alpha_r {_interval(car, '.1f')} N/rad (rear axle); {identified_status(car)}",
        f"#   l_f = {_interval(lf, '.4f')} m (CoG to front axle; wheelbase {L:g} m, mass {m:g} kg);"
        f" {identified_status(lf)}",
        f"#   mass_fl = mass_fr = m*l_r/(2L) = {front} kg [{lo['mass_fl']:.1f}, {hi['mass_fl']:.1f}]",
        f"#   mass_rl = mass_rr = m*l_f/(2L) = {rear} kg [{hi['mass_rl']:.1f}, {lo['mass_rl']:.1f}]",
        "#   (Autoware derives l_f = L*(1 - (mass_fl + mass_fr)/m) from these: the value above.)",
    ]
    head += _combination_notes(post)
    head += _steering_notes(params)
    head += _other_notes(params)
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


def _check_exportable(post: Mapping[str, Any], verdict: HeldOutVerdict, run_dir: Path) -> None:
    """Refuse, with what to do, an estimate that fails the held-out part, or one that nothing held
    out checks and the drive does not identify alone."""
    source = run_dir / "posterior.json"
    if verdict.scored and not verdict.passed:
        raise InputError(
            source,
            "validation",
            f"the estimate fails the held-out part ({'; '.join(verdict.failures)}): a controller would "
            f"inherit that error; {_diagnose_hint(post)}, or identify again with more --sims or "
            "another --seed",
        )
    if verdict.scored:
        return
    params = post["parameters"]
    for n in EXPORTED:
        if params[n].get("identified") is False:
            why = params[n].get("not_identified_because", "")
            raise InputError(
                source,
                n,
                f"not identified by this drive alone{f' ({why})' if why else ''}, and no held-out part "
                "was scored to check that the estimate predicts driving it never saw: rerun identify "
                "with --holdout 0.3",
            )


def _diagnose_hint(post: Mapping[str, Any]) -> str:
    """The run's own `vdsbi diagnose` command (its warnings name it), else the advice to run one."""
    for w in post.get("warnings", []):
        found = re.search(r"`(vdsbi diagnose [^`]*)`", w.get("message", ""))
        if found:
            return f"run `{found.group(1)}` to find what the model lacks"
    return "run `vdsbi diagnose` on the drive to find what the model lacks"


def _held_out_note(verdict: HeldOutVerdict) -> str:
    if not verdict.scored:
        return (
            "# Held-out check: none (identify ran with --holdout 0); written because the drive "
            "identifies l_f, C_alpha_f and C_alpha_r."
        )
    return f"# Held-out check passed: the fit of the training part predicted the {verdict.describe()}."


def _combination_notes(post: Mapping[str, Any]) -> list[str]:
    """Comments for what the drive determines: the understeer gradient, the steady-state yaw-rate
    gain (95 % intervals) and the pairs that trade along a ridge."""
    comb = post.get("combinations") or {}
    notes = []
    for key, name in (
        ("understeer_gradient", "understeer gradient"),
        ("yaw_rate_gain", "steady-state yaw-rate gain"),
    ):
        c = comb.get(key)
        if not c:
            continue
        at = f" at {c['at']:g} m/s" if c.get("at") else ""
        told = "" if "identified" not in c else ("; identified" if c["identified"] else "; not identified")
        notes.append(
            f"#   {name}{at} = {c['median']:.4g} [{c['q025']:.4g}, {c['q975']:.4g}] {c['unit']} (95 %){told}"
        )
    units = {n: p["unit"] for n, p in post["parameters"].items()}
    for pair in comb.get("trading_pairs", []):
        step = " with ".join(f"{pair['direction'][n]:+.4g} {units.get(n, '')} of {n}" for n in pair["pair"])
        notes.append(
            f"#   {ridge_sentence(pair)}: {step} leaves the fit about unchanged; the drive determines "
            "them together, not each alone"
        )
    return ["# What the drive determines (steady state, single-track model):", *notes] if notes else []


def _other_notes(params: Mapping[str, Any]) -> list[str]:
    """Comments for the rest of the estimate: Autoware has no key for it, and `predict` simulates it."""
    shown = {*EXPORTED, "signal_delay.delay", "steer_offset.offset"}
    rest = [n for n in params if n not in shown]
    if not rest:
        return []
    lines = ["# The rest of the estimate (no Autoware key; part of what `vdsbi predict` simulates):"]
    for n in rest:
        p = params[n]
        lines.append(f"#   {n} = {_interval(p, '.4g')} {p['unit']}; {identified_status(p)}")
    return lines


def identified_status(p: Mapping[str, Any], yes: str = "identified", no: str = "NOT identified alone") -> str:
    """Whether the drive identifies a parameter alone, and why not (`yes` and `no` the words)."""
    if p.get("identified") is False:
        why = p.get("not_identified_because")
        return f"{no}: {why}" if why else no
    return f"{yes}, moved by model error" if "model_error" in p else yes


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
