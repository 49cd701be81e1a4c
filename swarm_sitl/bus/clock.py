"""Waiting, for the per-process loops: for inputs, or for a wall-clock instant.

Both clocks use it. In lockstep a loop waits for its inputs (``wait_until``), in real time for the
next tick's instant (``sleep_until``); either way it keeps reading its inputs while it waits. The
loop blocks in ``select`` on its file descriptors (the MAVLink link, and in lockstep the bus's wake
socket, ``NodeBus.fileno``) and reads its inputs when one wakes it, all on one thread: the bus's
zenoh callback only queues a sample and writes that socket.
"""

import math
import select
import time
from collections.abc import Callable, Sequence
from typing import Protocol

from swarm_sitl.bus.codec import HOLD_NONE

POLL_S = 0.0005  #: longest block between two reads when an input has no file descriptor [s]
#: real time: how long after the last tick's instant a node that is done keeps its zenoh session [s]
END_LINGER_S = 0.25
#: real time: how far ahead of a node's clock another's message may be [s] (their clocks are one
#: host's, or NTP-synchronised hosts'); one further ahead is refused (``node_bus``)
HORIZON_LEAD_S = 0.5
#: lockstep, held: longest block between two looks at the hold (its put wakes a bus's descriptor
#: at once; the leader has none to block on) [s]
HELD_BLOCK_S = 0.02


class _Outages(Protocol):
    def outages(self, period_s: float) -> dict[int, list[tuple[int, int | None]]]: ...


class RunClock:
    """Where a node's run is, for the wrappers that act in time (a fault plan's stages): in
    lockstep the tick being run (the node's loop sets ``tick``: ``TickTime``), in real time the run
    seconds since the start epoch (the loop sets ``epoch_mono`` once the start signal has come:
    ``WallTime``). ``RunClock(lockstep, period_s)`` is the one of that clock."""

    def __new__(cls, *args: object, **kwargs: object) -> "RunClock":
        if cls is RunClock:  # the clock a run's kind asks for
            lockstep = args[0] if args else kwargs["lockstep"]
            cls = TickTime if lockstep else WallTime
        return super().__new__(cls)

    def __init__(self, lockstep: bool, period_s: float):
        self.lockstep = lockstep
        self.period_s = period_s
        self.tick = 0
        self.epoch_mono = math.nan

    def started(self) -> bool:
        """Whether the clock reads the run's time (before the start signal a wall clock's
        ``now`` is NaN)."""
        raise NotImplementedError

    def now(self) -> float:
        """Lockstep: the tick (a count); real time: run seconds."""
        raise NotImplementedError

    def horizon(self, last_tick: int) -> int:
        """The latest tick another node's message may be of now."""
        raise NotImplementedError

    def horizon_call(self, last_tick: int) -> Callable[[], int]:
        """``horizon(last_tick)`` as a call of no argument, for a bus that asks it of every
        estimate and status (``ZenohNodeBus.horizon``)."""
        return lambda: self.horizon(last_tick)

    def now_s(self) -> float:
        """Run seconds: simulated in lockstep, on the wall clock in real time."""
        raise NotImplementedError

    def arrival_s(self, sent_for_s: float) -> float:
        """When a message sent for ``sent_for_s`` is taken to arrive, for a fault plan's windows
        (``from_s``, ``until_s``) [s]."""
        raise NotImplementedError

    # -- a fault plan's timing rules (``faults.in_edges``, ``faults.edges``) --------------------
    #: whether a message's fate is keyed by its tick alone, so a block of ticks' fates can be
    #: drawn ahead (``faults.fate_table``): in lockstep a message is of its tick's time
    fates_by_tick: bool

    def planned_outages(self, plan: _Outages) -> dict[int, list[tuple[int, int | None]]]:
        """The plan's process outages a node's wrappers must know of, per node: (down tick,
        back tick or None). In lockstep every node plays them; in real time the supervisor does
        (``faults.processes``), and a node learns of them as they happen."""
        raise NotImplementedError

    def message_due(self, step: int, t_s: float, left_s: float, delay_s: float) -> tuple[float, bool, float]:
        """When a message of ``step`` (stamped ``t_s``) is due to be used, in ``now()``'s unit:
        it left its sender's queue ``left_s`` after its tick (0: no queue) and the plan delays it
        ``delay_s``. Also whether the queue made it late, and how long after it a duplicate's
        second copy comes (one period)."""
        raise NotImplementedError

    def decided_after(self, step: int, own_step: int, own_known: bool) -> bool:
        """Whether a message of ``step`` that needs the distance to this node waits, undecided,
        for this node to publish (``own_step``: the step of its newest position, ``own_known``:
        whether it has one)."""
        raise NotImplementedError

    def decidable_through(self, own_step: int) -> float:
        """Once this node has published ``own_step``, the latest step of the messages waiting
        for its position that can be decided."""
        raise NotImplementedError


class TickTime(RunClock):
    """Lockstep: the tick being run; a message is of the time it was sent for."""

    fates_by_tick = True

    def started(self) -> bool:
        return True

    def now(self) -> float:
        return float(self.tick)

    def horizon(self, last_tick: int) -> int:
        return last_tick  # a neighbour may run far ahead

    def horizon_call(self, last_tick: int) -> Callable[[], int]:
        return lambda: last_tick  # (a constant: asked of every message)

    def now_s(self) -> float:
        return self.tick * self.period_s

    def arrival_s(self, sent_for_s: float) -> float:
        return sent_for_s

    def planned_outages(self, plan: _Outages) -> dict[int, list[tuple[int, int | None]]]:
        return plan.outages(self.period_s)

    def message_due(self, step: int, t_s: float, left_s: float, delay_s: float) -> tuple[float, bool, float]:
        """A message of step ``s`` is on time at tick ``s + 1`` if it left its queue by then,
        else at the first tick after; a delay ``d`` adds ``ceil(d / dt)`` ticks."""
        dt = self.period_s
        queued = max(0, math.ceil(left_s / dt - 1e-9) - 1) if left_s > 0 else 0
        return step + 1 + queued + (math.ceil(delay_s / dt - 1e-9) if delay_s > 0 else 0), queued > 0, 1.0

    def decided_after(self, step: int, own_step: int, own_known: bool) -> bool:
        return step > own_step  # this node's position of the message's own step

    def decidable_through(self, own_step: int) -> float:
        return own_step


class WallTime(RunClock):
    """Real time: run seconds on the wall clock since the start epoch."""

    fates_by_tick = False

    def started(self) -> bool:
        return not math.isnan(self.epoch_mono)

    def now(self) -> float:
        return time.monotonic() - self.epoch_mono

    def horizon(self, last_tick: int) -> int:
        """None more than ``HORIZON_LEAD_S`` ahead of this clock (before the start signal: any)."""
        if math.isnan(self.epoch_mono):
            return last_tick
        return min(last_tick, int((time.monotonic() - self.epoch_mono + HORIZON_LEAD_S) / self.period_s))

    def now_s(self) -> float:
        return time.monotonic() - self.epoch_mono

    def arrival_s(self, sent_for_s: float) -> float:
        return self.now_s()  # (its arrival: now)

    def planned_outages(self, plan: _Outages) -> dict[int, list[tuple[int, int | None]]]:
        return {}

    def message_due(self, step: int, t_s: float, left_s: float, delay_s: float) -> tuple[float, bool, float]:
        """From its arrival (now), or from when it left its queue if that is later, plus the delay."""
        now = self.now_s()
        late = left_s > 0 and t_s + left_s > now  # (a budget's: it has left its queue)
        return (t_s + left_s if late else now) + delay_s, late, self.period_s

    def decided_after(self, step: int, own_step: int, own_known: bool) -> bool:
        return not own_known  # this node's newest position serves

    def decidable_through(self, own_step: int) -> float:
        return math.inf


class StallError(RuntimeError):
    """A lockstep input did not come within the stall timeout; the message names it."""


def join_tick(
    now_mono_s: float, epoch_mono_s: float, phase_s: float, dt_s: float, lead_s: float = 0.0
) -> int:
    """Real time: the first tick ``k >= 0`` whose instant ``epoch + k * dt + phase`` is at least
    ``lead_s`` after ``now_mono_s``: where a node that starts (or starts again after a restart)
    takes up the swarm's clock. Tick 0 for a node that has the start signal before the epoch."""
    return max(0, math.ceil((now_mono_s + lead_s - epoch_mono_s - phase_s) / dt_s - 1e-9))


def wall_epoch_to_monotonic(epoch_unix_s: float) -> float:
    """The ``time.monotonic()`` instant of a UNIX-time epoch (how a start instant crosses hosts)."""
    return time.monotonic() + (epoch_unix_s - time.time())


def _block(fds: Sequence[int], seconds: float) -> None:
    if fds:
        select.select(fds, [], [], seconds)
    else:
        time.sleep(seconds)


def sleep_until(deadline_mono_s: float, fds: Sequence[int], read: Callable[[], None]) -> None:
    """Until ``deadline_mono_s``, reading inputs when one of ``fds`` has data (a real-time loop
    reads its bus at its tick, so it does not poll it in between)."""
    while True:
        read()
        left = deadline_mono_s - time.monotonic()
        if left <= 0:
            return
        _block(fds, left)


def linger_after_last_tick(last_tick_mono_s: float, dt_s: float) -> None:
    """Real time: every node's last tick falls within one period (the same instant when ticks are
    aligned), and closing a zenoh session makes every peer's zenoh threads update their routes. A
    node that is done waits until the others' last tick is surely done too (``END_LINGER_S``, at
    least two periods after its own) before it tears down:
    without this, 6-9 of 16 followers of a swarm16 run on 2 cores missed their last tick."""
    time.sleep(max(0.0, last_tick_mono_s + max(END_LINGER_S, 2 * dt_s) - time.monotonic()))


def wait_until(
    ready: Callable[[], bool],
    read: Callable[[], None],
    fds: Sequence[int],
    timeout_s: float,
    describe: Callable[[], str],
    on_idle: Callable[[], None] | None = None,
    idle_every_s: float = 0.05,
    block_s: Callable[[], float] | None = None,
    hold: Callable[[], int] | None = None,
) -> None:
    """Read inputs until ``ready()``; ``on_idle()`` every ``idle_every_s``; ``StallError`` after
    ``timeout_s`` with ``describe()`` saying what is missing. Between reads it blocks on ``fds``
    for ``block_s()`` (default ``POLL_S``, for inputs without a descriptor): longer when every input
    has one, since its data wakes the select anyway and each needless wake-up costs a loaded
    machine. While ``hold()`` (lockstep: the supervisor's hold, ``NodeBus.hold_tick``) is out,
    the timeout does not run: a node past the hold may wait on one held before it until its
    user lets the run go."""
    start = time.monotonic()
    next_idle = start + idle_every_s
    while True:
        read()
        if ready():
            return
        now = time.monotonic()
        if hold is not None and hold() != HOLD_NONE:
            start = now
        if now - start > timeout_s:
            raise StallError(f"{describe()} (waited {now - start:.1f} s)")
        if on_idle is not None and now >= next_idle:
            on_idle()
            next_idle = now + idle_every_s
        _block(fds, POLL_S if block_s is None else block_s())


def wait_while_held(
    hold: Callable[[], int],
    done_tick: int,
    read: Callable[[], None],
    fds: Sequence[int],
    on_idle: Callable[[], None] | None = None,
) -> None:
    """Lockstep: a node that has finished ``done_tick`` waits while the supervisor's hold
    (``hold()``, ``NodeBus.hold_tick``) is at or below it: a page's pause, or the tick a single
    step runs to. Every node finishes the tick it is on, so the ticks its out-neighbours are on
    get their inputs and none of them waits on a held node. No stall timeout: a held run waits
    as long as its user does (the supervisor's end ends it: ``lifeline``). ``on_idle()`` between
    looks (a controller's heartbeat to its vehicle)."""
    while done_tick >= hold():
        if on_idle is not None:
            on_idle()
        _block(fds, HELD_BLOCK_S)
        read()
