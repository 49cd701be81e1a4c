"""The entry of the node processes: ``python -m swarm_sitl.nodes controller|leader CONFIG ...``.

``run`` and ``controllers`` start these (forked from the fork server, or as new interpreters);
``swarm-sitl controller`` and ``swarm-sitl leader`` are the same, for a node started by hand
(another host, a debugger). Each builds its node from the config (its vehicle link, its bus, the
fault plan's wrappers, its recording), runs it (``controller``, ``leader``) and prints one line
when it is done, or one error line naming what failed (exit 1; a bad config or argument: exit 2);
SIGTERM/SIGINT end it cleanly (its recording is flushed, exit 130).
"""

import argparse
import json
import signal
import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import zenoh

from sim_vehicles.mavlink.signing import SigningKeyError, read_key
from sim_vehicles.runtime.counter_file import CounterFile, NamedCounts
from sim_vehicles.runtime.event_log import EventLog
from sim_vehicles.runtime.lifeline import batch_scheduling, hold_on, mark, process_figures, profiled
from sim_vehicles.runtime.row_log import RowLog
from swarm_sitl.bus import keys as zenoh_keys
from swarm_sitl.bus.access import credentials_from_env
from swarm_sitl.bus.clock import RunClock, StallError
from swarm_sitl.bus.codec import State, encode_state
from swarm_sitl.bus.node_bus import NodeBus, ZenohNodeBus
from swarm_sitl.bus.session import error_line, open_session
from swarm_sitl.config.load import ConfigError, load_config, with_duration
from swarm_sitl.config.schema import SwarmConfig
from swarm_sitl.faults.edges import FaultyBus, acts_on
from swarm_sitl.faults.mavlink import MavlinkFaults
from swarm_sitl.laws.graph import GraphError
from swarm_sitl.link.transport import LinkError
from swarm_sitl.link.vehicle_link import VehicleLink
from swarm_sitl.nodes.arguments import add_node_parsers
from swarm_sitl.nodes.controller import run_controller
from swarm_sitl.nodes.law_host import LawError
from swarm_sitl.nodes.leader import run_leader
from swarm_sitl.nodes.pacing import pacer
from swarm_sitl.nodes.ros2_clock import Ros2Clock
from swarm_sitl.rundir.layout import (
    controller_columns,
    controller_events_path,
    controller_rows_path,
    controller_stats_path,
    counts_path,
    leader_stats_path,
    node_stem,
    published_path,
    tick_path,
)
from swarm_sitl.rundir.metrics import describe_inputs

EXIT_USAGE = 2


def _terminate(signum: int, frame: object) -> None:
    raise KeyboardInterrupt


def _state_out(session: Any, cfg: SwarmConfig, i: int) -> Callable[[State], None]:
    """Where follower ``i``'s vehicle state goes with each status (a run with ``ros2:`` on): its
    ``state`` key, dropped rather than waited for when the link is congested (no run waits for
    what ROS 2 sees)."""
    pub = session.declare_publisher(
        zenoh_keys.state(cfg.name, i), congestion_control=zenoh.CongestionControl.DROP
    )
    return lambda s: pub.put(encode_state(s))


def _session(cfg: SwarmConfig, connect: list[str]) -> Any:
    return open_session(cfg.zenoh, connect, credentials_from_env())


def _guarded(name: str, body: Any, lockstep: bool) -> int:
    hold_on()
    if lockstep:  # before zenoh starts its threads, so they inherit it
        batch_scheduling()
    signal.signal(signal.SIGTERM, _terminate)
    try:
        line = profiled(name, body)
    except (LinkError, StallError, LawError, SigningKeyError) as e:
        print(f"{name}: error: {e}", file=sys.stderr, flush=True)
        return 1
    except zenoh.ZError as e:
        print(f"{name}: error: zenoh: {error_line(e)}", file=sys.stderr, flush=True)
        return 1
    except KeyboardInterrupt:
        print(f"{name}: stopped", file=sys.stderr, flush=True)
        return 130
    print(line, flush=True)
    return 0


def _write_stats(path: Path, stats: dict[str, Any]) -> None:
    """A node's figures at its end, for the run's summary (``rundir.merge``)."""
    tmp = path.with_suffix(".tmp")
    tmp.write_text(json.dumps(stats, indent=1, sort_keys=True) + "\n")
    tmp.replace(path)


def _faulty_bus(
    cfg: SwarmConfig, zbus: ZenohNodeBus, node: int, clock: RunClock, resume_tick: int
) -> FaultyBus | None:
    """Node ``node``'s bus under the fault plan, if the plan acts on it."""
    edges = cfg.graph_edges()
    if not acts_on(cfg.faults, node, edges):
        return None
    return FaultyBus(
        zbus, cfg.faults, node, edges, clock, cfg.duration_s, cfg.run.stall_timeout_s, resume_tick
    )


def in_edge_stats(zbus: Any, faulty: Any) -> dict[int, dict[str, int]]:
    """Per in-neighbour: what came (``received``), what the fault plan let through
    (``delivered``), and what the bus refused (``refused``, only if any)."""
    stats = (
        faulty.edge_stats()
        if faulty
        else {s: {"received": n, "delivered": n} for s, n in zbus.received.items()}
    )
    for s, n in zbus.refused.items():
        stats.setdefault(s, {})["refused"] = n
    return stats


def cmd_controller(cfg: SwarmConfig, args: argparse.Namespace) -> int:
    """Follower ``args.id``'s controller process."""
    mark("main")
    i = args.id
    if i not in {f.id for f in cfg.followers}:
        print(
            f"swarm-sitl: error: --id {i} is not a follower of {cfg.name} (ids 1..{cfg.n_followers})",
            file=sys.stderr,
        )
        return EXIT_USAGE

    def body() -> str:
        rows = events = link = session = None
        bus: Any = None
        out = Path(args.out) if args.out else None
        try:
            if out is not None:
                path = controller_rows_path(out, i, args.incarnation)
                path.parent.mkdir(parents=True, exist_ok=True)
                n_in = len(cfg.build_graph().in_neighbours(i))
                rows = RowLog(path, controller_columns(cfg.law_class().record_fields, n_in))
            events = EventLog(
                controller_events_path(out, i, args.incarnation) if out else None, f"controller_{i}"
            )
            clock = pacer(args.lockstep, cfg.control_dt_s)
            link_faults = None
            if cfg.faults.on_mavlink(i, True) or cfg.faults.on_mavlink(i, False):
                link_faults = MavlinkFaults(cfg.faults, i, clock, cfg.duration_s)
            key = read_key(args.signing_key_file) if args.signing_key_file else None
            link = VehicleLink(
                args.mavlink, i, stamp_arrivals=not args.lockstep, faults=link_faults, signing_key=key
            )
            session = _session(cfg, args.connect)
            mark("zenoh")
            bus = zbus = ZenohNodeBus.of(session, cfg.name, cfg.node_keys(i), cfg.law_class().message_length)
            zbus.horizon = clock.horizon_call(cfg.n_control_steps)
            if out is not None:
                zbus.published_file = CounterFile(published_path(out, i, args.incarnation))
                zbus.tick_file = CounterFile(tick_path(out, node_stem(i, args.incarnation)))
            if args.lockstep:  # up to this incarnation's planned kill: what it waited for there
                kills = [
                    k for k, _ in cfg.faults.outages(cfg.control_dt_s).get(i, []) if k > args.resume_tick
                ]
                zbus.counted_steps = range(args.resume_tick, min([*kills, cfg.n_control_steps]))
            faulty = _faulty_bus(cfg, zbus, i, clock, args.resume_tick)
            if faulty is not None and rows is not None:
                faulty.before_kill = rows.flush  # its rows up to a planned kill are kept
            counted = [x for x in (faulty, link_faults) if x is not None]
            if out is not None and counted:  # what it counts under the plan outlives a kill
                names = [n for x in counted for n in x.counts_names()]
                counts = NamedCounts(counts_path(out, i, args.incarnation), names)
                for x in counted:
                    x.keep_counts(counts)
            node_bus: NodeBus = zbus if faulty is None else faulty
            bus = node_bus
            states = _state_out(session, cfg, i) if cfg.ros2.enabled else None
            flown = session if i in cfg.ros2.controllers else None  # (by a ROS 2 node: its bridge's)
            rep = run_controller(
                cfg, i, link, node_bus, args.lockstep, rows, clock, events, args.resume_tick, states, flown
            )
            if out is not None:
                _write_stats(
                    controller_stats_path(out, i, args.incarnation),
                    {
                        "follower": i,
                        "report": rep._asdict(),
                        "published": zbus.published,
                        "in_edges": {str(s): st for s, st in in_edge_stats(zbus, faulty).items()},
                        "mavlink": link_faults.link_stats() if link_faults else {},
                        "process": process_figures(),
                    },
                )
            degraded = describe_inputs(rep._asdict())
            return (
                f"follower {i}: {rep.ticks} ticks, {rep.late_ticks} late "
                f"(max {rep.max_late_s * 1e3:.2f} ms), "
                f"{rep.resends} setpoints resent, {rep.dropped_payloads} bad inputs dropped"
                + (f"; degraded inputs: {degraded}" if degraded else "")
            )
        finally:
            for thing in (rows, events, bus, link, session):
                if thing is not None:
                    thing.close()

    return _guarded(f"controller {i}", body, args.lockstep)


def cmd_leader(cfg: SwarmConfig, args: argparse.Namespace) -> int:
    """The leader's process."""
    mark("main")
    outs = cfg.node_keys(0).out_dests

    def body() -> str:
        session = None
        bus: Any = None
        ros2_clock = None
        try:
            session = _session(cfg, args.connect)
            mark("zenoh")
            if cfg.ros2.enabled:
                ros2_clock = Ros2Clock(session, cfg.ros2)
            clock = pacer(args.lockstep, cfg.control_dt_s)
            zbus = ZenohNodeBus.of(session, cfg.name, cfg.node_keys(0))
            zbus.horizon = clock.horizon_call(cfg.n_control_steps)
            if args.out:
                zbus.published_file = CounterFile(published_path(Path(args.out), 0, args.incarnation))
                zbus.tick_file = CounterFile(tick_path(Path(args.out), node_stem(0, args.incarnation)))
            node_bus: NodeBus = _faulty_bus(cfg, zbus, 0, clock, args.resume_tick) or zbus
            bus = node_bus
            published = None if ros2_clock is None else ros2_clock.tick
            rep = run_leader(cfg, node_bus, args.lockstep, outs, clock, args.resume_tick, published)
            if args.out:
                _write_stats(
                    leader_stats_path(Path(args.out), args.incarnation),
                    {"published": zbus.published, "process": process_figures()},
                )
            return f"leader: {rep.ticks} ticks published to {outs}, {rep.late_ticks} late"
        finally:
            for thing in (bus, ros2_clock, session):
                if thing is not None:
                    thing.close()

    return _guarded("leader", body, args.lockstep)


def run_node(cmd: Callable[[SwarmConfig, argparse.Namespace], int], args: argparse.Namespace) -> int:
    """``cmd`` with the config ``args`` name (its duration overridden by ``--duration``); a config
    that does not load is one line and exit 2."""
    try:
        cfg = with_duration(load_config(args.config), args.duration)
    except (ConfigError, GraphError) as e:
        print(f"swarm-sitl: error: {e}", file=sys.stderr)
        return EXIT_USAGE
    return cmd(cfg, args)


def run_role(role: str, args: argparse.Namespace) -> int:
    """The node ``role`` (``controller`` or ``leader``) with its parsed arguments."""
    return run_node(cmd_controller if role == "controller" else cmd_leader, args)


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m swarm_sitl.nodes controller|leader CONFIG ...``."""
    p = argparse.ArgumentParser(prog="python -m swarm_sitl.nodes", description=__doc__)
    add_node_parsers(p.add_subparsers(dest="role", required=True, metavar="ROLE"), run_role)
    args = p.parse_args(argv)
    return int(args.func(args))
