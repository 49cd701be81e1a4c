"""A fault plan on a vehicle's MAVLink link, each way apart: a wrapper of the datagrams the
controller's ``VehicleLink`` sends (uplink: setpoints) and receives (downlink: telemetry).

Each datagram's fate is ``plan.fate`` under the plan's ``mavlink: i`` entries.

- Real time: a lost datagram is not sent (uplink) or not read (downlink); a corrupted one goes on
  with one byte flipped, for the receiver's CRC check to drop and count; a delayed or duplicated one
  is held and goes out (or in) at the controller's first wake-up after it is due (it wakes at least
  once per control period). The plan's window is in run seconds.
- Lockstep (drop, loss, corrupt only): fates are keyed by the sample's or setpoint's
  ``time_boot_ms``, so the run is the same every time. A lost setpoint is a period the vehicle flies
  on what it holds: a clock-only SET_ATTITUDE_TARGET, stamped one period on, goes in its place (a
  corrupted one is sent too, and dropped by the vehicle). A lost sample is settled
  (``lost_ms``): the tick carries the sample before it by its age. Only the per-tick traffic is
  counted, each time once: a setpoint resent after a wall-clock timeout, the vehicle's repeated
  answer and the start-up traffic meet the same fate uncounted (a corrupted repeat is dropped, not
  passed on again), so the counts, the receivers' included, are the same every run.
"""

import heapq
import itertools
from collections.abc import Callable
from typing import Any

from sim_vehicles.runtime.counter_file import NamedCounts
from swarm_sitl.bus.clock import RunClock, TickTime, WallTime
from swarm_sitl.faults.counts import EdgeStats, counts_names
from swarm_sitl.faults.draws import uniform
from swarm_sitl.faults.plan import FaultPlan, fate, mavlink_channel

_LOCAL_POSITION_NED = 32
_STATUSTEXT = 253
_CORRUPT_BYTE = 3


def sample_ms(datagram: bytes) -> int | None:
    """The ``time_boot_ms`` of a datagram that is a vehicle's per-tick sample: its first frame is
    LOCAL_POSITION_NED (MAVLink 2), or comes after the STATUSTEXTs the vehicle said in the same pass
    (its failsafe, entered or left in that period); None for any other datagram (the answer to a
    request, which starts with its COMMAND_ACK, is start-up traffic)."""
    at, end = 0, len(datagram)
    while at + 14 <= end and datagram[at] == 0xFD:
        msg_id = int.from_bytes(datagram[at + 7 : at + 10], "little")
        if msg_id == _LOCAL_POSITION_NED:
            # (MAVLink 2 drops a payload's trailing zero bytes: a short stamp is zero-extended)
            return int.from_bytes(datagram[at + 10 : at + 10 + min(4, datagram[at + 1])], "little")
        if msg_id != _STATUSTEXT:
            return None
        signed = datagram[at + 2] & 0x01
        at += 12 + datagram[at + 1] + (13 if signed else 0)
    return None


def _flipped(data: bytes, seed: int, *keys: int) -> bytes:
    b = bytearray(data)
    b[int(uniform(seed, *keys, _CORRUPT_BYTE) * len(b))] ^= 0xFF
    return bytes(b)


class MavlinkFaults:
    """The plan's ``mavlink: vehicle`` entries on one vehicle's link; ``MavlinkFaults(plan,
    vehicle, clock, end_s)`` is the one of ``clock``'s kind (``LockstepMavlinkFaults`` for a
    ``TickTime``, ``WallMavlinkFaults`` for a ``WallTime``), which owns the timing rules."""

    def __new__(cls, plan: FaultPlan, vehicle: int, clock: RunClock, end_s: float) -> "MavlinkFaults":
        if cls is MavlinkFaults:
            cls = next(c for kind, c in _BY_CLOCK.items() if isinstance(clock, kind))
        return super().__new__(cls)

    def __init__(self, plan: FaultPlan, vehicle: int, clock: RunClock, end_s: float):
        self.seed = plan.seed
        self.clock = clock
        self.end_s = end_s
        self.rules = {way: plan.on_mavlink(vehicle, way == "up") for way in ("up", "down")}
        self.channel = {way: mavlink_channel(vehicle, way == "up") for way in ("up", "down")}
        self.stats = {way: EdgeStats() for way in ("up", "down")}
        self.lost_ms = -1  #: lockstep: the latest sample time whose datagram the plan lost
        self._period_ms = round(clock.period_s * 1000)
        #: real time: (due, order, way, data, whether it is a duplicate's second copy)
        self._held: list[tuple[float, int, str, bytes, bool]] = []
        self._order = itertools.count()

    # -- the clock's rules -----------------------------------------------------------------------
    def _stats(self, way: str, key_ms: int) -> EdgeStats | None:
        """Where this datagram is counted; None: not counted (it meets its fate all the same)."""
        raise NotImplementedError

    def _up_key(self, stamp_ms: int) -> int:
        """What a setpoint stamped ``stamp_ms`` draws its fate by."""
        raise NotImplementedError

    def _step(self, key: int) -> int:
        """The step a bursty entry's chain is at for a datagram keyed ``key``."""
        raise NotImplementedError

    def _setpoint_lost(self, stamp_ms: int, clock_only: Callable[[int], None]) -> None:
        """A setpoint stamped ``stamp_ms`` was lost or corrupted."""

    def _down_key(self, data: bytes) -> tuple[int, float] | None:
        """What a received datagram draws its fate by, and its time for the plan's windows [s];
        None: it passes untouched."""
        raise NotImplementedError

    def _sample_lost(self, key: int) -> None:
        """A received datagram keyed ``key`` was lost or corrupted."""

    def _fate(self, way: str, key: int, t_s: float) -> Any:
        rules, channel = self.rules[way], self.channel[way]
        return fate(self.seed, rules, channel, key, t_s, self.end_s, self.clock.period_s, self._step(key))

    # -- uplink ----------------------------------------------------------------------------------
    def send(
        self, frame: bytes, stamp_ms: int, write: Callable[[bytes], None], clock_only: Callable[[int], None]
    ) -> None:
        """Send ``frame`` (a setpoint stamped ``stamp_ms``) through ``write`` as the plan says;
        ``clock_only(ms)`` sends a lockstep clock-only setpoint."""
        key = self._up_key(stamp_ms)
        counted = self._stats("up", stamp_ms)
        st = counted or EdgeStats()
        st.received += 1
        f = self._fate("up", key, self.clock.arrival_s(stamp_ms / 1000))
        st.count_fate(bool(f.lost or (f.corrupt and not counted)))
        if f.lost or f.corrupt:
            if f.corrupt and counted:
                st.corrupt += 1
                write(_flipped(frame, self.seed, self.channel["up"], key))
            self._setpoint_lost(stamp_ms, clock_only)
            return
        if f.delay_s > 0:
            st.delayed += 1
            st.delays_s.append(f.delay_s)
            st.held += 1
            self._hold(f.delay_s, "up", frame, False)
        else:
            st.delivered += 1
            write(frame)
        if f.duplicate:
            self._hold(f.delay_s + self.clock.period_s, "up", frame, True)

    # -- downlink --------------------------------------------------------------------------------
    def receive(self, data: bytes) -> bytes | None:
        """The datagram to read now in place of ``data`` (None: none)."""
        keyed = self._down_key(data)
        if keyed is None:
            return data
        key, t = keyed
        counted = self._stats("down", key)
        st = counted or EdgeStats()
        st.received += 1
        f = self._fate("down", key, t)
        st.count_fate(bool(f.lost or (f.corrupt and not counted)))
        if f.lost or f.corrupt:
            self._sample_lost(key)
            if f.lost or not counted:
                return None
            st.corrupt += 1
            return _flipped(data, self.seed, self.channel["down"], key)
        if f.duplicate:
            self._hold(f.delay_s + self.clock.period_s, "down", data, True)
        if f.delay_s > 0:
            st.delayed += 1
            st.delays_s.append(f.delay_s)
            st.held += 1
            self._hold(f.delay_s, "down", data, False)
            return None
        st.delivered += 1
        return data

    # -- real time: what was held ----------------------------------------------------------------
    def next_due_s(self) -> float | None:
        """When the first held datagram is due [run s], or None if none is held."""
        return self._held[0][0] if self._held else None

    def _hold(self, delay_s: float, way: str, data: bytes, copy: bool) -> None:
        """Hold ``data`` for ``delay_s``; ``copy``: a duplicate's second copy (counted when it goes)."""
        heapq.heappush(self._held, (self.clock.now_s() + delay_s, next(self._order), way, data, copy))

    def release(self, write: Callable[[bytes], None]) -> list[bytes]:
        """Send the held uplink datagrams that are due; return the downlink ones to read."""
        held = self._held
        if not held:
            return []
        now = self.clock.now_s()
        out = []
        while held and held[0][0] <= now:
            _, _, way, data, copy = heapq.heappop(held)
            st = self.stats[way]
            st.delivered += 1
            if copy:
                st.duplicated += 1
            else:
                st.held -= 1
            if way == "up":
                write(data)
            else:
                out.append(data)
        return out

    def link_stats(self) -> dict[str, dict[str, Any]]:
        return {way: st.as_dict() for way, st in self.stats.items()}

    def counts_names(self) -> list[str]:
        return [n for way in self.stats for n in counts_names(f"mavlink {way}")]

    def keep_counts(self, counts: NamedCounts) -> None:
        """Count both ways in ``counts`` (names from ``counts_names``)."""
        for way, st in self.stats.items():
            st.bind(counts.view(counts_names(f"mavlink {way}")))


class LockstepMavlinkFaults(MavlinkFaults):
    """Lockstep: fates keyed by ``time_boot_ms``, each tick's datagram counted once, a lost
    setpoint replaced by a clock-only one, a lost sample settled (``lost_ms``)."""

    def __init__(self, plan: FaultPlan, vehicle: int, clock: RunClock, end_s: float):
        super().__init__(plan, vehicle, clock, end_s)
        self._counted_ms = {"up": -1, "down": -1}  #: the newest time each way counted

    def _stats(self, way: str, key_ms: int) -> EdgeStats | None:
        """None: a repeat of a tick's datagram already counted (it meets the same fate, but a
        corrupted repeat is not passed on again: the receiver's count of bad frames must not
        depend on how many repeats the load caused)."""
        if key_ms <= self._counted_ms[way]:
            return None
        self._counted_ms[way] = key_ms
        return self.stats[way]

    def _up_key(self, stamp_ms: int) -> int:
        return stamp_ms

    def _step(self, key: int) -> int:
        return key // self._period_ms  # (a bursty chain moves one step per tick; keys are ms)

    def _setpoint_lost(self, stamp_ms: int, clock_only: Callable[[int], None]) -> None:
        clock_only(stamp_ms + self._period_ms)  # a period the vehicle flies on what it holds

    def _down_key(self, data: bytes) -> tuple[int, float] | None:
        ms = sample_ms(data)
        if ms is None:  # start-up traffic: only the per-tick samples fail in lockstep
            return None
        return ms, ms / 1000

    def _sample_lost(self, key: int) -> None:
        self.lost_ms = key


class WallMavlinkFaults(MavlinkFaults):
    """Real time: fates keyed by each datagram's order, every datagram counted, windows read at
    the wall clock's run time."""

    def _stats(self, way: str, key_ms: int) -> EdgeStats | None:
        return self.stats[way]

    def _up_key(self, stamp_ms: int) -> int:
        return next(self._order)

    def _step(self, key: int) -> int:
        return key

    def _down_key(self, data: bytes) -> tuple[int, float] | None:
        return next(self._order), self.clock.now_s()


_BY_CLOCK: dict[type, type[MavlinkFaults]] = {TickTime: LockstepMavlinkFaults, WallTime: WallMavlinkFaults}
