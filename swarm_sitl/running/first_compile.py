"""The compiled kernels of a fresh install: each compiled once, on two processes at once.

numba compiles a kernel the first time a process calls it and caches it on disk
(``sim_vehicles.common.jit``), so a fresh install pays for each kernel once. But ``sim`` calls
only the laws' and the plant's kernels and ``run`` also the wire's (MAVLink frames, signing,
the vehicle's one-call lockstep tick): the first ``sim`` compiled its half, the first ``run``
after it the other half, and a first ``run`` compiled both, one after the other, in one process.

``compile_once(cfg)``: on a cold cache (no ``MARKER`` in the cache directory of these sources),
the wire's kernels are compiled by a child process (``python -m swarm_sitl.running.first_compile``)
while this process compiles the laws' and the plant's for ``cfg`` (one tick of ``sim``), then the
marker is written: the first command that flies pays for every kernel once, on two cores, and
every later one loads them. A kernel whose code changes is compiled again, once: the cache
directory is named after the kernels' sources.
"""

import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

import numba

from swarm_sitl.config.schema import SwarmConfig
from swarm_sitl.running.children import child_env, module_argv

MARKER = "compiled"  #: in numba's cache directory: every kernel of the wire and of a flight is there


def _marker() -> Path:
    return Path(str(numba.config.CACHE_DIR)) / MARKER  # type: ignore[attr-defined]


def cold() -> bool:
    """Whether this install's kernels have not yet been compiled (``compile_once`` not done)."""
    return not _marker().is_file()


def wire_kernels() -> None:
    """The kernels of the wire: a vehicle's frames, signing and lockstep tick (and its plant's,
    for the default vehicle), as a vehicle loads them before it is ready."""
    import sim_vehicles.__main__ as vehicle
    from sim_vehicles.models.vehicle_config import VehicleConfig

    vehicle.warm_up(VehicleConfig())


def flight_kernels(cfg: SwarmConfig) -> None:
    """The kernels of one tick of ``cfg``'s swarm in ``sim`` under the paper's law (a user's law
    is built and guarded by the command itself): the law's, the vehicles'."""
    from swarm_sitl.running.sim import run_sim

    paper = cfg.model_copy(update={"faults": type(cfg.faults)(), "law": type(cfg.law)()})
    run_sim(paper, n_steps=1)


def compile_once(cfg: SwarmConfig, say: Callable[[str], None]) -> None:
    """On a cold cache, every kernel ``cfg``'s runs need, on two processes (module docstring);
    nothing otherwise. A child that fails costs only the parallelism: what it did not compile is
    compiled where it is first called, as before."""
    if not cold():
        return
    say("compiling the numerical kernels once for this install (on two processes; about 20 s)")
    child = subprocess.Popen(
        module_argv("swarm_sitl.running.first_compile"),
        env=child_env(),
        stdin=subprocess.DEVNULL,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    try:
        flight_kernels(cfg)
    except Exception:  # (the command itself says what fails, where it flies)
        pass
    finally:
        code = child.wait()
    if code == 0:
        try:
            _marker().parent.mkdir(parents=True, exist_ok=True)
            _marker().touch()
        except OSError:  # (a read-only cache: every process compiles or loads as before)
            pass


if __name__ == "__main__":
    wire_kernels()
    sys.exit(0)
