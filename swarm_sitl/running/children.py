"""How the bench starts a child process: its command line and its environment.

A child is ``python -P -m MODULE`` (``module_argv``) with ``child_env()``, so it imports the same
``sim_vehicles`` and ``swarm_sitl`` as the process that starts it, installed or run from a checkout
without installing, whatever its working directory holds; and it carries ``PARENT_ENV`` (its
parent's pid: it dies with it, ``sim_vehicles.runtime.lifeline``).
"""

import os
import site
import sys
from collections.abc import Mapping
from pathlib import Path

from sim_vehicles.runtime.lifeline import ENV as PARENT_ENV

__all__ = ["PARENT_ENV", "child_env", "module_argv"]


def module_argv(module: str) -> list[str]:
    """``python -P -m module``, to run with ``child_env()``: a child imports the modules
    its parent imported. Without ``-P``, ``-m`` puts the working directory first on ``sys.path``,
    so a run started from a checkout beside an installed package ran its children from the
    checkout's sources, compiling every kernel again in each child (about 40 s of start-up on a
    fresh install) where the supervisor had just compiled them for the installed package."""
    return [sys.executable, "-P", "-m", module]


def child_env(base: Mapping[str, str] | None = None) -> dict[str, str]:
    """``base`` (default ``os.environ``) with the directory this package was imported from first on
    ``PYTHONPATH``, unless it is a site directory that every child searches anyway (putting one
    before the standard library would reorder more than our packages). So a child started with
    ``module_argv`` finds the same ``sim_vehicles`` and ``swarm_sitl`` as this process, installed
    or run from a checkout without installing."""
    env = dict(os.environ if base is None else base)
    root = Path(__file__).resolve().parents[2]
    sites = [*site.getsitepackages(), site.getusersitepackages()]
    if any(Path(d).resolve() == root for d in sites if d):
        return env
    env["PYTHONPATH"] = os.pathsep.join([str(root), *([env["PYTHONPATH"]] if env.get("PYTHONPATH") else [])])
    return env
