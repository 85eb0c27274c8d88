"""Writing results safely: output directories that appear whole or not at all, and atomic files."""

from __future__ import annotations

import contextlib
import os
import shutil
import tempfile
from collections.abc import Callable, Iterator
from pathlib import Path

from ._errors import InputError

#: The file whose presence keeps an interrupted output directory (`checkpoint_dir`).
CHECKPOINT = "checkpoint.npz"


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
