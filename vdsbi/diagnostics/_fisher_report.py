"""The observability report of a `Fisher`: `fisher_report` turns the scaled Fisher information
into plain JSON-able data (eigenvalues, numerical rank and practically identifiable directions
with their rules, Cramér–Rao bounds in physical units, the weakest direction, the correlation
from F⁻¹) and `report_markdown` renders that data as Markdown."""

from __future__ import annotations

import math

import numpy as np

from ._fisher import MAX_RELATIVE_STD, RANK_RTOL, Fisher


def fisher_report(
    fisher: Fisher,
    *,
    rank_rtol: float = RANK_RTOL,
    max_relative_std: float = MAX_RELATIVE_STD,
) -> dict:
    """The observability summary as plain JSON-able data.

    Eigen-analysis is done on the scaled F (dimensionless). Keys: params, units of scaling,
    fim (physical units), fim_scaled, eigenvalues (scaled, ascending), condition_number,
    rank {value, of, rtol, tolerance, rule}, identifiable {value, max_relative_std, rule},
    crb_std {name: std}, crb_relative {name: std/|value|}, weakest_direction {name: weight},
    correlation (matrix, from F⁻¹).
    """
    names = list(fisher.names)
    fz = np.asarray(fisher.fim_scaled, dtype=float)
    fz = 0.5 * (fz + fz.T)
    scale = np.asarray(fisher.scale, dtype=float)
    values = np.asarray(fisher.values, dtype=float)
    w, v = np.linalg.eigh(fz)
    tol = rank_rtol * (float(w[-1]) if w.size else 0.0)
    rank = int(np.sum(w > tol))
    identifiable = _identifiable_summary(w, max_relative_std)
    cond = float(w[-1] / w[0]) if w[0] > 0 else math.inf
    weak = v[:, 0] * np.sign(v[np.argmax(np.abs(v[:, 0])), 0])
    crb, corr = _crb_and_correlation(fz, w, v, scale, rank, len(names), rank_rtol, tol)
    return {
        "params": names,
        "channels": list(fisher.channels),
        "values": {n: float(x) for n, x in zip(names, values)},
        "scale": {n: float(s) for n, s in zip(names, scale)},
        "fim": (fz / np.outer(scale, scale)).tolist(),
        "fim_scaled": fz.tolist(),
        "eigenvalues": w.tolist(),
        "eigenvalues_note": "of the scaled F (parameters as fractions of `scale`), ascending",
        "condition_number": cond,
        "rank": _rank_summary(rank, len(names), rank_rtol, tol),
        "identifiable": identifiable,
        "crb_std": {n: float(s) for n, s in zip(names, crb)},
        "crb_relative": {n: float(s / abs(x)) if x != 0 else None for n, s, x in zip(names, crb, values)},
        "weakest_direction": {n: float(x) for n, x in zip(names, weak)},
        "weakest_direction_crb_std_scaled": float(1 / math.sqrt(w[0])) if w[0] > 0 else math.inf,
        "correlation": corr.tolist(),
    }


def _rank_summary(value: int, of: int, rtol: float, tolerance: float) -> dict:
    """The report's numerical rank of the scaled F, with its rule."""
    return {
        "value": value,
        "of": of,
        "rtol": rtol,
        "tolerance": tolerance,
        "rule": "eigenvalues of scaled F > rtol * largest eigenvalue",
        "nonsingular": value == of,
    }


def _identifiable_summary(w: np.ndarray, max_relative_std: float) -> dict:
    """How many eigen-directions of the scaled F (eigenvalues `w`) have a Cramér–Rao std of at
    most `max_relative_std`, with the rule."""
    tolerance = 1.0 / max_relative_std**2
    return {
        "value": int(np.sum(w >= tolerance)),
        "max_relative_std": max_relative_std,
        "tolerance": tolerance,
        "rule": "eigen-directions whose Cramér-Rao std (in fractions of `scale`) is <= max_relative_std",
    }


def _crb_and_correlation(fz, w, v, scale, rank: int, num_params: int, rank_rtol: float, tol: float):
    """Cramér–Rao std per parameter (physical units) and the correlation matrix, from F⁻¹ of the
    scaled F (`w`, `v` its eigen-decomposition; `rank` its rank at tolerance `tol`)."""
    if rank == num_params:
        cov_z = np.linalg.inv(fz)
    else:  # bounds of unidentifiable directions are infinite; report the pseudo-inverse
        cov_z = np.linalg.pinv(fz, rcond=rank_rtol, hermitian=True)
    sd_z = np.sqrt(np.clip(np.diag(cov_z), 0, None))
    corr = cov_z / np.outer(sd_z, sd_z)
    crb = scale * sd_z
    if rank < num_params:
        # A parameter with any weight on a null direction has an infinite bound.
        null = v[:, w <= tol]
        crb = np.where(np.abs(null).max(axis=1) > 1e-6, np.inf, crb)
    return crb, corr


def report_markdown(report: dict, title: str = "Observability") -> str:
    """A Markdown rendering of `fisher_report` output."""
    names = report["params"]
    lines = [f"# {title}", ""]
    lines.append(f"Channels: {', '.join(report['channels'])}.")
    r, ident = report["rank"], report["identifiable"]
    lines.append(
        f"Rank {r['value']}/{r['of']} ({r['rule']}, rtol = {r['rtol']:g}); "
        f"{'nonsingular' if r['nonsingular'] else 'SINGULAR'}. Condition number "
        f"{report['condition_number']:.3g} (scaled F). Practically identifiable directions: "
        f"{ident['value']}/{r['of']} (Cramér–Rao std ≤ {ident['max_relative_std']:g} of scale)."
    )
    lines += [
        "",
        "| parameter | value | CRB std | CRB std / value | weakest direction |",
        "|---|---|---|---|---|",
    ]
    for n in names:
        rel = report["crb_relative"][n]
        lines.append(
            f"| {n} | {report['values'][n]:.6g} | {report['crb_std'][n]:.4g} | "
            f"{'' if rel is None else f'{rel:.2%}'} | {report['weakest_direction'][n]:+.3f} |"
        )
    lines += [
        "",
        "Eigenvalues of the scaled F (ascending): " + ", ".join(f"{x:.4g}" for x in report["eigenvalues"]),
    ]
    lines += [
        "",
        "Correlation (from F⁻¹):",
        "",
        "| | " + " | ".join(names) + " |",
        "|---" * (len(names) + 1) + "|",
    ]
    for n, row in zip(names, report["correlation"]):
        lines.append(f"| {n} | " + " | ".join(f"{x:+.2f}" for x in row) + " |")
    return "\n".join(lines) + "\n"
