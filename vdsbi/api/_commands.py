"""The next command a result tells its user to run, spelled with the files as the user named them."""

from __future__ import annotations

import os
import shlex
from collections.abc import Mapping, Sequence
from pathlib import Path

from ..problem import parameter_name
from ..simulator.models import LongitudinalChoice


def shown(path: str | os.PathLike | Sequence[str | os.PathLike] | None, default: str) -> str:
    """`path` (or several) as the user gave it (quoted for a shell), or `default` when there is none."""
    if path is None:
        return default
    paths = [path] if isinstance(path, (str, os.PathLike)) else list(path)
    return " ".join(shlex.quote(str(p)) for p in paths)


def diagnose_command(recording, vehicle, out, longitudinal: LongitudinalChoice = "auto") -> str:
    """`vdsbi diagnose REC --vehicle V --out OUT` (OUT: `diagnose` beside the identify folder)."""
    target = "diagnose" if out is None else str(Path(out).parent / "diagnose")
    cmd = (
        f"vdsbi diagnose {shown(recording, 'REC')} --vehicle {shown(vehicle, 'VEHICLE')} "
        f"--out {shlex.quote(target)}"
    )
    return cmd + ("" if longitudinal == "auto" else f" --longitudinal {longitudinal}")


def identify_command(
    recording,
    vehicle,
    out,
    effects: Sequence[str],
    longitudinal: LongitudinalChoice = "auto",
    priors: Mapping[str, tuple[float, float]] | None = None,
    *,
    base: Sequence[str] = (),
    dropped: Sequence[str] = (),
) -> str:
    """`vdsbi identify REC --vehicle V --out identify-NAMES --effects +NAMES [--prior NAME=LO:HI …]`
    adding the effects a diagnosis named to identify's defaults, with the ranges it measured for
    their parameters (the folder beside the diagnosis' `out`). Where the diagnosis also dropped
    some of identify's defaults (`base`), `--effects` lists the whole set instead."""
    changes = [*effects, *(f"no-{e}" for e in dropped)]
    name = "identify-" + ("-".join(changes) or "base")
    target = name if out is None else str(Path(out).parent / name)
    if dropped:
        chosen = ",".join([*(e for e in base if e not in dropped), *effects]) or "none"
    else:
        chosen = "+" + ",".join(effects) if effects else "none"
    cmd = (
        f"vdsbi identify {shown(recording, 'REC')} --vehicle {shown(vehicle, 'VEHICLE')} "
        f"--out {shlex.quote(target)} --effects {chosen}"
    )
    cmd += "".join(f" --prior {n}={lo:.4g}:{hi:.4g}" for n, (lo, hi) in (priors or {}).items())
    return cmd + ("" if longitudinal == "auto" else f" --longitudinal {longitudinal}")


#: A measured effect parameter's prior spans this many of its standard errors either side ...
PRIOR_STDS = 4.0
#: ... and at least this fraction of its value (a fit's standard error ignores model error).
PRIOR_FRACTION = 0.5


def measured_priors(
    effects: Sequence[str], values: Mapping[str, Mapping[str, float]], stds: Mapping[str, Mapping[str, float]]
) -> dict[str, tuple[float, float]]:
    """Prior ranges {effect.param: (lo, hi)} around what a diagnosis measured: the value ±
    max(`PRIOR_STDS`·std, `PRIOR_FRACTION`·|value|), inside the effect's fit bounds and its null."""
    from ..simulator.effects import get_effect

    out = {}
    for e in effects:
        eff = get_effect(e)
        for p, (b_lo, b_hi), null in zip(eff.param_names, eff.bounds, eff.null):
            if p not in values.get(e, {}):
                continue
            v, sd = float(values[e][p]), float(stds.get(e, {}).get(p, 0.0))
            half = max(PRIOR_STDS * sd, PRIOR_FRACTION * abs(v), 1e-6 * (b_hi - b_lo))
            lo, hi = max(v - half, min(b_lo, null)), min(v + half, max(b_hi, null))
            out[parameter_name(e, p)] = (lo, hi)
    return out
