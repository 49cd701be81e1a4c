"""Counts that outlive their process: int64s of a file mapped in memory. Each count is one store
into the page cache, which the kernel keeps (and writes back) even when the process is killed the
next instant: what a SIGKILLed process had counted is still there to read.

``CounterFile``: one count, 8 bytes. ``NamedCounts``: several, after a header line that names
them (``COUNTS1 ["a", "b"]``, padded with spaces to a multiple of 8 bytes), as an int64 array.
"""

import json
import mmap
import os
import struct
from pathlib import Path

import numpy as np

_COUNT = struct.Struct("<q")


class CounterFile:
    """A new counter at ``path`` (an old file there is replaced), starting at 0."""

    def __init__(self, path: Path):
        fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_TRUNC, 0o644)
        try:
            os.ftruncate(fd, _COUNT.size)
            self._map = mmap.mmap(fd, _COUNT.size)
        finally:
            os.close(fd)
        self.value = 0

    def add(self, n: int = 1) -> None:
        self.value += n
        _COUNT.pack_into(self._map, 0, self.value)

    def set(self, value: int) -> None:
        self.value = value
        _COUNT.pack_into(self._map, 0, value)

    def close(self) -> None:
        self._map.close()


def read_counter(path: Path) -> int | None:
    """The count in ``path``, or None if there is no such counter."""
    try:
        data = path.read_bytes()
    except OSError:
        return None
    return _COUNT.unpack(data)[0] if len(data) == _COUNT.size else None


_MAGIC = b"COUNTS1 "


class NamedCounts:
    """New counts named ``names`` at ``path`` (an old file there is replaced), all 0. ``values``
    is the int64 array in the file: ``values[k] += 1`` is a count that survives a SIGKILL."""

    def __init__(self, path: Path, names: list[str]):
        head = _MAGIC + json.dumps(names).encode()
        head += b" " * (-(len(head) + 1) % 8) + b"\n"
        size = len(head) + 8 * len(names)
        fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_TRUNC, 0o644)
        try:
            os.ftruncate(fd, size)
            self._map = mmap.mmap(fd, size)
        finally:
            os.close(fd)
        self._map[: len(head)] = head
        self.index = {n: k for k, n in enumerate(names)}
        self.values: np.ndarray = np.ndarray((len(names),), dtype="<i8", buffer=self._map, offset=len(head))

    def view(self, names: list[str]) -> np.ndarray:
        """The counts ``names`` (consecutive in the file) as one writable array."""
        k = self.index[names[0]]
        assert [self.index[n] for n in names] == list(range(k, k + len(names))), names
        return self.values[k : k + len(names)]

    def close(self) -> None:
        """Unmapped once nothing holds a view of it any more (until then the file stays mapped)."""


def read_named_counts(path: Path) -> dict[str, int] | None:
    """The counts in ``path`` by name, or None if it is not such a file."""
    try:
        data = path.read_bytes()
    except OSError:
        return None
    end = data.find(b"\n")
    if not data.startswith(_MAGIC) or end < 0 or (end + 1) % 8:
        return None
    try:
        names = json.loads(data[len(_MAGIC) : end])
    except ValueError:
        return None
    body = data[end + 1 :]
    if not isinstance(names, list) or len(body) != 8 * len(names):
        return None
    return dict(zip(map(str, names), np.frombuffer(body, "<i8").tolist(), strict=True))
