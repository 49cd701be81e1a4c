"""Where a campaign's runs go: this machine's cores (threads, each driving one ``swarm-sitl run``,
itself 2n + 1 processes), or a Dask distributed cluster (``--scheduler``), each worker running
whole swarms on its own host. Both call ``point.run_point`` on the same inputs, so a row is the
same wherever it ran (but its wall time)."""

import asyncio
import os
import threading
from collections.abc import Iterator
from concurrent.futures import FIRST_COMPLETED, ThreadPoolExecutor, wait
from dataclasses import dataclass
from typing import Any

from swarm_sitl.campaigns.point import run_point, stop_running


class SchedulerError(RuntimeError):
    """The Dask scheduler cannot be used (not installed, not reachable); one line."""


@dataclass
class Task:
    key: tuple[Any, ...]  #: the row's values and seed
    name: str  #: the point's file name (``points/NAME.yaml``)
    config_yaml: str
    keep_dir: str | None = None
    #: the files its plug-in entries name (``plugins/...``): shipped with it, never a path
    plugins: dict[str, bytes] | None = None
    timeout_s: float | None = None  #: its wall budget (``point.run_point``)


def default_jobs() -> int:
    """Runs at once on this machine: one per core (a lockstep run keeps about one core busy: its
    processes take turns)."""
    return max(1, len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1)


def run_local(tasks: list[Task], jobs: int) -> Iterator[tuple[Task, dict[str, Any]]]:
    """Each task's metrics as its run ends, ``jobs`` runs at once."""
    pool = ThreadPoolExecutor(max_workers=jobs, thread_name_prefix="sweep")
    try:
        yield from _as_done(
            {
                pool.submit(run_point, t.config_yaml, t.name, t.keep_dir, t.plugins, t.timeout_s): t
                for t in tasks
            }
        )
    except BaseException:
        pool.shutdown(wait=False, cancel_futures=True)
        stop_running()  # the runs under way end now, and are not rows
        raise
    finally:
        pool.shutdown(wait=True, cancel_futures=True)


def _as_done(futures: dict[Any, Task]) -> Iterator[tuple[Task, dict[str, Any]]]:
    pending = set(futures)
    while pending:
        done, pending = wait(pending, return_when=FIRST_COMPLETED)
        for f in done:
            yield futures[f], f.result()


def connect(address: str, timeout_s: float = 10.0) -> Any:
    """A Dask client of the scheduler at ``address`` (``tcp://host:8786``), or ``SchedulerError``
    within about ``timeout_s`` (Dask's own client waits for ever on an address that accepts a
    connection and never answers: another service's port)."""
    try:
        from distributed import Client
    except ImportError:
        raise SchedulerError(
            "--scheduler needs Dask's distributed scheduler: pip install 'swarm-sitl[cluster]'"
        ) from None
    try:
        _answers(address, timeout_s)
        return Client(address, timeout=f"{timeout_s}s", set_as_default=False)
    except (OSError, TimeoutError) as e:
        raise SchedulerError(f"cannot reach the Dask scheduler at {address} ({e})") from None
    except ValueError as e:
        raise SchedulerError(f"--scheduler {address}: {e}") from None


def _answers(address: str, timeout_s: float) -> None:
    """Returns once a Dask peer at ``address`` has answered the handshake of Dask's protocol;
    ``TimeoutError`` if none did within ``timeout_s``, else the error connecting raised. In a
    thread of its own, whose event loop is its own (the caller's may be running: a notebook)."""
    from distributed.comm import connect as dask_connect

    async def handshake() -> None:
        comm = await asyncio.wait_for(dask_connect(address), timeout_s)
        await comm.close()

    failed: list[BaseException] = []

    def dask_handshake() -> None:  # (the thread's name in a stack dump)
        try:
            asyncio.run(handshake())
        except BaseException as e:  # given to the caller
            failed.append(e)

    probe = threading.Thread(target=dask_handshake)
    probe.start()
    probe.join()  # (within the timeout: wait_for ends it)
    if failed:
        raise (
            TimeoutError(f"no answer within {timeout_s:g} s")
            if isinstance(failed[0], TimeoutError)
            else failed[0]
        )


def run_dask(tasks: list[Task], client: Any) -> Iterator[tuple[Task, dict[str, Any]]]:
    """Each task's metrics as its run ends, on the cluster's workers (one run per worker thread)."""
    from distributed import as_completed

    futures = {
        client.submit(
            run_point, t.config_yaml, t.name, None, t.plugins, t.timeout_s, pure=False, key=f"sweep-{t.name}"
        ): t
        for t in tasks
    }
    try:
        for f in as_completed(list(futures), loop=client.loop):
            yield futures[f], f.result()
    finally:
        client.cancel(list(futures))
