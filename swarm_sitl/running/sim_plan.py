"""A fault plan in ``sim``, as a lockstep run of processes carries it out, tick for tick.

``sim`` without a plan is ``running.sim``'s loop; with one, each part of the plan acts here by the
same code and at the same tick as in a lockstep run (``docs/faults.md``), so the two record the
same run, bit for bit (``tests/test_sim_faults.py``):

- **Edges** (loss, delay, jitter, stall, duplicate, reorder, corrupt, bursty, range, bandwidth,
  partitions, a user's link model): each follower's in-edges go through the plan's stage
  (``faults.in_edges.InEdges``) into its ``EstimateTable``, as in the zenoh wrapper; a message of
  tick ``k`` comes once every node has published tick ``k`` (in lockstep it is needed at ``k + 1``),
  and the law's inbox is ``neighbour_inbox``'s, as a controller gathers it.
- **MAVLink** (drop, loss, bursty, corrupt; lockstep's kinds): a setpoint the plan loses is a
  clock-only one (the vehicle flies one period on what it holds, and counts it as no setpoint:
  its failsafe after ``setpoint_timeout_s``); a sample it loses is a tick that carries the newest
  one before it, recorded with that sample's true state and time, as ``merge`` records it (an
  incarnation's first sample answers its request: start-up traffic, never lost). The fates are
  keyed by ``time_boot_ms``, as ``faults.mavlink`` keys them in lockstep (read from a
  ``faults.fate_table.FateTable`` per way of a link when its models draw many at once).
- **Processes**: a node killed at tick ``k`` publishes nothing from ``k`` on and records nothing
  (its controller dies before it publishes ``k``); its vehicle flies its failsafe through the gap
  in simulated time, period by period, and a restarted controller takes it up at its restart
  tick with a fresh law, inbox and stage, hearing what its in-neighbours publish from that tick
  on. A lost vehicle takes its controller with it. A freeze costs a lockstep run wall time only:
  nothing here.

The vehicle is the vehicle process's own arming, modes and failsafe (``sim_vehicles.vehicle.modes``)
over the same plant, stepped as its endpoint steps it; under a plan with no MAVLink or process
entry (nothing can take a setpoint away, so its modes have nothing to do) it is stepped as ``sim``
steps it without a plan.
"""

from collections.abc import Callable
from typing import Any

import numpy as np

from sim_vehicles.common.command import AttitudeCommand
from sim_vehicles.mavlink import ardupilot_profile as ap_profile
from sim_vehicles.mavlink import px4_profile as px4
from sim_vehicles.models.build import build_vehicle, sensor_model
from sim_vehicles.models.vehicle_config import VehicleConfig
from sim_vehicles.plant.failsafe import ACTIONS
from sim_vehicles.runtime.event_log import EventLog
from sim_vehicles.vehicle.autopilots import PROFILES, PX4
from sim_vehicles.vehicle.modes import MODE_OFFBOARD, FlightModes
from swarm_sitl.bus.clock import RunClock
from swarm_sitl.bus.codec import Message
from swarm_sitl.bus.estimates import EstimateTable
from swarm_sitl.config.schema import SwarmConfig
from swarm_sitl.faults.fate_table import FateTable, batched
from swarm_sitl.faults.in_edges import InEdges
from swarm_sitl.faults.plan import down_at, fate, mavlink_channel
from swarm_sitl.laws.contract import VehicleSample
from swarm_sitl.nodes.assembly import Uplink, build_law, reported_vehicle_params
from swarm_sitl.nodes.controller import FORGET_EVERY
from swarm_sitl.nodes.law_guard import LawGuard
from swarm_sitl.nodes.law_host import HostedLaw
from swarm_sitl.nodes.neighbour_inbox import NeighbourInbox
from swarm_sitl.rundir.recording import Series, SeriesMaker, in_memory

Sampler = Callable[[float, np.ndarray], VehicleSample]


class _Table(EstimateTable):
    """A follower incarnation's table; it counts the steps its process would (``entry``'s
    ``counted_steps``: from its first tick to its next planned kill or the run's end)."""

    def __init__(self, counted: range):
        super().__init__()
        self.counted = counted

    def counts(self, step: int) -> bool:
        return step in self.counted


class MemoryEvents(EventLog):
    """Events kept in a list, as ``events.jsonl`` has them (no wall-clock stamps)."""

    def __init__(self, source: str, into: list[dict[str, Any]]):
        super().__init__(None, source)
        self.into = into

    def add(self, t_s: float, kind: str, **fields: Any) -> None:
        super().add(t_s, kind)
        fields.pop("unix_s", None)
        self.into.append({"t_s": round(t_s, 9), "kind": kind, "source": self.source, **fields})


class _Vehicle:
    """One vehicle as its process flies it in lockstep: armed and in offboard from the start;
    ``events`` takes its failsafe's entries and exits."""

    def __init__(
        self,
        spec: VehicleConfig,
        i: int,
        n_att: int,
        uplink: Uplink,
        events: list[dict[str, Any]],
        steady: bool,
    ):
        self.ap = ap = build_vehicle(spec, i)
        self.n_att = n_att
        #: whether the plan can never take a setpoint away (no MAVLink or process entry): in
        #: offboard with a setpoint every period, its modes have nothing to do, and are skipped
        self.steady = steady
        self.uplink = uplink
        self.sensors = sensor_model(spec, i)
        say: Callable[[int, str], None] = lambda severity, text: None  # noqa: E731  (no ground station)
        self.flight = FlightModes(
            ap,
            i,
            spec.setpoint_timeout_s,
            ACTIONS[spec.failsafe_action],
            MemoryEvents(f"vehicle_{i}", events),
            say,
            PROFILES[spec.autopilot],
        )
        self.flight.arm(True, False)
        self.offboard()

    def offboard(self) -> None:
        """``link.handshake.engage``: PX4's OFFBOARD after a clock-only setpoint at its time;
        an ArduCopter's GUIDED_NOGPS."""
        f = self.flight
        f.offboard_signal_s = self.ap.time_s
        f.set_mode(px4.OFFBOARD if f.profile is PX4 else ap_profile.GUIDED_NOGPS)

    def step(self) -> None:
        """One period on what it holds (the endpoint's ``step``: its own loop in its failsafe)."""
        f, ap = self.flight, self.ap
        left = self.n_att
        while left > 0:
            chunk = f.own_steps(left)
            ap.advance(chunk)
            left -= chunk
            f.check_failsafe()

    def setpoint(self, cmd: AttitudeCommand) -> None:
        """A valid setpoint stamped with its time: taken, then one period (in offboard, within
        the setpoint timeout, that is one call of the plant: ``lockstep_tick``'s usual tick)."""
        f, ap = self.flight, self.ap
        if self.steady:
            ap.set_command(self.uplink(cmd, ap))
            ap.advance(self.n_att)
            return
        f.offboard_signal_s = ap.time_s
        if f.take_setpoint():
            ap.set_command(self.uplink(cmd, ap))
        if f.mode == MODE_OFFBOARD and self.n_att * ap.dt_s <= f.setpoint_timeout_s:
            ap.advance(self.n_att)  # (its own loop has nothing to do, its failsafe cannot begin)
        else:
            self.step()

    def reported(self, ms: int) -> np.ndarray:
        x = self.ap.state
        return x if self.sensors is None else self.sensors.reported(ms, x)


class _Follower:
    """One incarnation of a follower's controller: from tick ``first`` on."""

    def __init__(
        self, law: HostedLaw, table: _Table, stage: InEdges | None, inbox: NeighbourInbox, first: int
    ):
        self.law, self.table, self.stage, self.inbox, self.first = law, table, stage, inbox, first
        #: the newest sample it has (a tick whose own the plan lost carries it), with its true state
        self.sample: tuple[VehicleSample, np.ndarray] | None = None


class PlannedSwarm:
    """The followers, their vehicles and what the plan does to them, tick by tick."""

    def __init__(self, cfg: SwarmConfig, n: int, sample: Sampler, make_series: SeriesMaker = in_memory):
        """``n``: the run's last tick; ``series``: what it records, rows 0..n (``make_series``)."""
        cfg.faults.check_lockstep()
        self.cfg = cfg
        self.plan = plan = cfg.faults
        self.sample = sample
        self.dt = dt = cfg.control_dt_s
        self.n = n
        self.ids = [f.id for f in cfg.followers]
        graph = cfg.build_graph()
        self.edges = cfg.graph_edges()
        self.sources = {i: [int(s) for s, _ in graph.in_neighbours(i)] for i in self.ids}
        self.outs: dict[int, list[int]] = {}
        for s, d in self.edges:
            self.outs.setdefault(s, []).append(d)
        self.outages = plan.outages(dt)
        self.clock = RunClock(True, dt)
        self.mass_max = reported_vehicle_params(cfg)
        n_att = cfg.rates.attitude_steps_per_control
        self.events: list[dict[str, Any]] = []  #: the vehicles' (``MemoryEvents``)
        steady = not any(f.is_process or f.mavlink is not None for f in plan.plan)
        self.vehicles = {
            i: _Vehicle(cfg.vehicle_config(i), i, n_att, Uplink(cfg, i), self.events, steady)
            for i in self.ids
        }
        self.period_ms = round(dt * 1000)
        self.up_rules = {i: plan.on_mavlink(i, True) for i in self.ids}
        self.down_rules = {i: plan.on_mavlink(i, False) for i in self.ids}
        #: the fates of each way of each vehicle's link a plan entry acts on, a block at a time
        self.mavlink_fates = {
            (i, up): FateTable(plan.seed, rules, mavlink_channel(i, up), cfg.duration_s, dt, stamp_ms=True)
            for up, by_vehicle in ((True, self.up_rules), (False, self.down_rules))
            for i, rules in by_vehicle.items()
            if rules and batched(rules)
        }
        self.guard: LawGuard | None = None  #: a user's law's guard, given to every incarnation
        #: the nodes whose in-edges a plan entry acts on (the others file what comes as it comes)
        self.faulty = {i for i in self.ids if any(plan.on_edge(s, i, self.edges) for s in self.sources[i])}
        self.followers: dict[int, _Follower | None] = {i: self._incarnation(i, 0) for i in self.ids}
        self.series: dict[int, Series] = {
            i: make_series(i, n + 1, f.law.law.record_fields, len(self.sources[i]))
            for i, f in self.followers.items()
            if f is not None
        }

    # -- incarnations ------------------------------------------------------------------------------
    def _incarnation(self, i: int, first: int) -> _Follower:
        law = build_law(self.cfg, i, *self.mass_max)
        law.guard = self.guard
        kills = [k for k, _ in self.outages.get(i, []) if k > first]
        table = _Table(range(first, min([*kills, self.n])))
        stage = None
        if i in self.faulty:
            stage = InEdges(table, self.plan, i, self.edges, self.clock, self.cfg.duration_s, self.outages)
            stage.in_order = True  # (``tick`` admits tick k's messages after every node's tick k)
        inbox = NeighbourInbox(i, self.sources[i], self.cfg.estimator.staleness_s, EventLog(None, f"c{i}"))
        return _Follower(law, table, stage, inbox, first)

    def set_guard(self, guard: LawGuard) -> None:
        self.guard = guard
        for f in self.followers.values():
            if f is not None:
                f.law.guard = guard

    def down(self, node: int, k: int) -> bool:
        o = self.outages.get(node)
        return o is not None and down_at(o, k)

    def _restarts_at(self, node: int, k: int) -> bool:
        o = self.outages.get(node)
        return o is not None and any(back == k for _, back in o)

    def _returns(self, node: int, k: int) -> bool:
        """Whether ``node``, down at ``k``, is started again later."""
        return any(first <= k and back is not None and k < back for first, back in self.outages.get(node, []))

    def _lost(self, rules: list, vehicle: int, uplink: bool, k: int, ms: int) -> bool:
        """``faults.mavlink``'s lockstep fate of the datagram of tick ``k``, stamped ``ms`` (lost
        or corrupted)."""
        table = self.mavlink_fates.get((vehicle, uplink))
        if table is not None:
            f = table.at(k)
        else:
            f = fate(
                self.plan.seed,
                rules,
                mavlink_channel(vehicle, uplink),
                ms,
                ms / 1000,
                self.cfg.duration_s,
                self.dt,
                ms // self.period_ms,
            )
        return f.lost or f.corrupt

    # -- one tick ----------------------------------------------------------------------------------
    def tick(self, k: int, leader: Message | None) -> dict[int, Message]:
        """Tick ``k`` of every follower (``leader``: the reference it published, None if it is
        down); returns what each follower published."""
        self.clock.tick = k
        t = k * self.dt
        out: dict[int, Message] = {}
        outages = self.outages
        for i in self.ids:
            v = self.vehicles[i]
            if i in outages and self.down(i, k):
                self.followers[i] = None
                if self._returns(i, k):  # its vehicle flies on its own through the gap, and
                    v.step()  # sends its sample each period (its sensors' latency keeps them)
                    v.reported(round((k + 1) * self.dt * 1000))
                continue
            f = self.followers[i]
            if f is None or (i in outages and self._restarts_at(i, k)):
                f = self.followers[i] = self._incarnation(i, k)
                v.offboard()
            m = self._follower_tick(i, k, t, f, v)
            out[i] = m
        for src, m in ([(0, leader)] if leader is not None else []) + list(out.items()):
            for d in self.outs.get(src, []):
                g = self.followers.get(d)
                if g is None or (d in outages and self.down(d, k)):
                    continue
                if g.stage is not None:
                    g.stage.admit(m)
                else:
                    g.table.file(m)
        return out

    def _follower_tick(self, i: int, k: int, t: float, f: _Follower, v: _Vehicle) -> Message:
        ms = round(t * 1000)
        reported = v.reported(ms)  # (sent whether or not the plan loses it: sensors with latency keep it)
        # (an incarnation's first sample is the answer to its request, start-up traffic: never lost)
        down = self.down_rules[i]
        if down and k > f.first and self._lost(down, i, False, k, ms) and f.sample is not None:
            # the newest it has, carried, at its time_boot_ms
            sample, truth = f.sample
            sample = sample._replace(t_s=round(sample.t_s * 1000) / 1000)
        else:
            sample, truth = self.sample(t, reported), v.ap.state
            if down:  # (kept for the ticks whose sample the plan loses)
                f.sample = (sample, truth.copy())
        self.series[i].record_vehicle(k, t, truth, sample.t_s)
        if f.stage is not None:
            f.stage.release()
        # what lockstep's tick uses (``newest_for_tick``) is the newest filed: the messages of
        # tick k are admitted after every node's tick k (``tick``), so the table holds none of
        # tick k or later, and the estimate of tick k - 1, when it has come, is the newest
        inbox = f.inbox.gather(t, f.table.latest) if k > f.first else {}
        step = f.law.step(t, sample, inbox)
        x, y, z = sample.p_W.tolist()
        msg = Message(i, k, t, step.message, (x, y, z))
        if f.stage is not None:
            f.stage.published(msg)
        self.series[i].record_controller(k, step.command, step.record, f.inbox.ages)
        if k < self.n:
            up = self.up_rules[i]
            if up and self._lost(up, i, True, k, ms):
                v.step()  # a clock-only setpoint in its place
            else:
                v.setpoint(step.command)
        if k % FORGET_EVERY == 0:
            f.table.forget_before(k - 1)
        return msg
