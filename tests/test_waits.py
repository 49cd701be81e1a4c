"""The waits a node's loop is made of (``bus.clock``): a sleep until a deadline that reads its
inputs as they come and ends at the deadline though none comes; a wait until ready that calls its
idle hook while it waits and, past its timeout, says what it waited for and how long. Each wait is
run in a thread and given a second or more beyond its own length, so a wait that never ends fails
the test instead of hanging it; nothing here is timed to the millisecond."""

import contextlib
import socket
import threading
import time

import pytest

from swarm_sitl.bus.clock import StallError, sleep_until, wait_until

pytestmark = pytest.mark.unit


def _ends(fn, within_s: float) -> None:
    th = threading.Thread(target=fn, daemon=True)
    th.start()
    th.join(within_s)
    assert not th.is_alive(), f"still waiting after {within_s} s"


def test_a_sleep_reads_inputs_as_they_come_and_ends_at_its_deadline_though_none_comes():
    a, b = socket.socketpair()
    with a, b:
        a.setblocking(False)
        got: list[tuple[bytes, float]] = []

        def read() -> None:
            with contextlib.suppress(BlockingIOError):  # (nothing there)
                got.append((a.recv(100), time.monotonic()))

        # The byte is sent 0.05 s in, the deadline is 1 s in: a loaded machine may start the
        # sender late, but not by the 0.95 s between them. The sender is joined before the
        # sockets close, so it never writes to a closed one.
        start = time.monotonic()
        deadline = start + 1.0
        sender = threading.Timer(0.05, lambda: b.send(b"x"))
        sender.start()
        _ends(lambda: sleep_until(deadline, [a.fileno()], read), 4.0)
        sender.join()
        assert [data for data, _ in got] == [b"x"]
        assert got[0][1] < deadline  # read when it came, not at the deadline
        assert time.monotonic() >= deadline  # and slept to the end
        start = time.monotonic()
        _ends(lambda: sleep_until(start + 0.1, [a.fileno()], read), 3.0)  # nothing comes at all
        assert len(got) == 1


def test_a_wait_calls_its_idle_hook_while_it_waits_and_past_its_timeout_says_what_it_waited_for():
    idle: list[float] = []
    ready_at = time.monotonic() + 0.3
    _ends(
        lambda: wait_until(
            lambda: time.monotonic() >= ready_at,
            lambda: None,
            [],
            10.0,
            lambda: "never",
            on_idle=lambda: idle.append(time.monotonic()),
            idle_every_s=0.05,
        ),
        5.0,
    )
    assert idle and idle[0] < ready_at  # called while it waited (every 0.05 s; a loaded machine: less often)
    errors: list[BaseException] = []

    def stall() -> None:
        try:
            wait_until(lambda: False, lambda: None, [], 0.2, lambda: "no estimate from 3 for tick 40")
        except StallError as e:
            errors.append(e)

    _ends(stall, 5.0)
    assert len(errors) == 1 and str(errors[0]).startswith("no estimate from 3 for tick 40 (waited ")
    waited = float(str(errors[0]).split("waited ")[1].split(" s)")[0])
    assert waited >= 0.2
