"""The next command a result tells its user to run, spelled with the files as the user named them."""

from __future__ import annotations

import os
import shlex
from collections.abc import Sequence


def shown(path: str | os.PathLike | None, default: str) -> str:
    """`path` as the user gave it (quoted for a shell), or `default` when there is none."""
    return default if path is None else shlex.quote(str(path))


def diagnose_command(recording, vehicle, out, longitudinal: str = "auto") -> str:
    """`vdsbi diagnose REC --vehicle V --out OUT` (OUT: the identify folder's sibling)."""
    target = "diagnose" if out is None else f"{str(out).rstrip('/')}-diagnose"
    cmd = (
        f"vdsbi diagnose {shown(recording, 'REC')} --vehicle {shown(vehicle, 'VEHICLE')} "
        f"--out {shlex.quote(target)}"
    )
    return cmd + ("" if longitudinal == "auto" else f" --longitudinal {longitudinal}")


def identify_command(recording, vehicle, out, effects: Sequence[str], longitudinal: str = "auto") -> str:
    """`vdsbi identify REC --vehicle V --out OUT --effects NAMES` with the effects a diagnosis named."""
    target = "identify" if out is None else f"{str(out).rstrip('/')}-identify"
    cmd = (
        f"vdsbi identify {shown(recording, 'REC')} --vehicle {shown(vehicle, 'VEHICLE')} "
        f"--out {shlex.quote(target)} --effects {','.join(effects) if effects else 'none'}"
    )
    return cmd + ("" if longitudinal == "auto" else f" --longitudinal {longitudinal}")
