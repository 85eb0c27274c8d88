"""`diagnose`: find, name and fix model mismatch (`vdsbi.discovery.diagnose_mismatch`), and say which
`identify` command models what it named."""

from __future__ import annotations

import dataclasses
import os
from pathlib import Path
from typing import Any

from ._commands import identify_command, measured_priors
from ._pages import diagnose_page


def not_claimed(chosen, priors, verdict: str) -> str:
    """What a diagnosis found but does not claim: the effects with the ranges it measured, and
    what remains."""
    ranges = ", ".join(f"{n} in [{lo:.4g}, {hi:.4g}]" for n, (lo, hi) in priors.items())
    return (
        f"found {' + '.join(chosen)}" + (f" ({ranges})" if ranges else "") + ", but modelling it does not "
        f"improve the held-out fit, so no identify command is given as the fix; {verdict}"
    )


def diagnose(
    recording,
    vehicle,
    out_dir: str | os.PathLike | None = None,
    *,
    names: tuple[Any, Any, Any] | None = None,
    **options,
):
    """`vdsbi.discovery.diagnose_mismatch` (imported on first use: it pulls in the discovery layer), with
    `report["identify_command"]`: the `vdsbi identify … --effects NAMES --prior …` that models the
    effects it chose, with prior ranges around the values it measured (`measured_priors`),
    written into report.json and report.md; report.html shows the tables and figures. Where the
    chosen effects do not improve the held-out fit there is no command (None), and
    `report["not_claimed"]` says what was found, with its ranges, and what remains.

    Args:
        recording, vehicle, out_dir, **options: as `vdsbi.discovery.diagnose_mismatch`.
        names: (recording, vehicle, out_dir) as the user knows them, for the command (default:
            the arguments as given).
    """
    from ..discovery import diagnose_mismatch, write_report

    found = diagnose_mismatch(recording, vehicle, None, **options)
    rec, veh, out = (_as_named(n) for n in (names or (recording, vehicle, out_dir)))
    if rec is None:
        rec = found.report["source"]
    chosen = found.report["chosen"]
    rep = found.report
    priors = measured_priors(chosen, rep.get("effect_params", {}), rep.get("effect_params_std", {}))
    dropped = rep.get("dropped", [])
    if not (chosen or dropped):
        # Nothing to add to identify's model: no command is the fix.
        extra = {"identify_command": None}
    elif not found.verdict.held_out_improved:
        # Modelling it does not predict the held-out part better: no command to run as the fix.
        extra = {"identify_command": None, "not_claimed": not_claimed(chosen, priors, found.verdict.text)}
    else:
        longitudinal = options.get("longitudinal", "auto")
        base = rep.get("base_effects", [])
        command = identify_command(rec, veh, out, chosen, longitudinal, priors, base=base, dropped=dropped)
        extra = {"identify_command": command}
    found = dataclasses.replace(found, report={**found.report, **extra})
    if out_dir is not None:
        plots = options.get("plots", getattr(options.get("settings"), "plots", True))
        write_report(found, Path(out_dir), plots=plots)
        (Path(out_dir) / "report.html").write_text(diagnose_page(found.report, out_dir))
    return found


def _as_named(given):
    """A path (or several) as the user named it; None for an in-memory object."""
    if isinstance(given, (str, os.PathLike)):
        return given
    if isinstance(given, (list, tuple)) and given and all(isinstance(g, (str, os.PathLike)) for g in given):
        return list(given)
    return None
