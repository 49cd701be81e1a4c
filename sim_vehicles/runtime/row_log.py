"""Append-only float64 row files that a crash cannot make unreadable.

Layout: one header line ``ROWLOG1 {"columns": [...]}\\n``, then rows of ``len(columns)`` float64,
little-endian, back to back. Rows are buffered and flushed every ``flush_rows`` rows and on close;
a reader drops a trailing partial row, so a process killed mid-write loses at most its unflushed
rows and never the file.
"""

import json
from pathlib import Path

import numpy as np

MAGIC = b"ROWLOG1 "


class RowLogError(ValueError):
    """A file is not a row log."""


class RowLog:
    def __init__(self, path: str | Path, columns: list[str], flush_rows: int = 256):
        self.path = Path(path)
        self.columns = list(columns)
        self.width = len(columns)
        self._buf = np.empty((flush_rows, self.width))
        self._n = 0
        self._f = open(self.path, "wb")  # noqa: SIM115  (closed by close())
        self._f.write(MAGIC + json.dumps({"columns": self.columns}).encode() + b"\n")
        self._f.flush()

    def append(self, *parts: "np.ndarray | tuple[float, ...] | list[float]") -> None:
        """One row: ``parts`` (1-D arrays, or tuples or lists of floats) concatenated in column order."""
        try:
            np.concatenate(parts, out=self._buf[self._n])
        except ValueError:
            n = sum(np.size(p) for p in parts)
            raise ValueError(f"{self.path.name}: row has {n} values, expected {self.width}") from None
        self._n += 1
        if self._n == len(self._buf):
            self.flush()

    def flush(self) -> None:
        if self._f.closed:
            return
        self._f.write(self._buf[: self._n].astype("<f8").tobytes())
        self._f.flush()
        self._n = 0

    def close(self) -> None:
        if not self._f.closed:
            self.flush()
            self._f.close()


def read_rows(path: str | Path) -> tuple[list[str], np.ndarray]:
    """The columns and the complete rows of a row log."""
    data = Path(path).read_bytes()
    end = data.find(b"\n")
    if not data.startswith(MAGIC) or end < 0:
        raise RowLogError(f"{path}: not a row log")
    try:
        columns = list(json.loads(data[len(MAGIC) : end])["columns"])
    except (ValueError, KeyError, TypeError):
        raise RowLogError(f"{path}: row log header is unreadable") from None
    body = data[end + 1 :]
    width = len(columns)
    n = len(body) // (8 * width) if width else 0
    rows = np.frombuffer(body[: n * 8 * width], dtype="<f8").reshape(n, width)
    return columns, rows
