"""Files of a run directory written whole or not at all: to a temporary name beside them, then
renamed over the final name (``os.replace``, atomic on one file system). A write cut short (a
second signal, a full disk) leaves the file as it was before, or absent: never half of it.
"""

import contextlib
import os
from collections.abc import Iterator
from pathlib import Path


@contextlib.contextmanager
def whole(path: Path) -> Iterator[Path]:
    """A temporary path to write ``path``'s new content to; renamed to ``path`` if the block ends
    normally, removed if it raises (or is interrupted)."""
    tmp = path.with_name(f".{path.name}.partial")
    try:
        yield tmp
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            tmp.unlink()
        raise


def write_text_whole(path: Path, text: str) -> None:
    with whole(path) as tmp:
        tmp.write_text(text)
