"""The law guard on its own (``nodes.law_guard``): a step that outlasts its time is stopped in the
thread that steps it (the main thread or another), ``os._exit`` in a step raises instead of ending
the process, memory past the bound stops the law at once or at its next step, the output is cut at
its limit with the count of what was dropped, and a step held where no signal reaches it ends its
process with the line."""

import io
import math
import mmap
import os
import subprocess
import sys
import threading
import time
from typing import ClassVar

import numpy as np
import pytest

from swarm_sitl.laws.contract import Received, VehicleSample
from swarm_sitl.nodes.law_guard import (
    HARD_STOP_S,
    WATCH_EVERY_S,
    BoundedOutput,
    LawExit,
    LawGuard,
    LawStopped,
    max_output_bytes,
    resident_bytes,
)
from swarm_sitl.nodes.law_host import HostedLaw, LawError

pytestmark = pytest.mark.integration


def _guard(timeout_s: float = 0.3, memory_mb: float | None = None, output=None, limit: int = 100) -> LawGuard:
    return LawGuard(timeout_s, memory_mb, output, limit)


def _stepping(guard: LawGuard, body) -> BaseException | None:
    try:  # as the host steps a law: entering may stop it already
        guard.enter("my_law.py:Law", 2, 0.5)
        body()
    except BaseException as e:
        return e
    finally:
        guard.leave()
    return None


def test_a_pure_python_loop_and_a_sleep_are_stopped_after_the_timeout_in_the_main_thread():
    guard = _guard(0.3)
    try:
        for body in (lambda: [None for _ in iter(int, 1)], lambda: time.sleep(30)):
            t0 = time.monotonic()
            e = _stepping(guard, body)
            wall = time.monotonic() - t0
            assert isinstance(e, LawStopped) and "did not return within 0.3 s (run.tick_timeout_s)" in str(e)
            assert 0.3 <= wall < 0.3 + 2 * WATCH_EVERY_S + 0.5, wall
        assert _stepping(guard, lambda: time.sleep(0.05)) is None  # a step within its time: untouched
    finally:
        guard.close()


def test_a_loop_in_another_thread_is_stopped_there():
    result: list[BaseException | None] = []

    def worker():
        guard = _guard(0.3)
        try:
            result.append(_stepping(guard, lambda: [None for _ in iter(int, 1)]))
        finally:
            guard.close()

    t = threading.Thread(target=worker)
    t.start()
    t.join(timeout=10)
    assert not t.is_alive() and len(result) == 1 and isinstance(result[0], LawStopped)


def test_os_exit_in_a_step_raises_and_outside_a_step_is_the_real_one():
    guard = _guard(5.0)
    real = os._exit
    try:
        e = _stepping(guard, lambda: os._exit(3))
        assert isinstance(e, LawExit) and e.code == 3
        assert os._exit is real  # given back after the step
    finally:
        guard.close()


def _fresh_resident(mb: float) -> np.ndarray:
    """``mb`` MB that were not resident before: new pages mapped and touched. (An array from the
    allocator may reuse memory an earlier test freed, still resident, and the process not grow.)"""
    pages = np.frombuffer(mmap.mmap(-1, int(mb * 1e6)), dtype=np.uint8)
    pages[:] = 1
    return pages


def test_memory_past_the_bound_stops_the_step_or_the_next_one():
    guard = _guard(5.0, memory_mb=40.0)
    held = []
    try:

        def grow():
            while True:  # 8 MB at a time, touched (resident), until the guard stops it
                held.append(_fresh_resident(8.0))
                time.sleep(0.005)

        e = _stepping(guard, grow)
        grown = len(held) * 8.0
        assert isinstance(e, LawStopped) and "past law.max_memory_mb 40" in str(e)
        # it held about what the process grew by (the process's own growth: under one array)
        assert 40.0 - 8.0 <= grown < 40.0 + 8.0 * (WATCH_EVERY_S / 0.005 + 2), grown
        e = _stepping(guard, lambda: None)  # still held: the next step stops at once
        assert isinstance(e, LawStopped)
    finally:
        held.clear()
        guard.close()


def test_the_step_that_took_the_memory_past_its_bound_is_the_one_stopped(monkeypatch):
    """Several laws in one process (``sim``): the step whose own allocation took the memory past
    the bound is stopped when it returns, whenever the watchdog would have looked (here: never),
    and a step that grew it less is not."""
    import swarm_sitl.nodes.law_guard as law_guard

    monkeypatch.setattr(law_guard, "WATCH_EVERY_S", 3600.0)  # (the watchdog does not look)
    guard = _guard(5.0, memory_mb=40.0)
    held = []
    try:

        def hoard(mb: float):
            def step():
                held.append(_fresh_resident(mb))
                guard.after_step()  # (as the host calls it when the step returned)

            return step

        assert _stepping(guard, hoard(8.0)) is None  # 8 MB of 40: on
        e = _stepping(guard, hoard(48.0))  # 56 MB: past, in this step
        assert isinstance(e, LawStopped) and "past law.max_memory_mb 40" in str(e)
    finally:
        held.clear()
        guard.close()


def test_output_past_its_limit_is_dropped_and_counted():
    target = io.StringIO()
    out = BoundedOutput(target, 100, "law.max_output_mb")
    for _ in range(7):
        out.write("x" * 30)
    text = target.getvalue()
    assert text.startswith("x" * 100 + "\n[swarm-sitl: ")
    assert out.dropped == 7 * 30 - 100 and "reached 100 bytes (law.max_output_mb)" in text
    assert out.closing_line() == "[swarm-sitl: 110 bytes of the law's output dropped (law.max_output_mb)]\n"


def test_prints_in_a_step_go_to_the_guards_output_and_are_given_back_after():
    target = io.StringIO()
    guard = _guard(5.0, output=target, limit=50)
    before = sys.stdout
    try:
        assert _stepping(guard, lambda: print("y" * 80)) is None
        assert sys.stdout is before
        assert target.getvalue().startswith("y" * 50 + "\n[swarm-sitl: ")
    finally:
        guard.close()
    assert target.getvalue().endswith(
        "[swarm-sitl: 31 bytes of the law's output dropped (law.max_output_mb)]\n"
    )


def test_a_step_no_signal_reaches_ends_its_process_with_the_line():
    """The step blocks the guard's signal and sleeps: the guard cannot stop it, so after its
    timeout and ``HARD_STOP_S`` the process ends (exit 1) with the line on stderr."""
    code = (
        "import signal, time\n"
        "from swarm_sitl.nodes.law_guard import LawGuard, _SIGNAL\n"
        "g = LawGuard(0.3, None, None, 0)\n"
        "g.enter('held.py:Held', 3, 1.25)\n"
        "signal.pthread_sigmask(signal.SIG_BLOCK, [_SIGNAL])\n"
        "time.sleep(30)\n"
    )
    t0 = time.monotonic()
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    wall = time.monotonic() - t0
    assert r.returncode == 1
    assert r.stderr.strip() == (
        "law held.py:Held, follower 3 at t=1.250 s: its step did not return within 0.3 s "
        f"(run.tick_timeout_s); it did not stop {HARD_STOP_S:g} s later (held in compiled code?), "
        "so the process ends"
    )
    assert wall < 0.3 + HARD_STOP_S + 10.0


class _Sleeper:
    """A law whose step sleeps in compiled code (``time.sleep``) longer than it may: no stop
    reaches it there."""

    message_length = 1
    record_fields: ClassVar[dict[str, int]] = {}

    def __init__(self, sleep_s: float):
        self.sleep_s = sleep_s

    def step(self, t, sample, inbox):
        time.sleep(self.sleep_s)
        return None


@pytest.mark.parametrize("told", [False, True])
def test_a_step_held_past_the_hard_stop_ends_its_process_with_one_line_naming_the_law_and_the_reason(
    monkeypatch, told
):
    """In the process itself (the process's end stood in for): a hosted law's step held in
    compiled code past its timeout and the hard stop gives one line naming the law, the follower,
    the time and the reason, to the step's own stderr or to ``on_hard_stop`` when the host gives
    one, then the process ends with code 1; once the step returns, the stop it was sent is its
    host's ``LawError`` with the guard's reason."""
    import swarm_sitl.nodes.law_guard as law_guard

    hard_s = 0.3
    monkeypatch.setattr(law_guard, "HARD_STOP_S", hard_s)
    exits: list[int] = []
    monkeypatch.setattr(law_guard, "_REAL_EXIT", exits.append)
    stderr, said = io.StringIO(), []
    monkeypatch.setattr(sys, "stderr", stderr)
    result: list[BaseException | None] = []

    def worker() -> None:  # (not the main thread: the stop is an exception posted to it)
        guard = LawGuard(0.3, None, None, 0, said.append if told else None)
        host = HostedLaw(_Sleeper(0.3 + hard_s + 0.6), 7, "my_laws.py:Sleeper")
        host.guard = guard
        sample = VehicleSample(0.25, np.zeros(3), np.zeros(3), np.array([1.0, 0.0, 0.0, 0.0]))
        try:
            host.step(0.25, sample, {0: Received(np.zeros(12), 0.24, 0.01)})
            result.append(None)
        except BaseException as e:
            result.append(e)
        finally:
            guard.close()

    t = threading.Thread(target=worker)
    t.start()
    t.join(timeout=30)
    reason = "its step did not return within 0.3 s (run.tick_timeout_s)"
    line = (
        f"law my_laws.py:Sleeper, follower 7 at t=0.250 s: {reason}; it did not stop {hard_s:g} s later "
        "(held in compiled code?), so the process ends"
    )
    assert exits == [1]
    assert (said, stderr.getvalue()) == (([line], "") if told else ([], line + "\n"))
    assert len(result) == 1 and isinstance(result[0], LawError)
    assert str(result[0]) == f"law my_laws.py:Sleeper, follower 7 at t=0.250 s: {reason}"


def test_a_memory_bound_is_on_the_growth_not_on_the_process_size():
    """A bound far under what the process already holds (the interpreter, numpy, the tests)
    stops no step that grows nothing."""
    size = resident_bytes()
    assert size is not None and size > 30e6
    guard = _guard(5.0, memory_mb=size / 1e6 / 4)
    try:
        assert _stepping(guard, lambda: time.sleep(4 * WATCH_EVERY_S)) is None
        guard.after_step()  # (the peak is the process's: no growth)
    finally:
        guard.close()


def test_an_unlimited_output_passes_whole():
    target = io.StringIO()
    guard = _guard(5.0, output=target, limit=max_output_bytes(math.inf))
    text = "z" * 100_000
    try:
        assert _stepping(guard, lambda: print(text)) is None
    finally:
        guard.close()
    assert target.getvalue() == text + "\n"
    assert max_output_bytes(2.5) == 2_500_000


def test_a_guard_left_open_does_not_keep_its_process_from_ending():
    """A host that ends without closing its guard (an error on its way out) still ends: the
    watchdog does not hold the interpreter."""
    code = "from swarm_sitl.nodes.law_guard import LawGuard\nLawGuard(5.0, None, None, 0)\nprint('made')\n"
    _guard(5.0).close()  # (one built here too: a mutation tester maps a test by what it runs in-process)
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert r.returncode == 0 and r.stdout == "made\n", r.stderr
