"""Parsing of the option values the commands share: JSON objects (inline or a file), θ, effects
and their parameters, effect lists, time segments. Every failure is a one-line `InputError`
naming the option and the field."""

from __future__ import annotations

import argparse
import json
import math
from collections.abc import Iterable, Mapping
from pathlib import Path

from ..io import InputError
from ..problem import parameter_name
from ..simulator import PARAM_NAMES
from ..simulator.effects import EFFECTS


def json_object(text: str, flag: str) -> Mapping:
    """A JSON object given inline (text starting with ``{``) or as a file name."""
    source = flag
    if not text.lstrip().startswith("{"):
        path = Path(text)
        if not path.is_file():
            raise InputError(flag, "value", f"'{text}' is neither a JSON object nor an existing file")
        source = str(path)
        try:
            text = path.read_text(encoding="utf-8")
        except OSError as err:
            raise InputError(source, "file", f"cannot read ({type(err).__name__})") from None
    try:
        data = json.loads(text)
    except json.JSONDecodeError as err:
        raise InputError(source, "value", f"invalid JSON at column {err.colno}: {err.msg}") from None
    if not isinstance(data, Mapping):
        raise InputError(source, "value", f"expected a JSON object, got {type(data).__name__}")
    return data


def number(value, flag: str, field: str) -> float:
    """`value` as a float, if it is a finite JSON number."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise InputError(flag, field, f"must be a finite number, got {value!r}")
    return float(value)


def number_text(text: str, flag: str, field: str) -> float:
    """`text` (a command-line word such as ``0.1015`` or ``-2e-3``) as a finite float."""
    try:
        value = float(text.strip())
    except ValueError:
        raise InputError(flag, field, f"must be a finite number, got {text!r}") from None
    return number(value, flag, field)


def theta(text: str | None, defaults: Mapping[str, float], flag: str = "--theta") -> dict[str, float]:
    """{name: value} for every parameter: `defaults` overridden by the JSON object `text`."""
    values = dict(defaults)
    if text is not None:
        for name, value in json_object(text, flag).items():
            if name not in PARAM_NAMES:
                raise InputError(flag, str(name), f"unknown parameter; expected one of {list(PARAM_NAMES)}")
            values[name] = number(value, flag, name)
    return values


def effects(text: str | None, flag: str = "--effects") -> tuple[list[str], dict[str, dict[str, float]]]:
    """(effect names, {effect: {param: value}}) from the JSON object `text` (null: defaults)."""
    if text is None:
        return [], {}
    names, values = [], {}
    for name, params in json_object(text, flag).items():
        cls = _effect(name, flag)
        if params is None:
            params = {}
        if not isinstance(params, Mapping):
            raise InputError(flag, name, f"expected {{param: value}}, got {params!r}")
        clean = {}
        for p, v in params.items():
            if p not in cls.param_names:
                raise InputError(
                    flag, parameter_name(name, p), f"unknown parameter; '{name}' has {list(cls.param_names)}"
                )
            clean[p] = number(v, flag, parameter_name(name, p))
        names.append(name)
        values[name] = clean
    return names, values


def effect_names(
    names: Iterable[str], flag: str = "--effects", known: Iterable[str] | None = None
) -> list[str]:
    """`names` (stripped), each one of `known` (default: the simulator's effects)."""
    known = list(EFFECTS if known is None else known)
    out = [n.strip() for n in names]
    bad = [n for n in out if n not in known]
    if bad:
        raise InputError(
            flag, bad[0], f"not an effect this command takes; expected some of {', '.join(known)}"
        )
    return out


def _effect(name: str, flag: str):
    if name not in EFFECTS:
        raise InputError(flag, str(name), f"unknown effect; expected one of {list(EFFECTS)}")
    return EFFECTS[name]


def segment(text: str) -> tuple[float, float]:
    """argparse type of ``T0:T1`` (seconds)."""
    try:
        a, b = (float(v) for v in text.split(":"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected T0:T1 in seconds, got {text!r}") from None
    return a, b


def add_longitudinal(parser: argparse.ArgumentParser) -> None:
    """The `--longitudinal` option of the commands that read a recording."""
    parser.add_argument(
        "--longitudinal",
        choices=("auto", "torque", "speed"),
        default="auto",
        help="torque: wheels driven by the recorded torques; speed: follow the measured speed (no "
        "or commanded torques); auto (default): torque if the recording has torque columns",
    )
