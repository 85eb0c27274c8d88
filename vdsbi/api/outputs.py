"""The files `identify` leaves in its directory (written through `vdsbi.io`'s output directories
and atomic files)."""

from __future__ import annotations

import os
import shutil
import tempfile
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ..io import (
    CHECKPOINT as CHECKPOINT,
    checkpoint_dir as checkpoint_dir,
    output_dir as output_dir,
    write_atomically as write_atomically,
    write_text_atomically as write_text_atomically,
)
from ..simulator import PARAM_NAMES, PARAM_UNITS
from ._export import EXPORT_FORMATS as EXPORT_FORMATS, FILE_NAMES, ExportFormat, export
from ._pages import identify_page
from .plots import ParameterAxes, pairplot, ppc_plot

#: Files `identify` writes into its output directory (besides `CHECKPOINT`).
RUN_FILE = "run.json"
ESTIMATOR = "estimator.npz"
#: Parameter draws for predicting other driving (`predict --band`).
PREDICTIVE = "predictive_draws.csv"


def summarise(
    samples: np.ndarray,
    prior_box: dict[str, tuple[float, float]],
    names: Sequence[str] = PARAM_NAMES,
    units: Mapping[str, str] = PARAM_UNITS,
) -> dict[str, dict[str, float]]:
    """Per parameter: mean, std, 2.5/5/50/95/97.5 % quantiles, unit and prior range of (N, P)
    samples."""
    q = np.quantile(samples, [0.05, 0.5, 0.95, 0.025, 0.975], axis=0)
    out = {}
    for i, n in enumerate(names):
        out[n] = {
            "mean": float(samples[:, i].mean()),
            "std": float(samples[:, i].std()),
            "q05": float(q[0, i]),
            "q50": float(q[1, i]),
            "q95": float(q[2, i]),
            "q025": float(q[3, i]),
            "q975": float(q[4, i]),
            "unit": units.get(n, "-"),
            "prior": [float(v) for v in prior_box[n]],
        }
    return out


def write_outputs(out: Path, result: Any, prob: Any, ppc: dict[str, np.ndarray]) -> None:
    """samples.csv, predictive_draws.csv, posterior.json, the estimator, pairplot.png, ppc.png and
    report.html of an `IdentifyResult`, written into a temporary folder inside `out` and moved in
    only when all are written."""
    import pandas as pd

    tmp = Path(tempfile.mkdtemp(prefix=".outputs-", dir=out))
    try:
        names = list(result.summary["parameters"])
        pd.DataFrame(result.samples, columns=names).to_csv(
            tmp / "samples.csv", index=False, float_format="%.9g"
        )
        pd.DataFrame(result.predictive, columns=names).to_csv(
            tmp / PREDICTIVE, index=False, float_format="%.9g"
        )
        (tmp / "posterior.json").write_text(result.to_json() + "\n")
        result.neural_posterior.save(tmp / ESTIMATOR)
        plot_posterior(result.summary, result.samples, tmp / "pairplot.png")
        ppc_plot(prob, ppc, tmp / "ppc.png")
        (tmp / "report.html").write_text(identify_page(result.summary, tmp, also=[out]))
        for f in tmp.iterdir():
            os.replace(f, out / f.name)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def plot_posterior(
    summary: Mapping[str, Any],
    samples: np.ndarray,
    path: str | os.PathLike,
    truth: Mapping[str, float] | None = None,
    title: str | None = None,
) -> None:
    """pairplot.png of an identify summary: over the prior box, in readable units, parameters the
    drive cannot inform in grey, `--compare` values in green and `truth` (when known) in red."""
    params = summary["parameters"]
    names = list(params)
    given = summary.get("validation", {}).get("reference", {}).get("given")
    pick = lambda d: None if d is None else np.array([float(d.get(n, np.nan)) for n in names])
    pairplot(
        samples,
        names,
        path,
        truth=pick(truth),
        title=title or f"posterior from {summary['recording']}",
        axes=ParameterAxes(
            box=[params[n]["prior"] for n in names],
            units=[params[n]["unit"] for n in names],
            faded=[_uninformed(params[n]) for n in names],
        ),
        reference=pick(given),
    )


def _uninformed(p: Mapping[str, Any]) -> bool:
    """The drive does not inform the parameter (its posterior is the prior's): grey in the pair
    plot. One the box holds, or one of a pair that trades, stays in colour: its ridge is the
    picture."""
    from ..diagnostics import MAX_STD_RATIO

    if "std_ratio_to_prior" not in p:
        return p.get("identified") is False
    return p["std_ratio_to_prior"] > MAX_STD_RATIO


def write_export(
    run_dir: str | os.PathLike, fmt: ExportFormat, out: str | os.PathLike | None = None, **kw
) -> Path:
    """`export` written to `out` (default: `run_dir`/FILE_NAMES[fmt]); the path written."""
    text = export(run_dir, fmt, **kw)
    path = Path(out) if out is not None else Path(run_dir) / FILE_NAMES[fmt]
    write_text_atomically(path, text)
    return path
