"""Start a run's processes by forking one warmed-up parent: each vehicle and node without its own
interpreter start, imports and kernel loads.

A fresh ``python -m swarm_sitl.nodes controller ...`` spends about a second of CPU importing numpy,
numba, pydantic, pymavlink and zenoh and loading its compiled kernels before it does anything;
a run of N followers starts 2N + 1 of them on a machine of two cores. The fork server is one
process that does that once (``serve``), then forks a child per request. Each child is still its
own process with its own sockets, zenoh session, pid and log, in its own session (``setsid``),
exactly as ``subprocess.Popen`` would have started it; it then runs the same ``main(argv)`` as
``python -m`` of its module would have (``sim_vehicles``' or ``swarm_sitl.nodes``').

Protocol (pipes between the supervisor and the server, one JSON object per line):

- supervisor -> server: ``{"module": "sim_vehicles" | "swarm_sitl.nodes", "argv": [...], "env": {...},
  "log": PATH}``;
- server -> supervisor: ``{"ready": true}`` once warmed up; ``{"pid": N}`` for each request, in
  order; ``{"exit": N, "code": C}`` when child N ends (C as ``Popen.returncode``: -signal if a
  signal ended it).

The server is forked before any zenoh session exists in it (zenoh's runtime starts with the first
session, and a fork does not carry threads), and it dies with the supervisor (``hold_on``), its
children with it. Linux only (``os.fork`` with ``prctl``); elsewhere ``run.start: spawn`` is used.

**Where the server comes from.** ``ForkServer(argv, ...)`` starts it as a new interpreter
(``python -m swarm_sitl.running.fork_server CONFIG``). ``ForkServer(..., here=True)`` forks it
from the calling process instead, when that is safe (``can_fork_here``: one thread, and the
caller vouches that no zenoh session was ever opened in it, as ``swarm-sitl run`` can): the
server then starts with what the caller has imported (numpy, numba, pydantic, the config's
modules: half a second of a run's start-up and of its CPU, paid once instead of twice). Either
way it is the same server: the same protocol, session, log, environment and title
(``fork_server`` on its command line), and it ends with ``os._exit``, running none of the
caller's exit handlers.
"""

import contextlib
import json
import os
import random
import select
import shlex
import signal
import subprocess
import sys
import threading
import time
import traceback
from pathlib import Path
from typing import IO, Any, NoReturn

from setproctitle import setproctitle

from swarm_sitl.running.children import PARENT_ENV, module_argv

#: the modules a child may run: a vehicle, or a node (``nodes.entry``)
ENTRY_MODULES = ("sim_vehicles", "swarm_sitl.nodes")


class ForkServerError(RuntimeError):
    """The fork server did not start, ended, or could not start a child; the message says which."""


def become(fds: tuple[int, int, int], argv: list[str], env: dict[str, str], session: bool = True) -> None:
    """In a forked process: become what ``subprocess.Popen`` would have started for command line
    ``argv`` with ``env``, in a session of its own (``session``; else in its parent's process
    group, as ``Popen`` leaves a child), ``fds`` its stdin, stdout and stderr (and Python's streams
    on them). (Also ``warm_commands``': a campaign's forked runs.)"""
    if session:
        os.setsid()
    for target, fd in enumerate(fds):
        os.dup2(fd, target)
    sys.stdin = open(0, closefd=False)  # noqa: SIM115
    sys.stdout = open(1, "w", buffering=1, closefd=False)  # noqa: SIM115
    sys.stderr = open(2, "w", buffering=1, closefd=False)  # noqa: SIM115
    # ps, top and pgrep show the command line Popen would have started (before the environment
    # changes: setproctitle takes its room from where the environment's strings lie)
    setproctitle(" ".join(shlex.quote(a) for a in argv))
    os.environ.clear()
    os.environ.update(env)
    random.seed()  # the parent's generator state is not this process's


def _run_child(request: dict[str, Any], fd: int) -> int:
    """In the forked child: become the process the request describes (``fd``: its log, opened by
    the server so that it exists when the pid is answered), run it, return its code."""
    signal.signal(signal.SIGCHLD, signal.SIG_DFL)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    signal.signal(signal.SIGINT, signal.SIG_DFL)
    null = os.open(os.devnull, os.O_RDONLY)
    become((null, fd, fd), [*module_argv(request["module"]), *request["argv"]], request["env"])
    os.close(fd)
    os.close(null)
    os.environ[PARENT_ENV] = str(os.getppid())  # hold_on(): this process dies with the server
    module, argv = request["module"], list(request["argv"])
    sys.argv = [module, *argv]
    # imported here, not at the top: this module is also the supervisor's side of the server
    # (``ForkServer``), which needs none of what the children run; the server has them already
    try:
        if module == "sim_vehicles":
            from sim_vehicles.__main__ import main as vehicle_main

            return int(vehicle_main(argv) or 0)
        from swarm_sitl.nodes.entry import main as node_main

        return int(node_main(argv) or 0)
    except SystemExit as e:
        return e.code if isinstance(e.code, int) else (0 if e.code is None else 1)
    except BaseException:
        traceback.print_exc()
        return 1


def _warm_up(config_path: str | None) -> None:
    """Import what the children run and load the compiled kernels into this process (the server's
    work, so imported here: the supervisor imports this module for ``ForkServer`` only)."""
    import sim_vehicles.__main__
    import swarm_sitl.nodes.entry  # noqa: F401  (every node's modules: its link, bus, faults, laws)
    from sim_vehicles.models.vehicle_config import VehicleConfig

    # the kernels a vehicle and a controller load before they declare themselves ready: the plant,
    # the attitude loop and the per-tick MAVLink frames (each child loaded them from numba's cache,
    # over 0.1 s of CPU apiece, 64 of them at once on two cores in a 64-follower start)
    sim_vehicles.__main__.warm_up(VehicleConfig())  # frames' kernels too
    if config_path:
        from swarm_sitl.config.load import load_config
        from swarm_sitl.running.sim import run_sim

        # stdout is the supervisor's channel: what a user's law prints (on import, building, its
        # first tick) goes to the server's log
        with contextlib.redirect_stdout(sys.stderr):
            run_sim(load_config(config_path), n_steps=1)


def _send(out: IO[str], msg: dict[str, Any]) -> None:
    out.write(json.dumps(msg) + "\n")
    out.flush()


def serve(config_path: str | None) -> int:
    """The server's loop: warm up, then fork a child per request line on stdin until stdin closes
    and every child has ended."""
    from sim_vehicles.runtime.lifeline import hold_on, settle_heap

    hold_on()
    _warm_up(config_path)
    settle_heap()
    out = sys.stdout
    _send(out, {"ready": True})
    live: set[int] = set()
    stdin_open = True
    buf = b""
    while stdin_open or live:
        if stdin_open:
            readable, _, _ = select.select([0], [], [], 0.02)
            if readable:
                chunk = os.read(0, 65536)
                if not chunk:
                    stdin_open = False
                buf += chunk
                while b"\n" in buf:
                    line, buf = buf.split(b"\n", 1)
                    request = json.loads(line)
                    try:
                        fd = os.open(request["log"], os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
                    except OSError as e:
                        _send(out, {"error": f"cannot open {request['log']}: {e.strerror}"})
                        continue
                    pid = os.fork()
                    if pid == 0:
                        code = 1
                        try:
                            code = _run_child(request, fd)
                        finally:
                            with contextlib.suppress(Exception):
                                sys.stdout.flush()
                                sys.stderr.flush()
                            os._exit(code & 0xFF if code >= 0 else 1)
                    os.close(fd)
                    live.add(pid)
                    _send(out, {"pid": pid})
        else:
            time.sleep(0.02)
        while live:
            try:
                pid, status = os.waitpid(-1, os.WNOHANG)
            except ChildProcessError:
                live.clear()
                break
            if pid == 0:
                break
            live.discard(pid)
            _send(out, {"exit": pid, "code": os.waitstatus_to_exitcode(status)})
    return 0


def can_fork_here() -> bool:
    """Whether this process may fork a server from itself (``ForkServer(..., here=...)``): it
    runs one Python thread, and no native thread but those named as it is (a C library's pool,
    numpy's BLAS: they are made to survive a fork). A fork carries only the calling thread:
    another's locks would stay held in the copy, and a zenoh runtime (its threads are named
    ``acc-0``, ``net-0``, ...) would be a husk. That no zenoh session was ever opened in this
    process is the caller's to vouch for all the same."""
    if not sys.platform.startswith("linux") or threading.active_count() != 1:
        return False
    try:
        names = {Path(f"/proc/self/task/{t}/comm").read_text() for t in os.listdir("/proc/self/task")}
    except OSError:
        return False
    return len(names) == 1


def _serve_here(argv: list[str], env: dict[str, str], fds: tuple[int, int, int]) -> NoReturn:
    """In a server forked from its supervisor: become what its command line ``argv`` with ``env``
    would be (``fds``: its stdin, stdout and stderr), serve, and end without running anything of
    the supervisor's (its exit handlers, its objects' finalizers)."""
    code = 1
    try:
        become(fds, argv, env)
        for fd in _open_fds():  # (as Popen's close_fds: the children inherit only their own)
            if fd > 2:
                with contextlib.suppress(OSError):
                    os.close(fd)
        for sig in (signal.SIGTERM, signal.SIGHUP, signal.SIGCHLD):
            signal.signal(sig, signal.SIG_DFL)
        signal.signal(signal.SIGINT, signal.default_int_handler)
        args = argv[len(module_argv(__name__)) :]
        sys.argv = [__name__, *args]
        print(f"fork server: forked from its supervisor (pid {os.getppid()})", file=sys.stderr)
        code = main(args)
    except SystemExit as e:
        code = e.code if isinstance(e.code, int) else (0 if e.code is None else 1)
    except BaseException:
        with contextlib.suppress(Exception):
            traceback.print_exc()
    finally:
        with contextlib.suppress(Exception):
            sys.stdout.flush()
            sys.stderr.flush()
        os._exit(code & 0xFF if code >= 0 else 1)


def _wait(poll: Any, timeout: float | None, what: str) -> int:
    """``Popen.wait`` for a process known by its ``poll``: its code, or ``TimeoutExpired``."""
    end = None if timeout is None else time.monotonic() + timeout
    while (code := poll()) is None:
        if end is not None and time.monotonic() > end:
            raise subprocess.TimeoutExpired(what, timeout or 0.0)
        time.sleep(0.005)
    return int(code)


def _open_fds() -> list[int]:
    try:
        return [int(x) for x in os.listdir("/proc/self/fd")]
    except OSError:
        return list(range(3, 256))


class _ServerHere:
    """The part of ``subprocess.Popen`` ``ForkServer`` uses, for a server forked here."""

    def __init__(self, argv: list[str], env: dict[str, str], log_fd: int):
        r_in, self._w_in = os.pipe()
        self._r_out, w_out = os.pipe()
        for stream in (sys.stdout, sys.stderr):  # (else the copy's buffers would be written twice)
            with contextlib.suppress(Exception):
                stream.flush()
        self.pid = os.fork()
        if self.pid == 0:
            _serve_here(argv, env, (r_in, w_out, log_fd))
        os.close(r_in)
        os.close(w_out)
        self.stdin: IO[bytes] | None = open(self._w_in, "wb")  # noqa: SIM115  (closed by ForkServer)
        self.stdout: IO[bytes] | None = open(self._r_out, "rb", buffering=0)  # noqa: SIM115
        self.returncode: int | None = None

    def poll(self) -> int | None:
        if self.returncode is None:
            try:
                pid, status = os.waitpid(self.pid, os.WNOHANG)
            except ChildProcessError:
                pid, status = self.pid, 0
            if pid:
                self.returncode = os.waitstatus_to_exitcode(status)
        return self.returncode

    def wait(self, timeout: float | None = None) -> int:
        return _wait(self.poll, timeout, f"fork server {self.pid}")

    def kill(self) -> None:
        if self.poll() is None:
            with contextlib.suppress(ProcessLookupError):
                os.kill(self.pid, signal.SIGKILL)


class ForkedProcess:
    """The part of ``subprocess.Popen`` the supervisor uses, for a child of the fork server.

    Requests are pipelined: ``ForkServer.spawn`` returns at once and the pid is learnt from the
    server's answers, in request order, when first needed (the supervisor asks for all of a run's
    processes without waiting for each fork in turn)."""

    def __init__(self, server: "ForkServer"):
        self.server = server
        self._pid: int | None = None
        self.returncode: int | None = None
        self.error = ""  #: why the server could not start it (then ``returncode`` is 1)

    @property
    def pid(self) -> int:
        while self._pid is None and not self.error:
            self.server.pump(block_s=1.0)
        return -1 if self._pid is None else self._pid

    def poll(self) -> int | None:
        if self.returncode is None:
            self.server.pump()
        return self.returncode

    def wait(self, timeout: float | None = None) -> int:
        return _wait(self.poll, timeout, f"pid {self._pid}")

    def send_signal(self, sig: int) -> None:
        if self.poll() is None and self.pid > 0:
            os.kill(self.pid, sig)


class ForkServer:
    """The supervisor's side: start the server, ask it for children, learn when they end."""

    def __init__(
        self,
        argv: list[str],
        env: dict[str, str],
        log_path: Path,
        timeout_s: float = 120.0,
        here: bool = False,
    ):
        """``argv``: the server's command line (``module_argv`` of this module, then its config if
        any); ``here``: fork it from this process instead of starting it (module docstring), which
        the caller has checked with ``can_fork_here``: ``argv`` is then its title and arguments."""
        self._log = open(log_path, "wb")  # noqa: SIM115  (closed in close())
        self.proc: subprocess.Popen[bytes] | _ServerHere
        if here:
            self.proc = _ServerHere(argv, env, self._log.fileno())
        else:
            self.proc = subprocess.Popen(
                argv,
                stdin=subprocess.PIPE,
                stdout=subprocess.PIPE,
                stderr=self._log,
                env=env,
                start_new_session=True,
            )
        self._buf = b""
        self._pending: list[ForkedProcess] = []  #: asked for, pid not yet answered, in order
        self._children: dict[int, ForkedProcess] = {}
        self._exits: dict[int, int] = {}
        self._log_path = log_path
        self._timeout_s = timeout_s
        self._ready = False  # it warms up while the caller does other things; spawn() waits

    def _wait_ready(self) -> None:
        if self._ready:
            return
        msg = self._next(self._timeout_s)
        if msg is None or not msg.get("ready"):
            last = self._log_path.read_text(errors="replace").strip().splitlines()[-1:] or [""]
            raise ForkServerError(f"the fork server did not start: {last[0]} (log: {self._log_path})")
        self._ready = True

    def _next(self, timeout_s: float | None) -> dict[str, Any] | None:
        """The next message; None if the server ended (or nothing came within ``timeout_s``)."""
        assert self.proc.stdout is not None
        end = None if timeout_s is None else time.monotonic() + timeout_s
        while b"\n" not in self._buf:
            wait = 0.0 if end is None else max(0.0, end - time.monotonic())
            readable, _, _ = select.select([self.proc.stdout], [], [], wait)
            if not readable:
                return None
            chunk = os.read(self.proc.stdout.fileno(), 65536)
            if not chunk:
                return None
            self._buf += chunk
        line, self._buf = self._buf.split(b"\n", 1)
        try:
            msg: dict[str, Any] = json.loads(line)
        except ValueError:
            raise ForkServerError(
                f"the fork server wrote something it should not on its channel: {line[:80]!r}"
            ) from None
        return msg

    def _take(self, msg: dict[str, Any]) -> None:
        if "pid" in msg or "error" in msg:
            child = self._pending.pop(0)
            if "error" in msg:
                child.error = str(msg["error"])
                child.returncode = 1
                return
            child._pid = int(msg["pid"])
            self._children[child._pid] = child
            if child._pid in self._exits:
                child.returncode = self._exits.pop(child._pid)
        elif "exit" in msg:
            pid, code = int(msg["exit"]), int(msg["code"])
            if pid in self._children:
                self._children[pid].returncode = code
            else:
                self._exits[pid] = code

    def spawn(self, module: str, argv: list[str], env: dict[str, str], log_path: Path) -> ForkedProcess:
        """Ask for a child; returns at once (its pid comes with the server's answer)."""
        assert self.proc.stdin is not None
        self._wait_ready()
        if self.proc.poll() is not None:
            raise ForkServerError(
                f"the fork server ended (code {self.proc.returncode}; log: {self._log_path})"
            )
        request = {"module": module, "argv": argv, "env": env, "log": str(log_path)}
        child = ForkedProcess(self)
        self._pending.append(child)
        try:
            self.proc.stdin.write((json.dumps(request) + "\n").encode())
            self.proc.stdin.flush()
        except OSError as e:
            raise ForkServerError(f"the fork server stopped taking requests ({e.strerror})") from None
        return child

    def pump(self, block_s: float = 0.0) -> None:
        """Take every answer and exit the server has reported (waiting up to ``block_s`` for the
        first); if the server itself is gone, its children are too (they die with it): each still
        unaccounted for is marked killed."""
        msg = self._next(block_s)
        while msg is not None:
            self._take(msg)
            msg = self._next(0.0)
        if self.proc.poll() is not None:
            for child in [*self._pending, *self._children.values()]:
                if child.returncode is None:
                    child.returncode = -signal.SIGKILL
                if child._pid is None and not child.error:
                    child.error = "the fork server ended before it started this process"
            self._pending.clear()

    def close(self) -> None:
        if self.proc.stdin is not None:
            with contextlib.suppress(OSError):
                self.proc.stdin.close()
        try:
            self.proc.wait(timeout=5.0)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()
        self._log.close()


def main(argv: list[str] | None = None) -> int:
    args = sys.argv[1:] if argv is None else argv
    return serve(args[0] if args else None)


if __name__ == "__main__":
    sys.exit(main())
