"""The law guard on its own (``nodes.law_guard``): a step that outlasts its time is stopped in the
thread that steps it (the main thread or another), ``os._exit`` in a step raises instead of ending
the process, memory past the bound stops the law at once or at its next step, the output is cut at
its limit with the count of what was dropped, and a step held where no signal reaches it ends its
process with the line."""

import io
import os
import subprocess
import sys
import threading
import time

import numpy as np
import pytest

from swarm_sitl.nodes.law_guard import (
    HARD_STOP_S,
    WATCH_EVERY_S,
    BoundedOutput,
    LawExit,
    LawGuard,
    LawStopped,
)

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


def test_memory_past_the_bound_stops_the_step_or_the_next_one():
    guard = _guard(5.0, memory_mb=40.0)
    held = []
    try:

        def grow():
            while True:  # 8 MB at a time, touched (resident), until the guard stops it
                held.append(np.ones(1_000_000))
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
                held.append(np.ones(int(mb * 1e6 / 8)))  # touched: resident
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
