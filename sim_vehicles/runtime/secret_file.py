"""A file only its owner may read: a signing passphrase, a router's passwords."""

import os
from pathlib import Path


def write_secret(path: Path, text: str) -> None:
    """Write ``text`` to a new file ``path`` that only this user can read (an old one is replaced;
    the file is created 0600, never readable by others even for an instant)."""
    path.unlink(missing_ok=True)
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    with os.fdopen(fd, "w") as f:
        f.write(text)
