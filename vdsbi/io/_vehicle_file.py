"""vehicle.json / vehicle.yaml reader."""

from __future__ import annotations

import json
import os
from pathlib import Path

from ..simulator import Vehicle
from ._errors import InputError

#: Upper limits that catch unit mistakes the Vehicle's own checks (positive, finite) let through:
#: the largest road vehicles have L ≈ 20 m and R ≈ 2 m; mm or a diameter exceed them.
_VEHICLE_LIMITS = {
    "wheelbase": (20.0, "m (is it in mm?)"),
    "wheel_radius": (2.0, "m (is it in mm, or the diameter in inches?)"),
    "mass": (1.0e5, "kg (is it in g?)"),
}


def read_vehicle(path: str | os.PathLike) -> Vehicle:
    """Read and validate a vehicle file (.json, .yaml or .yml) per the contract.

    Raises:
        InputError: "<file>: <key>: <what was wrong and what was expected>".
    """
    source = str(path)
    p = Path(path)
    suffix = p.suffix.lower()
    if suffix not in (".json", ".yaml", ".yml"):
        raise InputError(source, "file", f"unknown extension '{p.suffix}'; expected .json, .yaml or .yml")
    try:
        text = p.read_text(encoding="utf-8-sig")
    except FileNotFoundError:
        raise InputError(source, "file", "does not exist") from None
    except (OSError, UnicodeDecodeError) as err:
        raise InputError(source, "file", f"cannot read ({type(err).__name__})") from None
    if not text.strip():
        raise InputError(source, "file", "file is empty; expected a mapping with mass, wheelbase, ...")
    if suffix == ".json":
        try:
            data = json.loads(text)
        except json.JSONDecodeError as err:
            raise InputError(
                source, "file", f"invalid JSON at line {err.lineno} column {err.colno}: {err.msg}"
            ) from None
    else:
        import yaml

        try:
            data = yaml.safe_load(text)
        except yaml.YAMLError as err:
            mark = getattr(err, "problem_mark", None)
            where = f" at line {mark.line + 1} column {mark.column + 1}" if mark else ""
            problem = getattr(err, "problem", None) or "syntax error"
            raise InputError(source, "file", f"invalid YAML{where}: {problem}") from None
    if not isinstance(data, dict):
        raise InputError(
            source, "file", f"expected a mapping of vehicle constants, got {type(data).__name__}"
        )
    try:
        vehicle = Vehicle.from_dict(data, source=source)
    except ValueError as err:
        raise _as_input_error(source, str(err)) from None
    for key, (limit, unit) in _VEHICLE_LIMITS.items():
        value = float(getattr(vehicle, key))
        if value > limit:
            raise InputError(source, key, f"{value:g} is implausible (> {limit:g}); expected {unit}")
    return vehicle


def _as_input_error(source: str, message: str) -> InputError:
    """Turn Vehicle.from_dict's "<source>: key 'mass' must ..." into the io message format."""
    import re

    rest = message[len(source) + 2 :] if message.startswith(source + ": ") else message
    m = re.search(r"(?:key |noise_std\[|prior\[|parameter )'([^']+)'", rest)
    field = m.group(1) if m else "file"
    if rest.startswith("noise_std"):
        field = f"noise_std.{field}"
    elif rest.startswith("prior") or "prior for" in rest:
        field = f"prior.{field}"
    return InputError(source, field, rest)
