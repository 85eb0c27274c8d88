"""The next command a result tells its user to run, spelled with the files as the user named them."""

from __future__ import annotations

import os
import shlex
from collections.abc import Sequence
from pathlib import Path


def shown(path: str | os.PathLike | None, default: str) -> str:
    """`path` as the user gave it (quoted for a shell), or `default` when there is none."""
    return default if path is None else shlex.quote(str(path))


def diagnose_command(recording, vehicle, out, longitudinal: str = "auto") -> str:
    """`vdsbi diagnose REC --vehicle V --out OUT` (OUT: `diagnose` beside the identify folder)."""
    target = "diagnose" if out is None else str(Path(out).parent / "diagnose")
    cmd = (
        f"vdsbi diagnose {shown(recording, 'REC')} --vehicle {shown(vehicle, 'VEHICLE')} "
        f"--out {shlex.quote(target)}"
    )
    return cmd + ("" if longitudinal == "auto" else f" --longitudinal {longitudinal}")


def identify_command(recording, vehicle, out, effects: Sequence[str], longitudinal: str = "auto") -> str:
    """`vdsbi identify REC --vehicle V --out identify-NAMES --effects NAMES` with the effects a
    diagnosis named (the folder beside the diagnosis' `out`)."""
    name = "identify-" + ("-".join(effects) or "base")
    target = name if out is None else str(Path(out).parent / name)
    cmd = (
        f"vdsbi identify {shown(recording, 'REC')} --vehicle {shown(vehicle, 'VEHICLE')} "
        f"--out {shlex.quote(target)} --effects {','.join(effects) if effects else 'none'}"
    )
    return cmd + ("" if longitudinal == "auto" else f" --longitudinal {longitudinal}")
