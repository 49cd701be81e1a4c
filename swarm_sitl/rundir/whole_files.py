"""Files of a run directory written whole or not at all: to a temporary name beside them, then
renamed over the final name (``os.replace``, atomic on one file system). A write cut short (a
second signal, a full disk) leaves the file as it was before, or absent: never half of it; an
``OSError`` becomes a ``WriteError`` that names the file and the cause in one line.
"""

import contextlib
import os
from collections.abc import Iterator
from pathlib import Path


class WriteError(OSError):
    """A file of the run directory could not be written; the message names it and the cause."""

    def __str__(self) -> str:
        return str(self.strerror)


@contextlib.contextmanager
def whole(path: Path) -> Iterator[Path]:
    """A temporary path to write ``path``'s new content to; renamed to ``path`` if the block ends
    normally, removed if it raises (or is interrupted)."""
    tmp = path.with_name(f".{path.name}.partial")
    try:
        yield tmp
        os.replace(tmp, path)
    except BaseException as e:
        with contextlib.suppress(OSError):
            tmp.unlink()
        if isinstance(e, OSError) and not isinstance(e, WriteError):
            raise WriteError(e.errno, f"cannot write {path} ({e.strerror or e})") from e
        raise


def write_text_whole(path: Path, text: str) -> None:
    with whole(path) as tmp:
        tmp.write_text(text)
