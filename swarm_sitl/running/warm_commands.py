"""``swarm-sitl`` commands started as processes of their own without an interpreter's start each:
forked from one warm server (``multiprocessing``'s fork server, its imports done once).

A campaign flies each point as ``swarm-sitl run`` in a process of its own (``campaigns.point``):
a run that fails or is killed takes nothing of the campaign with it. Started as a new
interpreter, each point spent 1.2-1.5 s of CPU importing numpy, numba, pydantic, pymavlink and
zenoh before its run began, on a machine whose cores the runs themselves share. Here the first
command starts the server (one interpreter, those imports) and every command is a fork of it:
its own pid and process in its caller's process group, its stdout and stderr in the files given,
the caller's environment and working directory at the time, ``ps`` showing the command line a
new interpreter would have had (``fork_server.become``, as a run's children become theirs); it
runs the ``swarm_sitl`` module as ``-m`` does and ends as the interpreter would (its exit
handlers run), with the exit code ``python -m swarm_sitl`` would have had (``-N`` when signal N
ended it). Commands may be started from any thread.

Where a fork server cannot be used (not Linux; a daemonic process, which may have no children:
a Dask worker), ``start`` starts a new interpreter instead, the same command with the same files.
"""

import atexit
import contextlib
import multiprocessing
import os
import runpy
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

#: what the server imports once, before its first fork: the command line and the run's modules
PRELOAD = [
    "swarm_sitl.cli",
    "swarm_sitl.commands.runs",
    "swarm_sitl.running.run",
    "swarm_sitl.running.sim",
    "swarm_sitl.nodes.entry",  # (what the run's own fork server imports before its first child)
    "sim_vehicles.__main__",
]

#: the command line a new interpreter runs ``swarm-sitl`` by; ``start`` forks what begins with it
CLI = [sys.executable, "-m", "swarm_sitl"]

_lock = threading.Lock()
_context: Any = None


def _forkserver() -> Any:
    """The fork server's context (started at its first process), or None where there is none."""
    global _context
    if not sys.platform.startswith("linux") or multiprocessing.current_process().daemon:
        return None
    with _lock:
        if _context is None:
            ctx = multiprocessing.get_context("forkserver")
            ctx.set_forkserver_preload(PRELOAD)
            _context = ctx
    return _context


def _command(argv: list[str], out_path: str, err_path: str, env: dict[str, str]) -> None:
    """In the forked process: become ``python -m swarm_sitl ARGV`` with stdout and stderr in the
    files and the caller's environment ``env`` (the server's is the one it started with), in the
    caller's process group as ``Popen`` leaves a child (Ctrl-C at a terminal reaches it), run it,
    end as it would."""
    from swarm_sitl.running.fork_server import become

    fds = (
        os.open(os.devnull, os.O_RDONLY),
        os.open(out_path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644),
        os.open(err_path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644),
    )
    become(fds, [*CLI, *argv], env, session=False)
    for fd in fds:
        os.close(fd)
    tempfile.tempdir = None  # (read from TMPDIR again, as a new interpreter would)
    sys.argv = ["-m", *argv]  # (runpy puts the module's file first, as -m does)
    try:
        runpy.run_module("swarm_sitl", run_name="__main__", alter_sys=True)  # (it ends in SystemExit)
        code: Any = 0
    except SystemExit as e:
        code = e.code
    finally:
        with contextlib.suppress(Exception):
            sys.stdout.flush()
            sys.stderr.flush()
    atexit._run_exitfuncs()  # (as the interpreter's end would: multiprocessing's does not)
    sys.exit(code)


class Command:
    """A started command: the part of ``subprocess.Popen`` a campaign uses."""

    def __init__(self, cmd: list[str], out_path: Path, err_path: Path):
        self.args = list(cmd)
        self.returncode: int | None = None
        ctx = _forkserver() if cmd[: len(CLI)] == CLI else None
        self._proc: Any
        if ctx is None:
            with open(out_path, "wb") as out, open(err_path, "wb") as err:
                self._proc = subprocess.Popen(cmd, stdout=out, stderr=err)
        else:
            args = (cmd[len(CLI) :], str(out_path), str(err_path), dict(os.environ))
            self._proc = ctx.Process(target=_command, args=args)
            self._proc.start()
        self.pid = self._proc.pid

    def poll(self) -> int | None:
        if self.returncode is None:
            if isinstance(self._proc, subprocess.Popen):
                self.returncode = self._proc.poll()
            elif not self._proc.is_alive():
                self._proc.join()
                self.returncode = self._proc.exitcode
        return self.returncode

    def wait(self, timeout: float | None = None) -> int:
        """Its exit code; ``subprocess.TimeoutExpired`` if it has not ended within ``timeout``."""
        end = None if timeout is None else time.monotonic() + timeout
        while (code := self.poll()) is None:
            left = None if end is None else end - time.monotonic()
            if left is not None and left <= 0:
                raise subprocess.TimeoutExpired(self.args, timeout or 0.0)
            if isinstance(self._proc, subprocess.Popen):
                with contextlib.suppress(subprocess.TimeoutExpired):
                    self._proc.wait(timeout=left)
            else:
                self._proc.join(left)
        return code

    def send_signal(self, sig: int) -> None:
        if self.poll() is None:
            with contextlib.suppress(ProcessLookupError):
                os.kill(self.pid, sig)

    def kill(self) -> None:
        self.send_signal(signal.SIGKILL)


def start(cmd: list[str], out_path: Path, err_path: Path) -> Command:
    """Command line ``cmd`` started as a process of its own, its stdout and stderr written to
    ``out_path`` and ``err_path``: ``swarm-sitl`` (``CLI`` and its arguments) forked from the warm
    server where there is one (module docstring), any other command line as it is."""
    return Command(cmd, out_path, err_path)
