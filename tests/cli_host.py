"""``swarm-sitl`` (and a vehicle, ``python -m sim_vehicles``) for the tests, forked from a warm
interpreter instead of started as a new one.

A new ``python -m swarm_sitl`` spends 1.2-1.5 s of CPU before its command begins: importing numpy,
numba, pydantic, pymavlink and zenoh, and loading its kernels from numba's cache. The suite starts
a few hundred of them on two cores (``docs/performance.md``, *The test run*). So each pytest worker
starts one *host* the first time a test runs the command line: an interpreter that imports what
the commands run and loads the kernels once, then forks a child per command. The child is a
process of its own, as ``subprocess.Popen`` would have started it: its own pid, its standard
streams on the test's pipes, the test's working directory, environment and priority, the command
line that ``ps`` shows, a session of its own when asked; it then runs ``swarm_sitl.cli.main(argv)``
and ends as the interpreter ends (its threads joined, its exit handlers run), exactly as ``python
-m swarm_sitl ARGV`` would after its imports. What the command starts (its fork server, vehicles,
nodes, pool workers) it starts as it always does.

What a new interpreter would do differently, and so is run as one (``fresh=True``, or a
``NUMBA_*`` variable that is not the host's: numba reads them at its import): a test of the
install (which copy of the package a command imports) or of the interpreter's start itself.

Protocol, over a ``SOCK_SEQPACKET`` socket pair (one JSON object per packet):

- test -> host: ``{"module", "argv", "cwd", "env", "session", "nice"}`` with the child's stdin,
  stdout and stderr as three descriptors (``SCM_RIGHTS``);
- host -> test: ``{"pid": N}`` for each request, in order; ``{"exit": N, "code": C, "cpu_s": S}``
  when child N ends (C as ``Popen.returncode``: -signal if a signal ended it; S its CPU time and
  that of the children it reaped, as ``getrusage`` counts a reaped child's).

The host ends when the test's end of the socket closes (its worker is ending), once its children
have ended; the worker reaps it, so the CPU of every command is counted in the worker's children's.
"""

from __future__ import annotations

import atexit
import contextlib
import json
import os
import selectors
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import IO, Any

ROOT = Path(__file__).resolve().parents[1]
#: the modules a child may run as ``python -m``: the command line, and a vehicle
MODULES = ("swarm_sitl", "sim_vehicles")
#: ``swarm-sitl`` as a new interpreter runs it (the command line the children show)
CLI = [sys.executable, "-m", "swarm_sitl"]
#: what starts the host: this module's ``serve`` in a new interpreter, in the repository's root
HOST = [sys.executable, "-c", "from tests.cli_host import serve; serve()"]
#: the largest packet (a request with the test's environment)
PACKET_BYTES = 1 << 20


# -- the host ---------------------------------------------------------------------------------------
def _warm_up() -> None:
    """Import what the commands run and load the kernels of the paper's vehicle and law (what
    ``swarm-sitl run``'s fork server loads before its first child)."""
    import swarm_sitl.cli
    import swarm_sitl.running.run  # noqa: F401
    from swarm_sitl.running import fork_server

    fork_server._warm_up(str(ROOT / "configs" / "paper.yaml"))


def serve() -> None:
    """The host's loop (its stdin is its end of the socket pair): warm up, then fork a child per
    request until the socket closes. In a child this returns into ``_become``'s command, which
    raises ``SystemExit`` through here to the interpreter's own end."""
    sock = socket.socket(fileno=os.dup(0))
    null = os.open(os.devnull, os.O_RDONLY)
    os.dup2(null, 0)
    os.close(null)
    with contextlib.redirect_stdout(sys.stderr):
        _warm_up()
    sock.sendall(json.dumps({"ready": True}).encode())
    live: set[int] = set()
    while True:
        readable = select_one(sock, 0.02)
        if readable:
            packet, fds, _, _ = socket.recv_fds(sock, PACKET_BYTES, 3)
            if not packet:  # the worker is ending: reap what is left (its CPU is the run's), end
                for pid in live:
                    os.waitpid(pid, 0)
                return
            request = json.loads(packet)
            pid = os.fork()
            if pid == 0:
                sock.close()
                _become(request, fds)  # raises SystemExit
            for fd in fds:
                os.close(fd)
            live.add(pid)
            sock.sendall(json.dumps({"pid": pid}).encode())
        while live:
            pid, status, usage = os.wait4(-1, os.WNOHANG)
            if pid == 0:
                break
            live.discard(pid)
            cpu_s = usage.ru_utime + usage.ru_stime
            sock.sendall(
                json.dumps({"exit": pid, "code": os.waitstatus_to_exitcode(status), "cpu_s": cpu_s}).encode()
            )


def select_one(sock: socket.socket, timeout_s: float) -> bool:
    with selectors.DefaultSelector() as sel:
        sel.register(sock, selectors.EVENT_READ)
        return bool(sel.select(timeout_s))


def _become(request: dict[str, Any], fds: list[int]) -> None:
    """In a forked child: become ``python -m swarm_sitl ARGV`` as ``subprocess.Popen`` would have
    started it for the request, run the command, and end as that interpreter would."""
    import random
    import signal
    import tempfile

    import numpy as np
    from setproctitle import setproctitle

    if request["session"]:
        os.setsid()
    if request["nice"] > os.getpriority(os.PRIO_PROCESS, 0):
        os.setpriority(os.PRIO_PROCESS, 0, request["nice"])
    for target, fd in enumerate(fds):
        os.dup2(fd, target)
    for fd in fds:  # (the host's copies: all above 2, its own standard streams being open)
        with contextlib.suppress(OSError):
            os.close(fd)
    sys.stdin = open(0, closefd=False)  # noqa: SIM115
    sys.stdout = open(1, "w", closefd=False)  # noqa: SIM115
    sys.stderr = open(2, "w", buffering=1, closefd=False)  # noqa: SIM115
    argv, module = list(request["argv"]), request["module"]
    setproctitle(" ".join([sys.executable, "-m", module, *argv]))
    os.environ.clear()
    os.environ.update(request["env"])
    os.chdir(request["cwd"])
    sys.path[0] = os.getcwd()  # (as ``-m`` puts it)
    sys.argv = [str(ROOT / module / "__main__.py"), *argv]
    tempfile.tempdir = None  # (read again from TMPDIR)
    random.seed()
    np.random.seed()
    for sig in (signal.SIGTERM, signal.SIGHUP, signal.SIGCHLD):  # (SIGPIPE ignored, as Python starts)
        signal.signal(sig, signal.SIG_DFL)
    signal.signal(signal.SIGINT, signal.default_int_handler)
    if module == "sim_vehicles":
        from sim_vehicles.__main__ import main
    else:
        from swarm_sitl.cli import main
    raise SystemExit(main(argv))


# -- the tests' side --------------------------------------------------------------------------------
class _Host:
    """This process's host: started at the first request, ended with this process."""

    def __init__(self) -> None:
        from swarm_sitl.running.children import child_env

        mine, theirs = socket.socketpair(socket.AF_UNIX, socket.SOCK_SEQPACKET)
        self.env = env = child_env()  # (the packages this process imported, as a run's children)
        self.proc = subprocess.Popen(HOST, stdin=theirs, cwd=ROOT, env=env, start_new_session=True)
        theirs.close()
        self.sock = mine
        self.lock = threading.Lock()
        self.exits: dict[int, int] = {}
        self.pids: list[int] = []
        self.ready = False
        #: the CPU time of the commands that have ended (and of the children they reaped) [s]
        self.cpu_s = 0.0
        if not self._read(120.0) or not self.ready:
            raise RuntimeError(f"the tests' swarm-sitl host did not start (exit {self.proc.poll()})")

    def _read(self, timeout_s: float | None) -> bool:
        """Take one message from the host if one comes within ``timeout_s``."""
        if not select_one(self.sock, timeout_s if timeout_s is not None else 3600.0):
            return False
        packet = self.sock.recv(PACKET_BYTES)
        if not packet:
            raise RuntimeError(f"the tests' swarm-sitl host ended (exit {self.proc.poll()})")
        msg = json.loads(packet)
        if "ready" in msg:
            self.ready = True
        elif "pid" in msg:
            self.pids.append(msg["pid"])
        else:
            self.exits[msg["exit"]] = msg["code"]
            self.cpu_s += msg["cpu_s"]
        return True

    def fork(
        self, module: str, argv: list[str], cwd: str, env: dict[str, str], session: bool, fds: list[int]
    ) -> int:
        request = {
            "module": module,
            "argv": argv,
            "cwd": cwd,
            "env": env,
            "session": session,
            "nice": os.nice(0),
        }
        with self.lock:
            socket.send_fds(self.sock, [json.dumps(request).encode()], fds)
            while not self.pids:
                self._read(None)
            return self.pids.pop(0)

    def code(self, pid: int, timeout_s: float | None) -> int | None:
        """Child ``pid``'s exit code, waiting up to ``timeout_s`` (0: not at all) for it."""
        end = None if timeout_s is None else time.monotonic() + timeout_s
        with self.lock:
            while pid not in self.exits:
                left = None if end is None else end - time.monotonic()
                if left is not None and left <= 0:
                    while self._read(0.0):
                        pass
                    break
                self._read(left)
            return self.exits.get(pid)


_host: _Host | None = None


def host() -> _Host:
    global _host
    if _host is None or _host.proc.poll() is not None:
        _host = _Host()
        atexit.register(_end, _host)
    return _host


def _end(h: _Host) -> None:
    """At this process's end: close the host's socket and reap it (it reaps its children first),
    so that what they spent is counted where this process's children's time is."""
    h.sock.close()
    with contextlib.suppress(subprocess.TimeoutExpired):
        h.proc.wait(timeout=60)


def forkable(env: dict[str, str] | None) -> bool:
    """Whether a command with environment ``env`` may run forked from the host: numba's
    variables, read at its import, are the host's."""
    ours = _host.env if _host is not None else os.environ
    env = os.environ if env is None else env
    keys = {k for k in [*env, *ours] if k.startswith("NUMBA_")}
    return all(env.get(k) == ours.get(k) for k in keys)


class ForkedCli:
    """The part of ``subprocess.Popen`` the tests use, for ``swarm-sitl ARGV`` (``module``:
    ``python -m MODULE ARGV``, one of ``MODULES``) forked from the host. ``stdin``, ``stdout``,
    ``stderr``: ``subprocess.PIPE``, ``DEVNULL``, ``None`` (this process's own), a file object or a
    descriptor, as ``Popen`` takes them."""

    def __init__(
        self,
        args: list[str],
        *,
        stdin: Any = subprocess.DEVNULL,
        stdout: Any = None,
        stderr: Any = None,
        cwd: Any = None,
        env: dict[str, str] | None = None,
        text: bool = False,
        start_new_session: bool = False,
        module: str = "swarm_sitl",
    ):
        if module not in MODULES:
            raise ValueError(f"the host runs {MODULES}, not {module!r}")
        self.args = [sys.executable, "-m", module, *args]
        self.returncode: int | None = None
        self._host = host()
        child_fds, ours = [], []
        self.stdin: IO[Any] | None = None
        self.stdout: IO[Any] | None = None
        self.stderr: IO[Any] | None = None
        for k, spec in enumerate((stdin, stdout, stderr)):
            if spec is subprocess.PIPE:
                r, w = os.pipe()
                child, mine = (r, w) if k == 0 else (w, r)
                ours.append(child)
                mode = "w" if k == 0 else "r"
                setattr(self, ("stdin", "stdout", "stderr")[k], open(mine, mode if text else mode + "b"))  # noqa: SIM115
            elif spec is subprocess.DEVNULL:
                child = os.open(os.devnull, os.O_RDWR)
                ours.append(child)
            elif spec is subprocess.STDOUT:
                child = child_fds[1]
            elif spec is None:
                child = k
            else:
                child = spec if isinstance(spec, int) else spec.fileno()
            child_fds.append(child)
        env = dict(os.environ if env is None else env)
        try:
            self.pid = self._host.fork(
                module, [str(a) for a in args], str(cwd or os.getcwd()), env, start_new_session, child_fds
            )
        finally:
            for fd in ours:
                os.close(fd)

    def poll(self) -> int | None:
        if self.returncode is None:
            self.returncode = self._host.code(self.pid, 0.0)
        return self.returncode

    def wait(self, timeout: float | None = None) -> int:
        if self.returncode is None:
            self.returncode = self._host.code(self.pid, timeout)
            if self.returncode is None:
                raise subprocess.TimeoutExpired(self.args, timeout or 0.0)
        return self.returncode

    def communicate(self, input: Any = None, timeout: float | None = None) -> tuple[Any, Any]:
        """Read ``stdout`` and ``stderr`` (those piped) to their end, then wait: as ``Popen``'s."""
        if self.stdin is not None:
            with contextlib.suppress(BrokenPipeError):
                if input:
                    self.stdin.write(input)
                self.stdin.close()
        end = None if timeout is None else time.monotonic() + timeout
        got: dict[int, list[Any]] = {}
        with selectors.DefaultSelector() as sel:
            for k, stream in ((1, self.stdout), (2, self.stderr)):
                if stream is not None and not stream.closed:
                    got[k] = []
                    sel.register(stream, selectors.EVENT_READ, k)
            while sel.get_map():
                left = None if end is None else end - time.monotonic()
                if left is not None and left <= 0:
                    raise subprocess.TimeoutExpired(self.args, timeout or 0.0)
                for key, _ in sel.select(left):
                    chunk = os.read(key.fd, 65536)
                    if chunk:
                        got[key.data].append(chunk)
                    else:
                        sel.unregister(key.fileobj)
        outs = []
        for k, stream in ((1, self.stdout), (2, self.stderr)):
            if k not in got:
                outs.append(None)
                continue
            data = b"".join(got[k])
            text = "b" not in stream.mode  # type: ignore[union-attr]
            # (as ``Popen`` in text mode: universal newlines)
            outs.append(data.decode().replace("\r\n", "\n").replace("\r", "\n") if text else data)
            stream.close()  # type: ignore[union-attr]
        self.wait(None if end is None else max(0.0, end - time.monotonic()))
        return outs[0], outs[1]

    def send_signal(self, sig: int) -> None:
        if self.poll() is None:
            with contextlib.suppress(ProcessLookupError):
                os.kill(self.pid, sig)

    def terminate(self) -> None:
        self.send_signal(15)

    def kill(self) -> None:
        self.send_signal(9)

    def __enter__(self) -> ForkedCli:
        return self

    def __exit__(self, *exc: object) -> None:
        for stream in (self.stdin, self.stdout, self.stderr):
            if stream is not None:
                stream.close()
        self.wait()


def run(
    args: list[str],
    timeout: float,
    cwd: Any = None,
    env: dict[str, str] | None = None,
    module: str = "swarm_sitl",
) -> subprocess.CompletedProcess[str]:
    """``subprocess.run(CLI + args, capture_output=True, text=True, timeout=...)``, forked."""
    pipe = subprocess.PIPE
    proc = ForkedCli(args, stdout=pipe, stderr=pipe, cwd=cwd, env=env, text=True, module=module)
    try:
        out, err = proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()
        raise
    return subprocess.CompletedProcess(proc.args, proc.returncode or 0, out, err)
