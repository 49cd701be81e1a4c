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

import platform
import subprocess
from importlib import metadata
from pathlib import Path
from typing import Any

from swarm_sitl.config.schema import SwarmConfig
from swarm_sitl.rundir.plugins import entries, file_sha256, source_file

_LIBRARIES = {"numpy": "numpy", "numba": "numba", "zenoh": "eclipse-zenoh", "pymavlink": "pymavlink"}
GIT_TIMEOUT_S = 2.0  #: the longest ``git describe`` may take before it is left out [s]


def _version(distribution: str) -> str | None:
    try:
        return metadata.version(distribution)
    except metadata.PackageNotFoundError:
        return None


def git_describe(root: Path) -> str | None:
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


def provenance(cfg: SwarmConfig, kept: dict[str, Any] | None = None) -> dict[str, Any]:
    """``summary.json``'s ``provenance`` of a run of ``cfg`` (module docstring); ``kept``: the
    run directory's record of its plug-ins (``plugins.json``), whose hashes it takes (a config
    read from a run directory hashes nothing: its plug-ins are not looked for)."""
    plugins = {
        what: {"entry": entry, "sha256": None if cfg.is_recorded else file_sha256(source_file(entry))}
        for what, entry in entries(cfg.model_dump(mode="json")).items()
    }
    for what, k in (kept or {}).items():
        if what in plugins and isinstance(k, dict):
            plugins[what] = {"entry": k.get("entry"), "sha256": k.get("sha256"), "kept": k.get("kept")}
    root = Path(__file__).resolve().parents[2]
    return {
        "swarm_sitl": {"version": _version("swarm-sitl"), "git": git_describe(root)},
        "python": platform.python_version(),
        **{name: _version(dist) for name, dist in _LIBRARIES.items()},
        "plugins": plugins,
        "seeds": {"run": cfg.seed, **{name: seed for name, (seed, _) in cfg.seed_streams().items()}},
        "pinned_seeds": sorted(name for name, (_, pinned) in cfg.seed_streams().items() if pinned),
    }
