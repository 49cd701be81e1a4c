"""The estimate bus of one node over zenoh: its in-edges in, its out-edges out, nothing else.

``NodeBus`` is the interface the leader and controller loops use; ``ZenohNodeBus`` implements it
on an embedded zenoh session (``session``; keys in ``keys``, payloads in ``codec``). Faults (loss,
delay, partitions) are a wrapper of this interface (``faults.edges.FaultyBus``), not in the loops:
every estimate a ``ZenohNodeBus`` decodes goes through ``deliver``, which files it (``file``) or,
under a wrapper, hands it to the fault stage that files it when the plan lets it through.

Received samples are queued by a callback on zenoh's thread, which does nothing else: it appends
the sample to one queue and, unless one is pending, writes a byte to a local socket pair
(``fileno()``). A loop waiting for an estimate blocks in ``select`` on it beside its MAVLink socket
and wakes when one comes, not every few hundred microseconds to look (which cost most of a
controller's CPU per tick). ``poll()`` decodes and files the queue on the loop's thread. The queue
holds at most ``QUEUE_CAPACITY`` samples: past it the callback waits (zenoh's reliable transport
then backs up to the sender, as a full channel did).

Malformed payloads are dropped and counted in ``dropped``, and so is a message whose length is
not what its sender sends (``REFERENCE_LENGTH`` from the leader, the law's ``message_length`` from
a follower); well-formed ones that cannot be what their key says (another sender, a tick that
does not follow the last one taken from that sender, or past ``horizon()``) are dropped and
counted per sender in ``refused``. Access control
(``access``) keeps anyone but the sender off a key; these checks keep a faulty sender from
freezing a neighbour's table (one estimate of tick 2^32-1 would otherwise stay the newest for
good).
"""

import contextlib
import socket
import time
from collections import deque
from collections.abc import Callable, Iterable
from typing import Any, Protocol, TypeVar

import zenoh

from sim_vehicles.runtime import udp_arrival
from sim_vehicles.runtime.counter_file import CounterFile
from swarm_sitl.bus import keys as zenoh_keys
from swarm_sitl.bus.access import NodeKeys
from swarm_sitl.bus.codec import (
    HOLD_NONE,
    Message,
    PayloadError,
    Status,
    decode_hold,
    decode_message,
    decode_start,
    decode_status,
    encode_message,
    encode_status,
)
from swarm_sitl.bus.estimates import EstimateTable
from swarm_sitl.laws.contract import REFERENCE_LENGTH


def _matched(pub: zenoh.Publisher) -> bool:
    """Whether a subscriber matches ``pub`` (zenoh's stubs type ``matching_status`` as a bool;
    it is a ``MatchingStatus`` whose ``matching`` says it)."""
    status: Any = pub.matching_status
    return bool(getattr(status, "matching", status))


def _publisher(session: zenoh.Session, key: str) -> zenoh.Publisher:
    """Reliable, and blocking rather than dropping when the link is congested: in lockstep a lost
    estimate would stall the swarm (the fault issue drops on purpose, in a wrapper)."""
    return session.declare_publisher(
        key, congestion_control=zenoh.CongestionControl.BLOCK, reliability=zenoh.Reliability.RELIABLE
    )


T = TypeVar("T")

QUEUE_CAPACITY = 4096  #: samples a bus holds before its callback waits for the loop to take them
QUEUE_FULL_WAIT_S = 0.0005  #: how often a callback held by a full queue looks again [s]
DRAIN_POLL_S = 0.01  #: how often ``drain`` looks whether its receivers have gone [s]

# what a queued sample came on
_ESTIMATE, _STATUS, _ALIVE, _START, _HOLD = range(5)


class NodeBus(Protocol):
    @property
    def dropped(self) -> int:
        """Payloads that did not decode, dropped and counted."""
        ...

    def poll(self) -> None: ...
    def fileno(self) -> int:
        """A file descriptor that turns readable when something has come for ``poll()``."""
        ...

    def publish(self, msg: Message) -> None: ...
    def publish_status(self, status: Status) -> None: ...
    def settled(self, src: int, step: int) -> bool:
        """Lockstep: whether ``src``'s estimate of ``step`` has come, or will not (a fault plan
        says so): what a tick waits for."""
        ...

    def estimate(self, src: int, step: int) -> Message | None:
        """``src``'s estimate of ``step``, if it has come and may be used now."""
        ...

    def latest(self, src: int) -> Message | None:
        """The newest estimate of ``src`` that may be used now."""
        ...

    def forget_before(self, step: int) -> None: ...
    def progress(self, follower: int) -> int: ...
    def start_epoch(self) -> float | None: ...
    def hold_tick(self) -> int:
        """Lockstep: the supervisor's hold (``codec.HOLD_NONE`` while there is none): a node that
        has finished a tick at or past it waits (``clock.wait_while_held``)."""
        ...

    def lost(self) -> set[int]: ...
    def set_ready(self) -> None: ...
    def drain(self, timeout_s: float) -> bool: ...
    def close(self) -> None: ...


class ZenohNodeBus(EstimateTable):
    """Node ``node`` of swarm ``swarm``: subscribes to its ``in_sources``' edges, publishes on its
    ``out_dests``' edges, watches the status of ``watch_status`` followers (the leader's pacing).
    ``message_length``: how many values a follower's message has (the law's)."""

    def __init__(
        self,
        session: zenoh.Session,
        swarm: str,
        node: int,
        in_sources: Iterable[int],
        out_dests: Iterable[int],
        watch_status: Iterable[int] = (),
        watch_alive: Iterable[int] = (),
        message_length: int = REFERENCE_LENGTH,
    ):
        """``watch_alive``: nodes besides the in-neighbours whose liveliness to follow
        (``alive_puts``: how often each has declared itself ready, a restart counting again)."""
        super().__init__()
        self.session = session
        self.swarm = swarm
        self.node = node
        self.message_length = message_length
        self._progress: dict[int, int] = {}
        self._lost: set[int] = set()
        self._puts: dict[int, int] = {}
        self.received: dict[int, int] = {}  #: estimates decoded per in-neighbour
        #: lockstep: the steps ``received`` counts (None: all), those the node waits for; whether
        #: another one comes before the node exits, or before a restarted node subscribes, is a race,
        #: and the counts must be the same every run
        self.counted_steps: range | None = None
        self.published = 0  #: estimates published (each on every out-edge)
        #: where ``published`` is kept as it grows, so a killed process's count survives it
        self.published_file: CounterFile | None = None
        #: where the tick of the newest estimate published is kept (plus one; 0: none yet), so a
        #: supervisor can say where a process that ended or stalled was (``running.ends``)
        self.tick_file: CounterFile | None = None
        self.refused: dict[int, int] = {}  #: per sender, payloads that decoded but cannot be (above)
        self._last_step: dict[int, int] = {}  #: per sender, the tick of its last estimate taken
        #: the latest tick an estimate or status may be of now (``nodes.entry``: the run's last tick,
        #: in real time also no further ahead of this node's clock than ``HORIZON_LEAD_S``)
        self.horizon: Callable[[], int] = lambda: 2**32
        self._epoch: float | None = None
        self._hold = HOLD_NONE
        self._token: Any = None
        #: where each decoded estimate goes: ``file`` (a fault wrapper puts its stage here)
        self.deliver: Callable[[Message], None] = self.file
        self._pubs = [_publisher(session, zenoh_keys.edge(swarm, node, d)) for d in out_dests]
        self._status_pub = _publisher(session, zenoh_keys.status(swarm, node)) if node > 0 else None

        self._queue: deque[tuple[int, int, Any]] = deque()  #: (what, node, sample), in arrival order
        self._open = True
        self._woken = False  #: a wake-up byte is out that no poll() has answered yet
        # a socket pair rather than a pipe: a closed socket object refuses a late callback's write
        # (its descriptor is -1 from then on) where a closed pipe's number could be another file's
        self._wake_r, self._wake_w = socket.socketpair()
        self._wake_r.setblocking(False)
        self._wake_w.setblocking(False)
        self._waiting = udp_arrival.Waiting(self._wake_r)

        def on(what: int, n: int) -> Callable[[Any], None]:
            return lambda sample: self._queued(what, n, sample)

        sources = list(in_sources)
        self._est_subs = [
            (s, session.declare_subscriber(zenoh_keys.edge(swarm, s, node), on(_ESTIMATE, s)))
            for s in sources
        ]
        self._alive_subs = [
            (
                s,
                session.liveliness().declare_subscriber(
                    zenoh_keys.alive(swarm, s), on(_ALIVE, s), history=True
                ),
            )
            for s in dict.fromkeys([*sources, *watch_alive])
        ]
        self._status_subs = [
            (f, session.declare_subscriber(zenoh_keys.status(swarm, f), on(_STATUS, f))) for f in watch_status
        ]
        self._start_sub = [
            session.declare_subscriber(zenoh_keys.start(swarm), on(_START, 0)),
            session.declare_subscriber(zenoh_keys.hold(swarm), on(_HOLD, 0)),
        ]

    def _queued(self, what: int, n: int, sample: Any) -> None:
        """On zenoh's thread: queue the sample and wake the loop (nothing else, to hold the GIL
        for as short as can be)."""
        queue = self._queue
        while len(queue) >= QUEUE_CAPACITY and self._open:
            time.sleep(QUEUE_FULL_WAIT_S)
        queue.append((what, n, sample))
        # one byte per batch: once one is out, the loop's next poll() takes everything queued
        # (it reads the byte, clears the flag, then empties the queue: a sample queued before the
        # flag is cleared is taken by that poll, one queued after it sends its own byte)
        if not self._woken and self._open:
            self._woken = True
            with contextlib.suppress(OSError):  # full (the loop will wake anyway) or closed
                self._wake_w.send(b"\0")

    @classmethod
    def of(
        cls, session: zenoh.Session, swarm: str, keys: NodeKeys, message_length: int = REFERENCE_LENGTH
    ) -> "ZenohNodeBus":
        """The bus of ``keys.node``, on the keys the router's access control grants it; a
        follower's messages have ``message_length`` values."""
        return cls(
            session,
            swarm,
            keys.node,
            keys.in_sources,
            keys.out_dests,
            keys.watch_status,
            keys.watch_alive,
            message_length,
        )

    # -- receive ---------------------------------------------------------------------------------
    def counts(self, step: int) -> bool:
        """Whether an estimate of ``step`` is counted (``counted_steps``)."""
        return self.counted_steps is None or step in self.counted_steps

    def fileno(self) -> int:
        return self._wake_r.fileno()

    def poll(self) -> None:
        """File everything that has arrived, in the order it came."""
        # read the wake-up byte only if one is out: a read that finds nothing raises, and that
        # cost a controller tens of microseconds on nine ticks in ten (it polls the bus each tick
        # whether or not it was woken). A byte still comes after the flag was cleared if its
        # callback was between setting the flag and writing the byte: ``_waiting`` finds it
        # (poll(2), no exception), so the descriptor never stays readable
        if self._woken or self._waiting():
            with contextlib.suppress(OSError):  # written a moment late (the next poll takes it), or closed
                self._wake_r.recv(65536)
        self._woken = False
        queue = self._queue
        while queue:
            what, n, sample = queue.popleft()
            if what == _ESTIMATE:
                self._take_estimate(n, sample)
            elif what == _STATUS:
                self._take_status(n, sample)
            elif what == _ALIVE:
                if sample.kind == zenoh.SampleKind.DELETE:
                    self._lost.add(n)
                else:
                    self._lost.discard(n)
                    self._puts[n] = self._puts.get(n, 0) + 1
            elif what == _START:
                epoch = self._decoded(decode_start, sample)
                if epoch is not None and self._epoch is None:
                    self._epoch = epoch
            else:
                hold = self._decoded(decode_hold, sample)
                if hold is not None:
                    self._hold = hold

    def _decoded(self, decode: Callable[[bytes], T], sample: Any) -> T | None:
        """The sample's payload decoded, or None if it is malformed (dropped and counted)."""
        try:
            return decode(sample.payload.to_bytes())
        except PayloadError:
            self.dropped += 1
            return None

    def _take_estimate(self, src: int, sample: Any) -> None:
        m = self._decoded(decode_message, sample)
        if m is None:
            return
        if len(m.values) != (REFERENCE_LENGTH if src == 0 else self.message_length):
            self.dropped += 1  # not what this sender sends: no use to the law
            return
        if m.src != src or not self._in_sequence(src, m.step):
            self.refused[src] = self.refused.get(src, 0) + 1
            return
        if self.counts(m.step):
            self.received[m.src] = self.received.get(m.src, 0) + 1
        self.deliver(m)

    def _take_status(self, f: int, sample: Any) -> None:
        st = self._decoded(decode_status, sample)
        if st is None:
            return
        if st.follower != f or st.step > self.horizon():
            self.refused[f] = self.refused.get(f, 0) + 1
            return
        self._progress[f] = max(self._progress.get(f, -1), st.step)

    def _in_sequence(self, src: int, step: int) -> bool:
        """Whether ``src``'s estimate of ``step`` can follow the last one taken from it (a later
        tick, none past the horizon: a restarted sender resumes later than it stopped); if so it
        is now the last one."""
        if step <= self._last_step.get(src, -1) or step > self.horizon():
            return False
        self._last_step[src] = step
        return True

    # -- the loop's side -------------------------------------------------------------------------
    def publish(self, msg: Message) -> None:
        payload = encode_message(msg)
        self.published += 1
        if self.published_file is not None:  # counted before it goes: sent >= received, always
            self.published_file.add()
        if self.tick_file is not None:
            self.tick_file.set(msg.step + 1)
        for p in self._pubs:
            p.put(payload)

    def publish_status(self, status: Status) -> None:
        if self._status_pub is not None:
            self._status_pub.put(encode_status(status))

    def settled(self, src: int, step: int) -> bool:
        return step in self._estimates.get(src, {})

    def progress(self, follower: int) -> int:
        return self._progress.get(follower, -1)

    def start_epoch(self) -> float | None:
        return self._epoch

    def hold_tick(self) -> int:
        return self._hold

    def lost(self) -> set[int]:
        return set(self._lost)

    def alive_puts(self, node: int) -> int:
        """How many times ``node`` (an in-neighbour or one of ``watch_alive``) has declared itself
        ready: once per incarnation of its process."""
        return self._puts.get(node, 0)

    def set_ready(self) -> None:
        if self._token is None:
            self._token = self.session.liveliness().declare_token(zenoh_keys.alive(self.swarm, self.node))

    def _undeclare_subscriptions(self) -> None:
        subs = [
            *(sub for _, sub in [*self._est_subs, *self._alive_subs, *self._status_subs]),
            *self._start_sub,
        ]
        for sub in subs:
            sub.undeclare()
        self._est_subs, self._alive_subs, self._status_subs, self._start_sub = [], [], [], []

    def drain(self, timeout_s: float) -> bool:
        """The end of a lockstep run: take no more input (the subscriptions go), then wait until
        no subscriber is left on this node's out-edges, each receiver having finished its run and
        let go of its own, or ``timeout_s``; returns whether they all went. A node that ran ahead
        of its receivers would otherwise close its session with its last estimates still queued,
        and a reliable put still queued at close can be lost (seen with 32-64 followers on two
        cores: a receiver stalled on the estimate of the run's next-to-last tick). Letting go of
        the subscriptions first means a cycle of nodes does not wait on itself."""
        self._undeclare_subscriptions()
        end = time.monotonic() + timeout_s
        while any(_matched(p) for p in self._pubs):
            if time.monotonic() > end:
                return False
            time.sleep(DRAIN_POLL_S)
        return True

    def close(self) -> None:
        self._undeclare_subscriptions()
        if self._token is not None:
            self._token.undeclare()
            self._token = None
        if self._open:
            self._open = False
            self._wake_r.close()
            self._wake_w.close()
