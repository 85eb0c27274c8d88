"""The fleet's tables: estimates.csv (one row per drive and parameter, appended as drives finish
and rebuilt in order from the drives' result.json files) and changes.csv."""

from __future__ import annotations

import csv
import json
from collections.abc import Iterable
from pathlib import Path

from ..io import write_text_atomically
from ._changes import ChangeSettings, detect_changes

#: estimates.csv's columns.
ESTIMATE_COLUMNS = ("car", "recording", "time", "parameter", "estimate", "q05", "q95", "identified", "method")
#: changes.csv's columns.
CHANGE_COLUMNS = ("car", "parameter", "time", "before", "after")


def estimate_rows(record: dict) -> list[dict]:
    """One drive's rows (none for a failed drive)."""
    rows = []
    for name, p in record.get("parameters", {}).items():
        rows.append(
            {
                "car": record["car"],
                "recording": record["recording"],
                "time": record["time"],
                "parameter": name,
                "estimate": f"{p['estimate']:.6g}",
                "q05": f"{p['q05']:.6g}",
                "q95": f"{p['q95']:.6g}",
                "identified": str(bool(p["identified"])).lower(),
                "method": record["method"],
            }
        )
    return rows


def append_estimates(path: Path, record: dict) -> None:
    """Append one finished drive's rows (the header first if the file is new)."""
    new = not path.exists()
    with path.open("a", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=ESTIMATE_COLUMNS)
        if new:
            writer.writeheader()
        writer.writerows(estimate_rows(record))


def read_results(out: Path, settings_id: str | None = None) -> list[dict]:
    """Every drive's result.json under `out` (with `settings_id`: only those made with it), in
    car and time order."""
    records = []
    for f in sorted((out / "drives").glob("*/result.json")):
        try:
            r = json.loads(f.read_text())
        except (OSError, ValueError):
            continue
        if settings_id is None or r.get("settings") == settings_id:
            records.append(r)
    return sorted(records, key=lambda r: (r["car"], r["order"], r["line"]))


def _write_csv(path: Path, columns, rows: Iterable[dict]) -> None:
    import io

    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=columns)
    writer.writeheader()
    writer.writerows(rows)
    write_text_atomically(path, buf.getvalue())


def write_estimates(path: Path, records: list[dict]) -> None:
    """estimates.csv from scratch, in car and time order (atomically)."""
    _write_csv(path, ESTIMATE_COLUMNS, (row for r in records for row in estimate_rows(r)))


def fleet_changes(records: list[dict], settings: ChangeSettings = ChangeSettings()):
    """Every car's changes, each parameter followed over the drives that identify it."""
    by_car: dict[str, list[dict]] = {}
    for r in records:
        if r.get("parameters"):
            by_car.setdefault(r["car"], []).append(r)
    found = []
    for car, drives in by_car.items():
        names = list(drives[0]["parameters"])
        for name in names:
            seq = [r for r in drives if r["parameters"].get(name, {}).get("identified")]
            if len(seq) < 2:
                continue
            p = [r["parameters"][name] for r in seq]
            found += detect_changes(
                car,
                name,
                [r["time"] for r in seq],
                [x["q50"] for x in p],
                [x["q05"] for x in p],
                [x["q95"] for x in p],
                settings,
            )
    return found


def write_changes(path: Path, changes) -> None:
    rows = [
        {
            "car": c.car,
            "parameter": c.parameter,
            "time": c.time,
            "before": f"{c.before:.6g}",
            "after": f"{c.after:.6g}",
        }
        for c in changes
    ]
    _write_csv(path, CHANGE_COLUMNS, rows)
