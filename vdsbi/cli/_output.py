"""Output directories that appear whole or not at all."""

from __future__ import annotations

import contextlib
import os
import shutil
import tempfile
from collections.abc import Iterator
from pathlib import Path

from ..io._errors import InputError


@contextlib.contextmanager
def output_dir(path: str | os.PathLike, *, resume: bool = False, overwrite: bool = False) -> Iterator[Path]:
    """Yield a directory to write results into; `path` holds them only if the block succeeds.

    Without `resume`, the block writes into a fresh temporary sibling (``.NAME.partial-*``) that is
    renamed to `path` on success and deleted on any exception, so a failed or interrupted run
    leaves nothing at `path`. With `resume`, the block works in `path` itself (created if
    missing), whose checkpoints the command is expected to write atomically.

    Raises:
        InputError: `path` exists, is not empty, and neither `resume` nor `overwrite` is set.
    """
    out = Path(path)
    if resume:
        out.mkdir(parents=True, exist_ok=True)
        yield out
        return
    if out.exists() and not out.is_dir():
        raise InputError(out, "--out", "exists and is not a directory")
    if out.exists() and any(out.iterdir()) and not overwrite:
        raise InputError(out, "--out", "directory exists and is not empty; use --resume or another DIR")
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
