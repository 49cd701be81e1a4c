"""Events as they happen, one flushed JSON line each (a killed process keeps what it wrote).

Every event has ``t_s`` (the writer's simulated or run seconds), ``kind`` and ``source`` (the
process that saw it), plus fields of its kind. The run's ``events.jsonl`` merges every process's
file (``swarm_sitl.rundir.events``).
"""

import json
from pathlib import Path
from typing import IO, Any


class EventLog:
    """Appends events to a file (or nowhere, with ``path=None``)."""

    def __init__(self, path: str | Path | None, source: str):
        self.source = source
        self._f: IO[str] | None = open(path, "w") if path is not None else None  # noqa: SIM115
        self.count = 0

    def add(self, t_s: float, kind: str, **fields: Any) -> None:
        self.count += 1
        if self._f is not None:
            line = {"t_s": round(t_s, 9), "kind": kind, "source": self.source, **fields}
            self._f.write(json.dumps(line) + "\n")
            self._f.flush()

    def close(self) -> None:
        if self._f is not None:
            self._f.close()
            self._f = None
