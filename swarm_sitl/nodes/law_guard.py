"""What keeps a user's law from hanging, ending or flooding the process that hosts it (``sim``, a
controller): ``LawGuard``, around each step of a ``law_host.HostedLaw``.

- **A step that outlasts ``run.tick_timeout_s``** is stopped by a watchdog thread: ``LawStopped`` is
  raised in the thread that steps the law (by a signal when it is the main thread, so a sleep and a
  pure Python loop both end; by ``PyThreadState_SetAsyncExc`` in another thread), and the host
  turns it into its ``LawError`` of one line naming the law, the follower, the tick and the wait.
  A step that still has not returned ``HARD_STOP_S`` later holds the interpreter in compiled code:
  the guard writes the line to the process's stderr (or gives it to ``on_hard_stop``, which keeps
  what it can: a controller flushes its rows, ``sim`` writes its run directory) and ends the
  process with code 1 (a controller's supervisor names it from its log).
- **Memory**: the process's resident memory may grow by ``law.max_memory_mb`` over what it was
  when the guard started (the law built, its first ticks warmed up); past it, the same stop: at
  the end of the step that took it there (``after_step``: the process's peak, one system call,
  read after every step, so in ``sim``, where several laws share the process, the follower
  named is the one whose step grew it), or by the watchdog while a step that never returns grows
  it.
- **An exit**: ``sys.exit`` raises ``SystemExit``, which the host catches like any error;
  ``os._exit``, which would end the process on the spot, is replaced while a step runs (in the
  thread that steps) by a raise of ``LawExit``, so the one line names the call and its code.
- **Output**: what the law prints while it steps goes to ``output`` (a controller's process log;
  ``sim``: ``RUN_DIR/logs/laws.log``) up to ``law.max_output_mb``; the rest is dropped and counted,
  one line saying so at the limit and one at the end.
"""

import ctypes
import io
import math
import os
import resource
import signal
import sys
import threading
import time
from collections.abc import Callable
from typing import IO, Any, NoReturn

#: how often the watchdog looks at the step in progress and the memory [s]
WATCH_EVERY_S = 0.05
#: a step stopped that has not returned this long after: the process ends (exit code 1) [s]
HARD_STOP_S = 2.0
_SIGNAL = signal.SIGUSR2
_REAL_EXIT = os._exit
_PAGE_BYTES = os.sysconf("SC_PAGE_SIZE") if hasattr(os, "sysconf") else 4096


class LawStopped(BaseException):
    """Raised in a law's step by its guard: the step outlasted its time, or the memory its bound.
    A ``BaseException``: a law's ``except Exception`` does not swallow it."""


class LawExit(SystemExit):
    """A law called ``os._exit(code)`` while it stepped."""


def resident_bytes() -> int | None:
    """This process's resident memory (Linux ``/proc``; None elsewhere)."""
    try:
        with open("/proc/self/statm") as f:
            return int(f.read().split()[1]) * _PAGE_BYTES
    except (OSError, ValueError, IndexError):
        return None


class BoundedOutput(io.TextIOBase):
    """Text to ``target`` up to ``limit_bytes`` (counted as characters written); past it dropped,
    counted, and said once."""

    def __init__(self, target: IO[str], limit_bytes: int, what: str):
        self.target = target
        self.limit = limit_bytes
        self.what = what  #: the config key that sets the limit, for the lines
        self.written = 0
        self.dropped = 0

    def writable(self) -> bool:
        return True

    def write(self, s: str) -> int:
        n = len(s)
        room = self.limit - self.written
        if n <= room:
            self.written += n
            self.target.write(s)
            return n
        if room > 0:
            self.target.write(s[:room])
            self.written = self.limit
        if self.dropped == 0:
            self.target.write(
                f"\n[swarm-sitl: the law's output reached {self.limit} bytes ({self.what}); the rest "
                "is dropped and counted]\n"
            )
        self.dropped += n - max(room, 0)
        return n

    def flush(self) -> None:
        self.target.flush()

    def closing_line(self) -> str:
        return f"[swarm-sitl: {self.dropped} bytes of the law's output dropped ({self.what})]\n"


class LawGuard:
    """The guard of the laws one thread steps (``enter`` and ``leave`` around each step)."""

    def __init__(
        self,
        tick_timeout_s: float,
        max_memory_mb: float | None,
        output: IO[str] | None,
        max_output_bytes: int,
        on_hard_stop: Callable[[str], None] | None = None,
    ):
        self.tick_timeout_s = tick_timeout_s
        self.max_memory_bytes = None if max_memory_mb is None else max_memory_mb * 1e6
        self._output = None
        if output is not None:
            self._output = BoundedOutput(output, max_output_bytes, "law.max_output_mb")
        self._on_hard_stop = on_hard_stop
        self._tid = threading.get_ident()
        self._main = threading.current_thread() is threading.main_thread()
        self._seq = 0
        self._since: float | None = None  #: when the step in progress began (monotonic s)
        self._who: tuple[str, int, float] = ("", 0, 0.0)  #: the step in progress: law, follower, t
        self._reason: str | None = None  #: why the step in progress is stopped
        self._stopped_seq = -1
        self._over: str | None = None  #: the memory is past its bound (stop at the next step)
        self._saved: tuple[Any, Any, Any] | None = None
        self._baseline = resident_bytes()
        self._done = threading.Event()
        self._old_handler: Any = None
        if self._main:
            self._old_handler = signal.signal(_SIGNAL, self._on_signal)
        self._thread = threading.Thread(target=self._watch, name="law-guard", daemon=True)
        self._thread.start()

    # -- the stepping thread ---------------------------------------------------------------------
    def enter(self, law: str, follower: int, t_s: float) -> None:
        """Follower ``follower``'s step at ``t_s`` begins (``law``: its entry); ``LawStopped`` if
        the memory is past its bound already."""
        if self._over is not None:
            raise LawStopped(self._over)
        self._seq += 1
        self._who = (law, follower, t_s)
        self._saved = (os._exit, sys.stdout, sys.stderr)
        os._exit = self._exit  # type: ignore[assignment]
        if self._output is not None:
            sys.stdout = sys.stderr = self._output
        self._since = time.monotonic()

    def after_step(self) -> None:
        """The step returned: ``LawStopped`` if it took the memory past its bound. The peak
        resident memory bounds the resident memory, so /proc is read only once the peak is past."""
        if self.max_memory_bytes is None or self._baseline is None:
            return
        peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024  # (Linux: in kB)
        if peak - self._baseline <= self.max_memory_bytes:
            return
        memory = self._memory_line()
        if memory is not None:
            self._over = memory
            raise LawStopped(memory)

    def leave(self) -> None:
        """The step is over (returned or raised)."""
        self._since = None
        if self._saved is not None:
            os._exit, sys.stdout, sys.stderr = self._saved
            self._saved = None
        if not self._main and self._stopped_seq == self._seq:  # an exception not yet delivered
            ctypes.pythonapi.PyThreadState_SetAsyncExc(ctypes.c_ulong(self._tid), None)

    def _exit(self, code: int) -> NoReturn:
        if threading.get_ident() == self._tid and self._since is not None:
            raise LawExit(code)
        _REAL_EXIT(code)

    def _on_signal(self, signum: int, frame: Any) -> None:
        if self._since is not None and self._stopped_seq == self._seq and self._reason is not None:
            raise LawStopped(self._reason)

    # -- the watchdog ----------------------------------------------------------------------------
    def _memory_line(self) -> str | None:
        if self.max_memory_bytes is None or self._baseline is None:
            return None
        now = resident_bytes()
        if now is None or now - self._baseline <= self.max_memory_bytes:
            return None
        grown = (now - self._baseline) / 1e6
        return (
            f"the process grew by {grown:.0f} MB while the law ran, past law.max_memory_mb "
            f"{self.max_memory_bytes / 1e6:g}"
        )

    def _watch(self) -> None:
        while not self._done.wait(WATCH_EVERY_S):
            since, seq = self._since, self._seq
            reason = None
            if since is not None and time.monotonic() - since > self.tick_timeout_s:
                reason = f"its step did not return within {self.tick_timeout_s:g} s (run.tick_timeout_s)"
            memory = self._memory_line()
            if memory is not None:
                self._over = memory
                reason = reason or memory
            if reason is None or since is None or self._stopped_seq == seq:
                continue
            self._stop(seq, reason)

    def _stop(self, seq: int, reason: str) -> None:
        self._reason = reason
        self._stopped_seq = seq
        if self._main:
            signal.pthread_kill(self._tid, _SIGNAL)
        else:
            stopped = ctypes.py_object(LawStopped)
            ctypes.pythonapi.PyThreadState_SetAsyncExc(ctypes.c_ulong(self._tid), stopped)
        end = time.monotonic() + HARD_STOP_S
        while time.monotonic() < end:
            if self._done.wait(WATCH_EVERY_S) or self._seq != seq or self._since is None:
                return
        law, follower, t = self._who
        line = (
            f"law {law}, follower {follower} at t={t:.3f} s: {reason}; it did not stop "
            f"{HARD_STOP_S:g} s later (held in compiled code?), so the process ends"
        )
        saved = self._saved
        try:
            if self._on_hard_stop is not None:  # it says the line (and keeps what it can)
                self._on_hard_stop(line)
            else:
                err = saved[2] if saved is not None else sys.stderr
                err.write(f"{line}\n")
                err.flush()
        finally:
            _REAL_EXIT(1)

    @property
    def stop_reason(self) -> str:
        """Why the step was stopped (asked when ``LawStopped`` came without a message)."""
        return self._reason or "stopped by its guard"

    def close(self) -> None:
        self._done.set()
        self._thread.join(timeout=1.0)
        if self._main and self._old_handler is not None:
            signal.signal(_SIGNAL, self._old_handler)
        out = self._output
        if out is not None and out.dropped:
            out.target.write(out.closing_line())
            out.target.flush()


def max_output_bytes(max_output_mb: float) -> int:
    return int(max_output_mb * 1e6) if math.isfinite(max_output_mb) else 2**62
