"""A campaign's table: one CSV row per run, written as each run ends (an interrupted campaign
keeps every finished row), read back to resume and to chart."""

import csv
import math
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from swarm_sitl.campaigns.point import METRICS

TABLE = "table.csv"
SPEC = "spec."  #: a requirement's column: its robustness in the run


def columns(keys: list[str], requirements: Sequence[str] = ()) -> list[str]:
    """The table's columns: the swept keys, the seed, whether a bisection added it, the metrics,
    each requirement's robustness (``spec.NAME``: the config's ``spec:``), and the config file the
    run flew (in ``points/``)."""
    return [*keys, "seed", "refined", *METRICS, *(f"{SPEC}{r}" for r in requirements), "config"]


def row_key(keys: list[str], row: dict[str, Any]) -> tuple[Any, ...]:
    """What identifies a run: its values and its seed."""
    return (*(round(float(row[k]), 12) for k in keys), int(row["seed"]))


def _cell(v: Any) -> str:
    if isinstance(v, float):
        return "" if math.isnan(v) else repr(v)
    return str(v)


def read_rows(path: Path, keys: list[str]) -> list[dict[str, Any]]:
    """The rows of ``path`` (none if it does not exist), numbers as numbers."""
    if not path.is_file():
        return []
    out = []
    with path.open(newline="") as f:
        for raw in csv.DictReader(f):
            row: dict[str, Any] = {}
            for k, v in raw.items():
                if k in ("failure", "config"):
                    row[k] = v or ""
                elif k in ("seed", "refined", "passed"):
                    row[k] = int(v)
                else:
                    row[k] = float(v) if v not in ("", None) else math.nan
            if all(k in row for k in keys):
                out.append(row)
    return out


class TableWriter:
    """Appends rows to the table, each flushed to disk as it comes."""

    def __init__(self, path: Path, keys: list[str], requirements: Sequence[str] = ()):
        self.cols = columns(keys, requirements)
        new = not path.is_file() or path.stat().st_size == 0
        self._f = path.open("a", newline="")
        self._w = csv.DictWriter(self._f, fieldnames=self.cols)
        if new:
            self._w.writeheader()
            self._f.flush()

    def add(self, row: dict[str, Any]) -> None:
        self._w.writerow({c: _cell(row.get(c, "")) for c in self.cols})
        self._f.flush()
        os.fsync(self._f.fileno())

    def close(self) -> None:
        self._f.close()


def write_sorted(
    path: Path, keys: list[str], rows: list[dict[str, Any]], requirements: Sequence[str] = ()
) -> None:
    """The whole table, sorted by its values and seeds, replacing ``path`` at once."""
    tmp = path.with_name(path.name + ".tmp")
    cols = columns(keys, requirements)
    with tmp.open("w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=cols)
        w.writeheader()
        for row in sorted(rows, key=lambda r: row_key(keys, r)):
            w.writerow({c: _cell(row.get(c, "")) for c in cols})
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, path)
