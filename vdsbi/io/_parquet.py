"""Parquet reader for the recording contract."""

from __future__ import annotations

import os

import numpy as np

from ._contract import build_recording
from ._errors import InputError
from ._recording import Recording


def read_parquet_columns(path: str | os.PathLike) -> dict[str, np.ndarray]:
    """Columns of a contract Parquet file as name -> array (no validation beyond parsing)."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    source = str(path)
    if os.path.getsize(path) == 0:
        raise InputError(source, "file", "file is empty; expected a Parquet file with columns t, steer, ...")
    try:
        table = pq.read_table(path)
    except (pa.ArrowException, OSError) as err:
        msg = " ".join(str(err).split())
        raise InputError(source, "file", f"cannot read as Parquet ({msg})") from None
    names = [str(n) for n in table.column_names]
    dup = sorted({c for c in names if names.count(c) > 1})
    if dup:
        raise InputError(source, dup[0], "duplicated column; expected each column once")
    out: dict[str, np.ndarray] = {}
    for name, col in zip(names, table.columns):
        if pa.types.is_integer(col.type) or pa.types.is_floating(col.type):
            out[name] = col.to_numpy(zero_copy_only=False).astype(float)  # nulls become NaN
        else:
            out[name] = np.asarray(col.to_pylist(), dtype=object)
    return out


def read_parquet(path: str | os.PathLike, *, rate: float = 200.0) -> Recording:
    """Read and validate a contract Parquet file, resampled to `rate` Hz."""
    return build_recording(read_parquet_columns(path), path, rate=rate)
