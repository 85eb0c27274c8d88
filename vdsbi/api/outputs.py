"""Writing results: output directories that appear whole or not at all, atomic files, and the
files `identify` leaves in its directory."""

from __future__ import annotations

import contextlib
import os
import shutil
import tempfile
from collections.abc import Callable, Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ..io import InputError
from ..simulator import PARAM_NAMES, PARAM_UNITS
from ._pages import identify_page
from ._plots import pairplot, ppc_plot

#: Files `identify` writes into its output directory.
CHECKPOINT = "checkpoint.npz"
RUN_FILE = "run.json"
ESTIMATOR = "estimator.npz"


def _checked(path: str | os.PathLike, *, allow_nonempty: bool) -> Path:
    """`path` as a Path, if it is a directory that may take results (or does not exist yet)."""
    out = Path(path)
    if out.exists() and not out.is_dir():
        raise InputError(out, "--out", "exists and is not a directory")
    if out.exists() and any(out.iterdir()) and not allow_nonempty:
        raise InputError(out, "--out", "directory exists and is not empty; use --resume or another DIR")
    return out


@contextlib.contextmanager
def output_dir(path: str | os.PathLike, *, resume: bool = False, overwrite: bool = False) -> Iterator[Path]:
    """Yield a directory to write results into; `path` holds them only if the block succeeds.

    Without `resume`, the block writes into a fresh temporary sibling (``.NAME.partial-*``) that is
    renamed to `path` on success and deleted on any exception, so a failed or interrupted run
    leaves nothing at `path`. With `resume`, the block works in `path` itself, as in
    `checkpoint_dir`.

    Raises:
        InputError: `path` exists, is not empty, and neither `resume` nor `overwrite` is set.
    """
    if resume:
        with checkpoint_dir(path, resume=True) as out:
            yield out
        return
    out = _checked(path, allow_nonempty=overwrite)
    parent = out.absolute().parent
    created = [p for p in [parent, *parent.parents] if not p.exists()]
    parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.partial-", dir=parent))
    try:
        yield tmp
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        for p in created:  # innermost first
            with contextlib.suppress(OSError):
                p.rmdir()
        raise
    if out.exists():
        shutil.rmtree(out)
    os.replace(tmp, out)


@contextlib.contextmanager
def checkpoint_dir(
    path: str | os.PathLike, *, resume: bool = False, checkpoint: str = CHECKPOINT
) -> Iterator[Path]:
    """Yield `path` itself, so that checkpoints written in the block survive an interruption.

    The block is expected to write its files atomically. On an exception, `path` is removed again
    if this call created it and no `checkpoint` was written into it.

    Raises:
        InputError: `path` is not a directory, or is not empty and `resume` is not set.
    """
    out = _checked(path, allow_nonempty=resume)
    created = not out.exists()
    out.mkdir(parents=True, exist_ok=True)
    try:
        yield out
    except BaseException:
        if created and not (out / checkpoint).exists():
            shutil.rmtree(out, ignore_errors=True)
        raise


def write_atomically(path: str | os.PathLike, write: Callable[[str], None]) -> None:
    """`write(tmp)` to a temporary sibling renamed into place: no partial file on failure."""
    path = Path(path)
    parent = path.absolute().parent
    parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.partial-", suffix=path.suffix, dir=parent)
    os.close(fd)
    os.chmod(tmp, 0o644)  # mkstemp's 0600 is meant for secrets, not results
    try:
        write(tmp)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def write_text_atomically(path: str | os.PathLike, text: str) -> None:
    write_atomically(path, lambda tmp: Path(tmp).write_text(text))


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
    """samples.csv, posterior.json, the estimator, pairplot.png, ppc.png and report.html of an
    `IdentifyResult`, written into a temporary folder inside `out` and moved in only when all are
    written."""
    import pandas as pd

    tmp = Path(tempfile.mkdtemp(prefix=".outputs-", dir=out))
    try:
        names = list(result.summary["parameters"])
        pd.DataFrame(result.samples, columns=names).to_csv(
            tmp / "samples.csv", index=False, float_format="%.9g"
        )
        (tmp / "posterior.json").write_text(result.to_json() + "\n")
        result.posterior.save(tmp / ESTIMATOR)
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
        box=[params[n]["prior"] for n in names],
        units=[params[n]["unit"] for n in names],
        reference=pick(given),
        faded=[params[n].get("identified") is False for n in names],
    )
