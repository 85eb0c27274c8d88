"""CSV reader for the recording contract."""

from __future__ import annotations

import csv
import os

import numpy as np
import pandas as pd

from ._contract import build_recording, is_number
from ._errors import InputError
from ._recording import Recording


def read_csv_columns(path: str | os.PathLike) -> dict[str, np.ndarray]:
    """Columns of a contract CSV as name -> array, in file order (no validation beyond parsing).

    Raises:
        InputError: empty file, unreadable text, ragged rows, duplicated header names.
    """
    source = str(path)
    try:
        with open(path, newline="", encoding="utf-8-sig") as f:
            first = f.readline()
    except UnicodeDecodeError:
        raise InputError(source, "file", "not UTF-8 text; expected a comma-separated text file") from None
    if not first.strip():
        raise InputError(source, "header", "file is empty; expected a header row t,steer,...")
    header = next(csv.reader([first]))
    names = [h.strip() for h in header]
    if all(is_number(c) for c in names):
        raise InputError(source, "header", "the first row holds numbers; expected a header row t,steer,...")
    dup = sorted({c for c in names if names.count(c) > 1 and c})
    if dup:
        raise InputError(source, dup[0], "duplicated column; expected each column once")
    try:
        frame = pd.read_csv(
            path,
            encoding="utf-8-sig",
            skipinitialspace=True,
            dtype=str,  # parse numbers ourselves so the error names the cell
            keep_default_na=False,
            na_filter=False,
        )
    except pd.errors.ParserError as err:
        msg = " ".join(str(err).split())
        raise InputError(source, "rows", f"malformed CSV ({msg}); expected one value per column") from None
    frame.columns = [str(c).strip() for c in frame.columns]
    out: dict[str, np.ndarray] = {}
    for name in frame.columns:
        text = frame[name].str.strip()
        empty = (text == "") | text.str.lower().isin(["nan", "na", "null", "none"])
        num = pd.to_numeric(text.where(~empty, "nan"), errors="coerce").to_numpy(dtype=float)
        bad = np.flatnonzero(np.isnan(num) & ~empty.to_numpy())
        if bad.size:
            out[name] = text.to_numpy(dtype=object)
        else:
            out[name] = num
    return out


def read_csv(path: str | os.PathLike, *, rate: float = 200.0) -> Recording:
    """Read and validate a contract CSV, resampled to `rate` Hz."""
    return build_recording(read_csv_columns(path), path, rate=rate)
