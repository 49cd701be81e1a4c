"""One follower's controller as a process: its vehicle over MAVLink, its neighbours over the bus.

The step function is the law's (``law_host.HostedLaw.step``), the same one ``sim`` runs; this
module only feeds it. Per tick ``k`` (what a tick is to a law: ``laws.contract``):

- lockstep: wait for the vehicle's sample stamped ``t_k`` and for every in-neighbour's estimate of
  tick ``k - 1`` to have come (``NodeBus.settled``: a fault plan may then hide or hold it); step
  with the newest message of each (``neighbour_inbox``); publish the law's message; send
  SET_ATTITUDE_TARGET stamped ``t_k``, which advances the vehicle one period. A setpoint whose
  answer does not come is sent again (the vehicle answers a repeat with its sample and does not
  step twice). The run is deterministic and equals ``sim``.
- real time: at ``epoch + t_k`` on the wall clock (``t_k`` includes the follower's tick phase,
  ``SwarmConfig.tick_phase_s``), step with the latest sample and the latest
  estimate of each in-neighbour (``neighbour_inbox``); a tick that starts more than one period
  late is skipped.

Either way an in-neighbour whose newest estimate is older than ``estimator.staleness_s`` is left
out of the sums until it speaks again (riding through a lost or cut edge), and a sample older than
a control period is counted (``NodeReport``).
  The sample's instant in swarm time is its ``time_boot_ms`` plus the vehicle's clock offset,
  estimated as the smallest (arrival - stamp) seen.

Every tick is written to ``procs/controller_<i>.rows`` (``row_log``) as it happens.
"""

import math
import sys
import time
from collections.abc import Callable
from typing import Any, NamedTuple

import numpy as np

from sim_vehicles.common.command import AttitudeCommand
from sim_vehicles.mavlink import signing, tick_frames
from sim_vehicles.runtime.event_log import EventLog
from sim_vehicles.runtime.lifeline import mark, settle_heap
from sim_vehicles.runtime.row_log import RowLog
from swarm_sitl.bus.clock import StallError, sleep_until, wait_until, wall_epoch_to_monotonic
from swarm_sitl.bus.codec import Message, State, Status
from swarm_sitl.bus.estimates import newest_for_tick
from swarm_sitl.bus.node_bus import NodeBus
from swarm_sitl.config.schema import RunSection, SwarmConfig
from swarm_sitl.laws.contract import VehicleSample
from swarm_sitl.link.vehicle_link import VehicleLink
from swarm_sitl.nodes.assembly import build_law, law_context
from swarm_sitl.nodes.law_guard import LawGuard, max_output_bytes
from swarm_sitl.nodes.law_host import HostedLaw, LawError, warm_up
from swarm_sitl.nodes.neighbour_inbox import NeighbourInbox
from swarm_sitl.nodes.pacing import Lockstep, Pacer, pacer
from swarm_sitl.nodes.ros2_controller import Ros2Controller
from swarm_sitl.rundir.recording import command_parts

RESEND_AFTER_S = 0.25
#: real time: how long before its first tick a controller arms and switches its vehicle to offboard [s]
ARM_LEAD_S = 0.1
#: lockstep: how long a tick blocks for its vehicle sample before it reads its inputs [s] (the rest
#: of the wait, resends and stall checks included, is ``wait_until``'s)
SAMPLE_WAIT_S = 0.05
#: lockstep: how long a tick still waits for an estimate from a node whose liveliness token has gone
#: (its last messages may come after the token's removal) before the run is called stalled
LOST_GRACE_S = 1.0
#: longest block while waiting on the vehicle's socket and the bus, each of which wakes the wait
#: when something comes: how often resends and stall checks get their turn [s]
IDLE_S = 0.05
#: every this many ticks the bus drops the estimates older than the last tick's (a lockstep tick
#: asks only for those of the tick before it, a real-time one for the newest, which the bus keeps
#: apart; dropping them every tick cost a call per tick). Without it a real-time controller's
#: memory grew by every estimate it had heard (2 MB a minute on paper.yaml, ``bench --soak``)
FORGET_EVERY = 8


class NodeReport(NamedTuple):
    ticks: int
    late_ticks: int  #: real time: ticks skipped (a period behind) or done after the next tick's instant
    max_late_s: float
    resends: int
    dropped_payloads: int
    #: ticks on an old vehicle sample: none new since the tick before (the one before used again,
    #: as when a sample is lost), or one older than a control period
    old_samples: int = 0
    max_sample_age_s: float = 0.0
    stale_estimates: int = 0  #: (tick, in-neighbour) pairs left out: its estimate past staleness


def wait_for_start(bus: NodeBus, link: VehicleLink | None, timeout_s: float, who: str) -> float:
    """Declare this node ready and wait for the supervisor's start; returns the epoch [UNIX s]."""
    mark("ready")
    bus.set_ready()
    fds = [bus.fileno(), *([link.fileno()] if link else [])]

    def read() -> None:
        bus.poll()
        if link is not None:
            link.poll()

    def idle() -> None:
        if link is not None:
            link.send_heartbeat_if_due()

    wait_until(
        lambda: bus.start_epoch() is not None,
        read,
        fds,
        timeout_s,
        lambda: f"{who}: no start signal",
        idle,
        block_s=lambda: IDLE_S,
    )
    epoch = bus.start_epoch()
    assert epoch is not None
    return epoch


class _Inputs:
    """What one tick waits for, and reading it: the vehicle link and the bus."""

    def __init__(self, who: str, node: int, link: VehicleLink, bus: NodeBus, sources: list[int], dt: float):
        self.who, self.node, self.link, self.bus, self.sources, self.dt = who, node, link, bus, sources, dt
        # lockstep: either input wakes the wait
        self.fds = [link.fileno(), bus.fileno()]
        # real time: the bus is read at the tick only, and so is a link with kernel arrival stamps
        # (no wake-up per datagram); any other link is read as its datagrams come, to stamp them
        self.tick_fds = [] if link.stamps_arrivals else [link.fileno()]
        self.epoch_mono = math.nan
        self.offset_s = math.inf  #: vehicle boot time -> swarm time (real time)
        self._last_ms = -1
        self.last_cmd: AttitudeCommand | None = None
        self.sent_at = math.inf
        self.resends = 0
        # lockstep: the tick being waited for; the first one (0, or where a restart resumes) waits
        # for no estimate
        self.first = 0
        self.k = 0
        self.t_ms = 0
        self.need: list[int] = []
        self._lost_since = math.inf
        #: lockstep: the tick last finished, its instant [s], its sample's [s] and position [m]
        #: (what a node held mid-tick says: ``idle``), and the tick last said so
        self.done: tuple[int, float, float, np.ndarray] | None = None
        self._said = -1
        self.old_samples = 0  #: ticks on an old vehicle sample (``NodeReport.old_samples``)
        self.max_age = 0.0  #: the oldest sample a tick flew on [s]
        self.stall_timeout_s = math.inf

    def read(self) -> None:
        self.bus.poll()
        self.read_link()

    def read_link(self, readable: bool = False, until_ms: int = -1) -> None:
        link = self.link
        link.poll(readable, until_ms)
        sample_ms = link.sample_ms
        if sample_ms != self._last_ms:
            self._last_ms = sample_ms
            arrival = link.sample_arrival_mono - self.epoch_mono
            self.offset_s = min(self.offset_s, arrival - sample_ms / 1000.0)

    # -- lockstep --------------------------------------------------------------------------------
    def _lacking(self) -> list[int]:
        """The in-neighbours whose estimate of tick ``k - 1`` has not come."""
        return [s for s in self.need if not self.bus.settled(s, self.k - 1)]

    def ready(self) -> bool:
        return self.link.sample_settled(self.t_ms) and not self._lacking()

    def missing(self) -> str:
        k = self.k
        lacking = self._lacking()
        what = [f"estimate of node {s} for tick {k - 1}" for s in lacking]
        if not self.link.sample_settled(self.t_ms):
            what.append(f"vehicle sample at {self.t_ms} ms (latest {self.link.sample_ms} ms)")
        gone = self.bus.lost() & set(lacking)
        tail = f"; node(s) {sorted(gone)} went away" if gone else ""
        return f"{self.who} at tick {k}: no {', '.join(what)}{tail}"

    def idle(self) -> None:
        done = self.done
        if done is not None and done[0] > self.bus.hold_tick() and self._said != done[0]:
            # it finished a tick past the hold before it heard of it, and this tick's inputs may
            # be held: it says where it is, and the supervisor brings the hold up to it
            self._said = done[0]
            self.bus.publish_status(Status(self.node, *done))
        if (
            self.last_cmd is not None
            and not self.link.sample_settled(self.t_ms)
            and time.monotonic() - self.sent_at > RESEND_AFTER_S
        ):  # the setpoint or its answer was lost: send it again, the vehicle will not step twice
            self.link.send_setpoint(self.last_cmd, self.t_ms - round(self.dt * 1000))
            self.sent_at = time.monotonic()
            self.resends += 1
        # a node that finished its run and exited is gone too: only an estimate that is missing
        # from a node that is gone stalls the tick
        if not self.bus.lost() & set(self._lacking()):
            self._lost_since = math.inf
            return
        now = time.monotonic()
        self._lost_since = min(self._lost_since, now)
        if now - self._lost_since > LOST_GRACE_S:
            raise StallError(self.missing())

    def newest_lockstep(self, src: int) -> Message | None:
        """The in-neighbour's estimate of tick ``k - 1``, or (a fault plan hid or held it) the
        newest it may use now."""
        return newest_for_tick(self.bus, src, self.k)

    def wait_lockstep(self, k: int, timeout_s: float) -> None:
        self.k, self.t_ms = k, round(k * self.dt * 1000)
        self.need = self.sources if k > self.first else []
        if self.link.sample_ms != self.t_ms:
            # the vehicle answers the setpoint just sent: a read before its datagram comes finds
            # nothing, so block for it first (in the read itself: ``VehicleLink.block_reads``),
            # then read the bus
            self.read_link(True, self.t_ms)
            self.bus.poll()
        if not self.ready():
            wait_until(
                self.ready,
                self.read,
                self.fds,
                timeout_s,
                self.missing,
                self.idle,
                block_s=lambda: IDLE_S,
                hold=self.bus.hold_tick,
            )

    def send(self, cmd: AttitudeCommand, time_boot_ms: int) -> None:
        self.last_cmd = cmd
        self.link.send_setpoint(cmd, time_boot_ms)
        self.sent_at = time.monotonic()


class _LockstepInputs(_Inputs):
    """A lockstep tick's inputs: the vehicle's sample stamped ``t_k`` and the in-neighbours'
    estimates of tick ``k - 1``, waited for (module docstring)."""

    def start(self, clock: Pacer, resume_tick: int, phase_s: float, r: RunSection) -> None:
        link = self.link
        if resume_tick:  # the vehicle flew on its own through the gap: its clock moves first
            link.advance_to(round(resume_tick * self.dt * 1000), r.start_timeout_s)
        link.engage(r.start_timeout_s, True)
        link.request_sample(r.start_timeout_s)
        self.epoch_mono = wall_epoch_to_monotonic(wait_for_start(self.bus, link, r.start_timeout_s, self.who))
        clock.epoch_mono = self.epoch_mono
        self.first = clock.first_tick(resume_tick, phase_s)
        link.block_reads(SAMPLE_WAIT_S)  # a tick's first read of its link waits for the vehicle's answer
        self.stall_timeout_s = r.stall_timeout_s

    def tick(
        self, k: int, t: float, inbox_of: NeighbourInbox
    ) -> tuple[dict, float, np.ndarray, np.ndarray, np.ndarray, float]:
        """``(inbox, the sample's boot time [s], p, v, q, its instant [s])`` of tick ``k``."""
        self.wait_lockstep(k, self.stall_timeout_s)
        inbox = inbox_of.gather(t, self.newest_lockstep) if k > self.first else {}
        boot_s, p, v, q = self.link.sample()
        sample_t = t
        if self.link.sample_ms != self.t_ms:  # a fault plan lost it: the one before, carried
            sample_t = boot_s
            self.old_samples += 1
            self.max_age = max(self.max_age, t - boot_s)
        return inbox, boot_s, p, v, q, sample_t

    def stamp_ms(self, t: float) -> int:
        """A setpoint's ``time_boot_ms``: its tick's instant, which steps the vehicle there."""
        return round(t * 1000)

    def finished(self, k: int, t: float, sample_t: float, p: np.ndarray) -> None:
        self.done = (k, t, sample_t, p)


class _WallInputs(_Inputs):
    """A real-time tick's inputs: the latest sample and estimates at its instant (module docstring)."""

    def start(self, clock: Pacer, resume_tick: int, phase_s: float, r: RunSection) -> None:
        self.epoch_mono = wall_epoch_to_monotonic(
            wait_for_start(self.bus, self.link, r.start_timeout_s, self.who)
        )
        clock.epoch_mono = self.epoch_mono
        # the swarm's clock where it stands: tick 0 at the run's start (the start signal comes
        # half a second ahead), a later one for a controller started again mid-run (a fault
        # plan's restart, or one started by hand), which flies its vehicle from there on
        self.first = clock.first_tick(resume_tick, phase_s, ARM_LEAD_S)
        # offboard only just before the setpoints start: offboard without setpoints for
        # the setpoint timeout (COM_OF_LOSS_T) is the vehicle's failsafe
        sleep_until(
            self.epoch_mono + self.first * self.dt + phase_s - ARM_LEAD_S, self.tick_fds, self.read_link
        )
        self.link.engage(r.start_timeout_s, False)
        self._used_boot_s = math.nan  # the sample the tick before flew on

    def tick(
        self, k: int, t: float, inbox_of: NeighbourInbox
    ) -> tuple[dict, float, np.ndarray, np.ndarray, np.ndarray, float]:
        link = self.link
        if link.sample_ms < 0:
            raise StallError(f"{self.who}: no vehicle sample at tick {k}")
        inbox = inbox_of.gather(t, self.bus.latest)
        boot_s, p, v, q = link.sample()
        sample_t = min(boot_s + self.offset_s, t)
        age = t - sample_t
        # (a lost sample's successor is about a period old, and whether its age reads above or
        # below dt turns on time_boot_ms's millisecond: the sample used again is what tells)
        if age > self.dt or boot_s == self._used_boot_s:
            self.old_samples += 1
            self.max_age = max(self.max_age, age)
        self._used_boot_s = boot_s
        return inbox, boot_s, p, v, q, sample_t

    def stamp_ms(self, t: float) -> int:
        """A setpoint's ``time_boot_ms``: its tick's instant on the vehicle's clock."""
        return round((t - self.offset_s) * 1000)

    def finished(self, k: int, t: float, sample_t: float, p: np.ndarray) -> None:
        return None


def _warm_up(cfg: SwarmConfig, i: int, link: VehicleLink, sources: list[int]) -> None:
    """Two ticks of a scratch law (``sources``: its in-neighbours) and a call of each per-tick
    frame kernel: the compiled kernels load now, not in the first ticks."""
    tick_frames.warm_up()
    signing.warm_up()
    scratch = build_law(cfg, i, link.mass_kg, link.full_thrust_N)
    x = np.zeros(3)
    sample = VehicleSample(0.0, x, x, np.array([1.0, 0.0, 0.0, 0.0]))
    warm_up(scratch.law, sample, sources, scratch.message_length)


def run_controller(
    cfg: SwarmConfig,
    i: int,
    link: VehicleLink,
    bus: NodeBus,
    lockstep: bool,
    rows: RowLog | None,
    clock: Pacer | None = None,
    events: EventLog | None = None,
    resume_tick: int = 0,
    states: Callable[[State], None] | None = None,
    ros2_session: Any = None,
) -> NodeReport:
    """Follower ``i``'s loop; ``clock`` is where the run is for ``bus``'s wrappers (it is set
    here), ``events`` takes what the follower sees happen (lost and regained neighbours),
    ``states`` its vehicle's state with each status (a run with ``ros2:`` on). A follower of
    ``ros2.controllers`` is flown by a ROS 2 node through ``ros2_session`` (``ros2_controller``),
    in place of the law.
    ``resume_tick``: a controller restarted by a fault plan in lockstep takes its vehicle up at
    this tick (its clock moved there first, through the gap it flew on its own), with a fresh
    state, like tick 0. In real time a controller joins at the tick the swarm's clock is at
    (``join_tick``: the start epoch, its tick phase, the wall clock), whatever ``resume_tick``."""
    who = f"follower {i}"
    r = cfg.run
    dt = cfg.control_dt_s
    clock = pacer(lockstep, dt) if clock is None else clock
    clock.attach(bus, r.stall_timeout_s)
    events = EventLog(None, f"controller_{i}") if events is None else events
    link.connect(r.start_timeout_s, cfg.vehicle.mass_kg, cfg.gravity_mps2)
    if i in cfg.ros2.controllers:
        ctx = law_context(cfg, i, link.mass_kg, link.full_thrust_N)
        within = (r.start_timeout_s, r.tick_timeout_s) if clock.lockstep else None  # (its answers)
        law = HostedLaw(Ros2Controller(ctx, ros2_session, cfg.ros2, cfg.law_class(), within), i, "ros2")
    else:
        law = build_law(cfg, i, link.mass_kg, link.full_thrust_N)
    sources = [s for s, _ in cfg.build_graph().in_neighbours(i)]
    inputs = _LockstepInputs if isinstance(clock, Lockstep) else _WallInputs
    io = inputs(who, i, link, bus, sources, dt)
    inbox_of = NeighbourInbox(i, sources, cfg.estimator.staleness_s, events)
    _warm_up(cfg, i, link, sources)
    settle_heap()
    guard = None
    if not cfg.law.is_paper:  # a user's law: stopped if it hangs, exits or floods (law_guard)
        guard = LawGuard(
            r.tick_timeout_s,
            cfg.law.max_memory_mb,
            sys.stdout,
            max_output_bytes(cfg.law.max_output_mb),
            None if rows is None else lambda line: _last_words(rows, line),
        )
        law.guard = guard
    try:
        return _loop(cfg, i, link, bus, rows, clock, resume_tick, law, io, inbox_of, states)
    finally:
        if guard is not None:
            guard.close()


def _last_words(rows: RowLog, line: str) -> None:
    """A law held in compiled code past its guard's stop: the rows so far kept, the line said."""
    try:
        rows.flush()
    finally:
        print(line, file=sys.__stderr__, flush=True)


def _loop(
    cfg: SwarmConfig,
    i: int,
    link: VehicleLink,
    bus: NodeBus,
    rows: RowLog | None,
    clock: Pacer,
    resume_tick: int,
    law: HostedLaw,
    io: "_LockstepInputs | _WallInputs",
    inbox_of: NeighbourInbox,
    states: Callable[[State], None] | None = None,
) -> NodeReport:
    """``run_controller``'s ticks, its law built and warmed up: one loop for both clocks (the
    clock paces the ticks, ``pacing``; the inputs read what a tick of that clock flies on)."""
    r = cfg.run
    dt = cfg.control_dt_s
    n = cfg.n_control_steps
    phase = cfg.tick_phase_s(i, clock.lockstep)
    link.request_rates(dt, r.other_telemetry_hz, r.start_timeout_s)
    io.start(clock, resume_tick, phase, r)
    k = io.first
    while k <= n:
        t = k * dt + phase
        at, lateness = clock.wait_instant(k, phase, io.tick_fds, io.read_link, io.read, last=n)
        if at != k:  # a whole period behind: skip to the current tick
            k = at
            continue
        inbox, boot_s, p, v, q, sample_t = io.tick(k, t, inbox_of)
        link.check_vehicle()  # (rebooted or disarmed: this controller ends, in one line)
        try:
            step = law.step(t, VehicleSample(sample_t, p, v, q), inbox)
        except LawError as e:
            inputs = getattr(e.__cause__, "inputs", None)
            if rows is not None and inputs is not None:  # what it was given, to reproduce it offline
                np.savez(rows.path.with_suffix(".failure.npz"), **inputs)
            raise
        bus.publish(Message(i, k, t, step.message, (float(p[0]), float(p[1]), float(p[2]))))
        if k < n:
            io.send(step.command, io.stamp_ms(t))
        done = clock.out_at(k, phase)  # the setpoint is out this long after t_k
        if rows is not None:
            rows.append(
                (k, t, boot_s, sample_t, lateness, done),
                p,
                v,
                q,
                *command_parts(step.command),
                step.record,
                inbox_of.ages,
            )
        # a node held after this tick says where it stopped (a page shows each step)
        held = clock.held(k)
        if held or k % r.status_every == 0 or k == n or k == io.first:
            bus.publish_status(Status(i, k, t, sample_t, p))
            if states is not None:  # (a run with ros2: on: what its ROS 2 face republishes)
                states(State(i, k, t, p, v, q, link.downlink.rates_B(), step.message))
        io.finished(k, t, sample_t, p)
        if held and k < n:
            clock.hold_after(k, io.read, io.fds, link.send_heartbeat_if_due)
        if k % FORGET_EVERY == 0:
            bus.forget_before(k - 1)
        k += 1
    clock.end(n, phase)
    return NodeReport(
        n + 1 - io.first,
        clock.late,
        clock.max_late_s,
        io.resends,
        bus.dropped + link.rx_bad,
        io.old_samples,
        io.max_age,
        sum(inbox_of.stale_ticks.values()),
    )
