"""The two clocks a node's ticks run on, each one object: the controller's and the leader's loops
are written once against them and never ask which clock runs.

- ``Lockstep``: a tick comes when its inputs have (the controller's: its vehicle's sample of it
  and the estimates of the tick before, ``controller``; the leader's: its followers within the
  window, ``wait_for``), never late; a node at or past the supervisor's hold stops there (a
  page's pause or single step: ``held``, ``hold_after``); at the end the bus drains, so every
  receiver has every estimate before the session closes.
- ``WallClock``: a tick comes at its instant on the wall clock, ``epoch + k dt + phase``
  (``wait_instant``); one that starts a whole period late is skipped to the current tick (never
  past the run's last tick, which is flown however late) and counted, and so is one whose output
  goes out after the next tick's instant (``out_at``); a node started again mid-run joins at the
  tick the swarm's clock is at (``first_tick``); at the end a node lingers until the others' last
  tick is surely done.

Each is also the node's ``RunClock`` (what the fault wrappers read: the tick in lockstep, run
seconds in real time): ``pacer(lockstep, period_s)`` makes one before the node's bus (whose
wrappers read it), and the loop attaches the bus to it (``attach``).
"""

import math
import time
from collections.abc import Callable, Sequence

from swarm_sitl.bus.clock import (
    RunClock,
    TickTime,
    WallTime,
    join_tick,
    linger_after_last_tick,
    sleep_until,
    wait_until,
    wait_while_held,
)
from swarm_sitl.bus.node_bus import NodeBus

Reader = Callable[[], None]  #: reads a node's inputs


class _Pacer(RunClock):
    """What both clocks keep: the node's bus, and how late its ticks were."""

    def __init__(self, lockstep: bool, period_s: float):
        super().__init__(lockstep, period_s)
        self.bus: NodeBus | None = None
        self.stall_timeout_s = math.inf
        #: ticks skipped (a period behind) or whose output went out after the next one's instant
        self.late = 0
        self.max_late_s = 0.0  #: the latest an output went out after its tick's instant [s]

    def attach(self, bus: NodeBus, stall_timeout_s: float) -> None:
        """The node's bus (its hold, its drain) and how long a lockstep input may be waited for."""
        self.bus, self.stall_timeout_s = bus, stall_timeout_s

    def _bus(self) -> NodeBus:
        assert self.bus is not None, "attach the node's bus first"
        return self.bus


class Lockstep(_Pacer, TickTime):
    """Ticks paced by their inputs (module docstring)."""

    def __init__(self, period_s: float):
        super().__init__(True, period_s)

    def first_tick(self, resume_tick: int, phase_s: float, lead_s: float = 0.0) -> int:
        """The tick this node starts at: 0, or where a fault plan's restart resumes it."""
        return resume_tick

    def wait_instant(
        self,
        k: int,
        phase_s: float,
        fds: Sequence[int],
        read: Reader,
        read_at: Reader,
        skip: bool = True,
        last: int | None = None,
    ) -> tuple[int, float]:
        """``(the tick to run, its lateness [s])``: here ``k``, never late (its inputs pace it:
        the node waits for them)."""
        self.tick = k
        return k, 0.0

    def wait_for(
        self, k: int, ready: Callable[[], bool], describe: Callable[[], str], read: Reader, block_s: float
    ) -> None:
        """Before tick ``k``: until ``ready()`` (``StallError`` naming ``describe()`` after the
        stall timeout, which a hold stops), or, the tick before being at or past the hold, while
        the hold lasts, and again."""
        bus = self._bus()

        def held() -> bool:
            return k - 1 >= bus.hold_tick()

        while True:
            wait_until(
                lambda: ready() or held(),
                read,
                [],
                self.stall_timeout_s,
                describe,
                block_s=lambda: block_s,
                hold=bus.hold_tick,
            )
            if not held():
                return
            wait_while_held(bus.hold_tick, k - 1, read, [])

    def out_at(self, k: int, phase_s: float) -> float:
        """How long after its instant tick ``k``'s output went out [s]: none in lockstep."""
        return 0.0

    def held(self, k: int) -> bool:
        """Whether the supervisor's hold stops this node after tick ``k``."""
        return k >= self._bus().hold_tick()

    def hold_after(self, k: int, read: Reader, fds: Sequence[int], idle: Reader) -> None:
        """After tick ``k``, held (``held``): wait while the hold is at or below it."""
        wait_while_held(self._bus().hold_tick, k, read, fds, idle)

    def end(self, last_tick: int, phase_s: float) -> None:
        """The bus drains: its receivers have every estimate before the session closes."""
        self._bus().drain(self.stall_timeout_s)


class WallClock(_Pacer, WallTime):
    """Ticks at their instants on the wall clock (module docstring)."""

    def __init__(self, period_s: float):
        super().__init__(False, period_s)

    def first_tick(self, resume_tick: int, phase_s: float, lead_s: float = 0.0) -> int:
        """The tick the swarm's clock is at, ``lead_s`` ahead of now: 0 at the run's start (the
        start signal comes half a second ahead), a later one for a node started again mid-run
        (whatever ``resume_tick``)."""
        return join_tick(time.monotonic(), self.epoch_mono, phase_s, self.period_s, lead_s)

    def wait_instant(
        self,
        k: int,
        phase_s: float,
        fds: Sequence[int],
        read: Reader,
        read_at: Reader,
        skip: bool = True,
        last: int | None = None,
    ) -> tuple[int, float]:
        """Sleep until tick ``k``'s instant, ``read()`` as ``fds`` wake it, then ``read_at()``
        (what is read at the tick only); ``(k, its lateness [s])``. A whole period behind it is
        counted late and, with ``skip``, the tick given is the one to skip to (those between
        counted too), never past ``last`` (the run's last tick is flown however late: every node
        reports the end)."""
        self.tick = k
        sleep_until(self.epoch_mono + k * self.period_s + phase_s, fds, read)
        read_at()
        lateness = time.monotonic() - self.epoch_mono - (k * self.period_s + phase_s)
        if lateness <= self.period_s:
            return k, lateness
        if not skip:
            self.late += 1
            return k, lateness
        skip_to = int((time.monotonic() - self.epoch_mono - phase_s) / self.period_s)
        if last is not None:
            skip_to = min(skip_to, max(last, k))
        self.late += max(skip_to - k, 1)  # (the last tick, flown late, is counted once)
        return skip_to, lateness

    def wait_for(
        self, k: int, ready: Callable[[], bool], describe: Callable[[], str], read: Reader, block_s: float
    ) -> None:
        """Nothing: on the wall clock a tick waits for its instant only."""
        return None

    def out_at(self, k: int, phase_s: float) -> float:
        """How long after its instant tick ``k``'s output went out [s]; after the next tick's
        instant, it is counted late."""
        done = time.monotonic() - self.epoch_mono - (k * self.period_s + phase_s)
        if done > self.period_s:
            self.late += 1
        self.max_late_s = max(self.max_late_s, done)
        return done

    def held(self, k: int) -> bool:
        return False  # (a hold is lockstep's)

    def hold_after(self, k: int, read: Reader, fds: Sequence[int], idle: Reader) -> None:
        return None

    def end(self, last_tick: int, phase_s: float) -> None:
        """Linger until every node's last tick is surely done (``linger_after_last_tick``)."""
        linger_after_last_tick(self.epoch_mono + last_tick * self.period_s + phase_s, self.period_s)


Pacer = Lockstep | WallClock


def pacer(lockstep: bool, period_s: float) -> Pacer:
    """The clock of a node's run: ``Lockstep`` or ``WallClock``."""
    return Lockstep(period_s) if lockstep else WallClock(period_s)
