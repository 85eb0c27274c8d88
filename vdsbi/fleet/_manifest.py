"""The fleet's manifest: one CSV row per drive (car, recording, vehicle, time), read and checked
before anything runs, every error naming the manifest's line."""

from __future__ import annotations

import dataclasses
import os
import re
from pathlib import Path

from ..io import InputError

#: Columns every manifest has; others are ignored.
COLUMNS = ("car", "recording", "vehicle", "time")


@dataclasses.dataclass(frozen=True)
class Drive:
    """One drive of the fleet.

    Attributes:
        car: the car's name as the manifest gives it.
        name: the recording as the manifest gives it.
        recording: absolute path of the recording (any format `identify` reads).
        vehicle: absolute path of its vehicle file.
        time: when it was driven, as the manifest gives it (orders a car's drives).
        order: its time as seconds since the epoch (UTC where the manifest gives no zone), or the
            number itself where the manifest gives numbers.
        line: the manifest's line (header is line 1).
    """

    car: str
    name: str
    recording: Path
    vehicle: Path
    time: str
    order: float
    line: int

    @property
    def key(self) -> str:
        """A file-name-safe identity, stable across runs: the car and the recording's stem, with
        a short hash of the recording's full path (two cars may name their drives alike)."""
        import hashlib

        digest = hashlib.sha1(str(self.recording).encode()).hexdigest()[:8]
        return f"{safe_name(self.car)}__{safe_name(self.recording.stem)}-{digest}"


def safe_name(text: str) -> str:
    return re.sub(r"[^A-Za-z0-9._-]+", "_", text).strip("._") or "_"


def read_manifest(path: str | os.PathLike) -> tuple[Drive, ...]:
    """The manifest's drives, ordered by car then time.

    Paths are relative to the manifest's folder (absolute ones are kept). `time` is an ISO date
    or date-time, or a number (e.g. seconds or a drive index).

    Raises:
        InputError: naming the manifest, the line and the column: a missing column or value, a
            recording or vehicle file that does not exist, a time that is neither a date nor a
            number, a drive listed twice.
    """
    import pandas as pd

    source = Path(path)
    if not source.is_file():
        raise InputError(source, "file", "does not exist")
    try:
        table = pd.read_csv(source, dtype=str, keep_default_na=False, skipinitialspace=True)
    except (pd.errors.ParserError, pd.errors.EmptyDataError, UnicodeDecodeError) as err:
        raise InputError(source, "file", f"not a readable CSV ({type(err).__name__})") from None
    table.columns = [str(c).strip() for c in table.columns]
    missing = [c for c in COLUMNS if c not in table.columns]
    if missing:
        raise InputError(
            source, "header", f"missing column(s) {', '.join(missing)}; need {', '.join(COLUMNS)}"
        )
    if table.empty:
        raise InputError(source, "rows", "no drives listed")
    drives, seen = [], {}
    for i, row in enumerate(table.itertuples(index=False)):
        line = i + 2
        values = {c: str(getattr(row, c)).strip() for c in COLUMNS}
        for c in COLUMNS:
            if not values[c]:
                raise InputError(source, f"line {line}: {c}", "is empty")
        files = {}
        for c in ("recording", "vehicle"):
            p = Path(values[c])
            p = p if p.is_absolute() else (source.parent / p)
            if not p.exists():
                raise InputError(source, f"line {line}: {c}", f"'{values[c]}' does not exist (looked at {p})")
            files[c] = p.resolve()
        ident = (values["car"], files["recording"])
        if ident in seen:
            raise InputError(
                source,
                f"line {line}: recording",
                f"listed twice for car {values['car']} (line {seen[ident]})",
            )
        seen[ident] = line
        order = _order(values["time"], source, line)
        drives.append(
            Drive(
                values["car"],
                values["recording"],
                files["recording"],
                files["vehicle"],
                values["time"],
                order,
                line,
            )
        )
    return tuple(sorted(drives, key=lambda d: (d.car, d.order, d.line)))


def _order(text: str, source: Path, line: int) -> float:
    """`text` as a number, else as an ISO date(-time) in seconds since the epoch."""
    import pandas as pd

    try:
        return float(text)
    except ValueError:
        pass
    try:
        stamp = pd.Timestamp(text)
    except (ValueError, TypeError):
        stamp = None
    if stamp is None or pd.isna(stamp):
        raise InputError(
            source, f"line {line}: time", f"'{text}' is neither a date/time (ISO 8601) nor a number"
        )
    if stamp.tzinfo is None:
        stamp = stamp.tz_localize("UTC")
    return float(stamp.timestamp())
