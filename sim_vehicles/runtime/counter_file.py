"""A count that outlives its process: 8 bytes of a file mapped in memory. Each ``add`` is one
store into the page cache, which the kernel keeps (and writes back) even when the process is
killed the next instant: what a SIGKILLed process had counted is still there to read.
"""

import mmap
import os
import struct
from pathlib import Path

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

    def close(self) -> None:
        self._map.close()


def read_counter(path: Path) -> int | None:
    """The count in ``path``, or None if there is no such counter."""
    try:
        data = path.read_bytes()
    except OSError:
        return None
    return _COUNT.unpack(data)[0] if len(data) == _COUNT.size else None
