"""What made a run, for ``summary.json``'s ``provenance``: so that two runs made with different
code, libraries or plug-ins can be told apart.

- ``swarm_sitl``: the package's version and, where it runs from a git checkout, ``git describe
  --always --dirty`` of it (None for an installed package);
- ``python``, ``numpy``, ``numba``, ``zenoh``, ``pymavlink``: the versions in use;
- ``plugins``: each plug-in the config names (the law, a vehicle model, each link model of the
  plan) with the SHA-256 of the file its code is in (a file entry's file, a package entry's
  module file; None for one that cannot be found);
- ``seeds``: the seed of each random stream the config has (the plan's, the law's, the gusts',
  the sensors').
"""

import hashlib
import importlib.util
import platform
import subprocess
from importlib import metadata
from pathlib import Path
from typing import Any

from sim_vehicles.common.entry import is_file_entry, split_entry
from swarm_sitl.config.schema import SwarmConfig

_LIBRARIES = {"numpy": "numpy", "numba": "numba", "zenoh": "eclipse-zenoh", "pymavlink": "pymavlink"}
GIT_TIMEOUT_S = 2.0  #: the longest ``git describe`` may take before it is left out [s]


def _version(distribution: str) -> str | None:
    try:
        return metadata.version(distribution)
    except metadata.PackageNotFoundError:
        return None


def _git_describe(root: Path) -> str | None:
    """``git describe --always --dirty`` of the checkout ``root`` is in, if it is one."""
    if not (root / ".git").exists():
        return None
    try:
        r = subprocess.run(
            ["git", "describe", "--always", "--dirty"],
            cwd=root,
            capture_output=True,
            text=True,
            timeout=GIT_TIMEOUT_S,
        )
    except (OSError, subprocess.TimeoutExpired):
        return None
    return r.stdout.strip() or None if r.returncode == 0 else None


def _source_file(entry: str) -> Path | None:
    """The file a plug-in entry's code is in (None: it cannot be found)."""
    where, _ = split_entry(entry)
    if is_file_entry(entry):
        return Path(where)
    try:
        spec = importlib.util.find_spec(where)
    except (ImportError, ValueError):
        return None
    return Path(spec.origin) if spec is not None and spec.origin else None


def file_sha256(path: Path | None) -> str | None:
    if path is None or not path.is_file():
        return None
    return hashlib.sha256(path.read_bytes()).hexdigest()


def provenance(cfg: SwarmConfig) -> dict[str, Any]:
    """``summary.json``'s ``provenance`` of a run of ``cfg`` (module docstring)."""
    root = Path(__file__).resolve().parents[2]
    entries = {"law": cfg.law.entry}
    if ":" in cfg.vehicle.model:
        entries["vehicle"] = cfg.vehicle.model
    for j, f in enumerate(cfg.faults.plan):
        if f.model is not None:
            entries[f"faults.plan.{j}"] = f.model.entry
    return {
        "swarm_sitl": {"version": _version("swarm-sitl"), "git": _git_describe(root)},
        "python": platform.python_version(),
        **{name: _version(dist) for name, dist in _LIBRARIES.items()},
        "plugins": {
            what: {"entry": entry, "sha256": file_sha256(_source_file(entry))}
            for what, entry in entries.items()
        },
        "seeds": {"run": cfg.seed, **{name: seed for name, (seed, _) in cfg.seed_streams().items()}},
        "pinned_seeds": sorted(name for name, (_, pinned) in cfg.seed_streams().items() if pinned),
    }
