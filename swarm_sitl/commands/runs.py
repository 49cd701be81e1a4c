"""The commands that fly a swarm: ``sim`` (in one process), ``run`` (as processes), ``vehicles``
(only the simulated vehicles) and ``controllers`` (our controllers on given MAVLink endpoints).

Imports are at the top but for three parts, each imported by the commands that run it: measured
after the config schema every command needs (0.6 s), matplotlib costs 0.44 s (``plot``, and
``bench``: 0.54 s with its runs), the run machinery (``running``) 0.12 s (``sim``, ``run``,
``vehicles``, ``controllers``) and a node's own modules 0.17 s (``controller``, ``leader``).
"""

import argparse
import json
import shutil
import sys
import time
from pathlib import Path
from typing import Any

from tqdm import tqdm

from swarm_sitl.commands.common import (
    EXIT_FAILED,
    CliError,
    add_base_port,
    add_run_outputs,
    check_base_port,
    degraded_lines,
    held_to_bound,
    interrupted_exit,
    load,
    run_dir_of,
    summary_lines,
)
from swarm_sitl.commands.run_options import check_external, with_ros2
from swarm_sitl.commands.run_progress import RunProgress
from swarm_sitl.commands.view import DEFAULT_PORT, port_number, serve, stream_to_foxglove
from swarm_sitl.config.load import with_duration, with_faults, with_seed, with_spec
from swarm_sitl.config.schema import SwarmConfig
from swarm_sitl.rundir.layout import expected_run_bytes, sim_spool_dir
from swarm_sitl.rundir.metrics import bound_failures
from swarm_sitl.rundir.outputs import write_spooled_outputs
from swarm_sitl.rundir.rejoins import rejoin_lines
from swarm_sitl.rundir.whole_files import WriteError
from swarm_sitl.view.foxglove_live import DEFAULT_PORT as FOXGLOVE_PORT
from swarm_sitl.view.live import LiveFeed


def _write_sim(cfg: SwarmConfig, rec: Any, run_dir: Path) -> dict:
    try:
        return write_spooled_outputs(cfg, rec, run_dir)
    except WriteError as e:  # sim's rows are spooled only until written: nothing rebuilds them
        raise CliError(
            f"{e}; sim keeps its rows only until it writes them, so run it again once it fits"
        ) from None


def cmd_sim(args: argparse.Namespace) -> int:
    cfg = with_spec(with_seed(with_duration(load(args.config), args.duration), args.seed), args.spec)
    cfg = _with_fault_file(cfg, args.faults)
    try:
        cfg.faults.check_lockstep()
    except ValueError as e:
        raise CliError(f"sim flies a plan as lockstep does: {e}") from None
    from swarm_sitl.running.first_compile import compile_once
    from swarm_sitl.running.sim import (
        SimFailedError,
        run_sim_spooled,
    )  # the run machinery: 0.12 s (module doc)

    run_dir = run_dir_of(args.out, cfg, "sim")
    spool = sim_spool_dir(run_dir)  # its rows, a block at a time, until they are written
    shutil.rmtree(spool, ignore_errors=True)
    compile_once(
        cfg, (lambda line: None) if args.quiet else lambda line: print(line, file=sys.stderr, flush=True)
    )
    n = cfg.n_control_steps
    t0 = time.monotonic()
    law_log = None
    if not cfg.law.is_paper:  # what a user's law prints (law_guard bounds it)
        (run_dir / "logs").mkdir(exist_ok=True)
        law_log = open(run_dir / "logs" / "laws.log", "w")  # noqa: SIM115  (closed below)

    def hard_stop(line: str, rec: Any) -> None:  # a law held in compiled code: the process ends
        try:
            _write_sim(cfg, rec, run_dir)
        finally:
            print(f"swarm-sitl: error: {line} (what was recorded is in {run_dir})", file=sys.__stderr__)

    try:
        if args.quiet:
            rec = run_sim_spooled(cfg, spool, law_output=law_log, on_hard_stop=hard_stop)
        else:
            with tqdm(total=n + 1, unit="tick", desc=f"sim {cfg.name}", mininterval=0.25, leave=False) as bar:
                stride = max(1, (n + 1) // 100)

                def progress(k: int) -> None:
                    if k % stride == 0 or k == n:
                        bar.update(k + 1 - bar.n)

                rec = run_sim_spooled(
                    cfg, spool, progress=progress, law_output=law_log, on_hard_stop=hard_stop
                )
    except SimFailedError as e:
        try:
            _write_sim(cfg, e.recording, run_dir)
        finally:
            shutil.rmtree(spool, ignore_errors=True)
        print(f"swarm-sitl: error: {e} (what was recorded is in {run_dir})", file=sys.stderr)
        return EXIT_FAILED
    except BaseException:  # (Ctrl-C: nothing is written, and its spool goes too)
        shutil.rmtree(spool, ignore_errors=True)
        raise
    finally:
        if law_log is not None:
            law_log.close()
    wall = time.monotonic() - t0
    try:
        summary = _write_sim(cfg, rec, run_dir)
    finally:
        shutil.rmtree(spool, ignore_errors=True)
    print(
        f"sim {cfg.name}: {cfg.duration_s:g} s simulated in {wall:.2f} s wall "
        f"({cfg.duration_s / wall:.1f}x real time) -> {run_dir}"
    )
    print("\n".join(summary_lines(summary)))
    return held_to_bound(bound_failures(summary, cfg.run.max_formation_error_m))


def warn_if_short_of_disk(cfg: SwarmConfig, run_dir: Path) -> None:
    """One line on stderr when the run's expected size does not fit on ``run_dir``'s disk."""
    need = expected_run_bytes(cfg.n_control_steps + 1, cfg.n_followers, cfg.law_class().record_fields)
    on = run_dir.resolve()
    while not on.exists():  # the disk it will be on
        on = on.parent
    free = shutil.disk_usage(on).free
    if free < need:
        print(
            f"swarm-sitl: warning: this run writes about {need / 1e6:.0f} MB to {run_dir}, "
            f"whose disk has {free / 1e6:.0f} MB free",
            file=sys.stderr,
        )


def _run_and_record(
    cfg: SwarmConfig,
    run_dir: Path,
    lockstep: bool,
    quiet: bool,
    mavlink: dict[int, str] | None,
    kind: str,
    base_port: int = 0,
    external: tuple[int, ...] = (),
    view: tuple[str, int] | None = None,
    foxglove: tuple[str, int] | None = None,
) -> int:
    """``view``: the address and port of the run's live page (``run --view``), or None;
    ``foxglove``: those of its Foxglove WebSocket server (``run --foxglove``), or None."""
    from swarm_sitl.running.first_compile import compile_once
    from swarm_sitl.running.run import RunRequest, record_run  # the run machinery: 0.12 s (module doc)

    warn_if_short_of_disk(cfg, run_dir)
    compile_once(cfg, (lambda line: None) if quiet else lambda line: print(line, file=sys.stderr, flush=True))
    clock = "lockstep" if lockstep else "real time"
    feed = server = stream = None
    if view is not None or foxglove is not None:
        feed = LiveFeed(cfg, run_dir, lockstep)
    if foxglove is not None and feed is not None:
        stream = stream_to_foxglove(cfg, *foxglove)
        feed.sinks.append(stream)
    if view is not None and feed is not None:
        try:
            server = serve(feed, *view, "live view")
        except CliError:
            if stream is not None:
                stream.close()
            raise
    progress = RunProgress(cfg, f"{kind} {cfg.name} ({clock})", quiet)
    try:
        out = record_run(
            RunRequest(
                cfg,
                run_dir,
                lockstep,
                mavlink,
                base_port,
                external,
                progress,
                progress.note,
                feed,
                fork_here=True,  # (this process opens its first zenoh session in the run)
            )
        )
    finally:
        progress.close()
        if stream is not None and feed is not None:
            stream.close()
            failed = "; ".join(feed.sink_errors)
            print(
                f"foxglove: {stream.logged} messages logged" + (f"; it stopped: {failed}" if failed else ""),
                file=sys.stderr,
            )
        if server is not None:
            server.close()
            refused = f" ({server.refused} refused: another Host or page)" if server.refused else ""
            print(
                f"live view: {server.requests} requests answered{refused}; the run is over, to watch it "
                f"again: swarm-sitl view {run_dir}",
                file=sys.stderr,
            )
    if out.lost_outputs is not None:
        print(f"swarm-sitl: error: {out.lost_outputs}", file=sys.stderr)
        return EXIT_FAILED
    if out.failure is not None:
        print(
            f"swarm-sitl: error: {out.failure} (partial run in {run_dir}, logs in {run_dir / 'logs'})",
            file=sys.stderr,
        )
        return EXIT_FAILED
    if out.interrupted:
        code, name = interrupted_exit(out.interruption)
        print(f"swarm-sitl: interrupted ({name}); partial run in {run_dir}", file=sys.stderr)
        return code
    print(
        f"{kind} {cfg.name} ({clock}): {cfg.duration_s:g} s simulated in {out.run_wall_s:.2f} s wall "
        f"({cfg.duration_s / out.run_wall_s:.1f}x real time; start-up {out.startup_wall_s:.1f} s) "
        f"-> {run_dir}"
    )
    print("\n".join(summary_lines(out.summary)))
    for line in degraded_lines(out.summary):
        print(line)
    restarts, not_back = rejoin_lines(out.summary)
    for line in restarts:
        print(line)
    if not cfg.run.max_formation_error_m:  # with a bound they are its failures (stderr, exit 3)
        for line in not_back:
            print(f"  {line}")
    return held_to_bound(out.bound_failures)


def _with_fault_file(cfg: SwarmConfig, path: str | None) -> SwarmConfig:

    return cfg if path is None else with_faults(cfg, path)


def cmd_run(args: argparse.Namespace) -> int:
    cfg = _with_fault_file(
        with_spec(with_seed(with_duration(load(args.config), args.duration), args.seed), args.spec),
        args.faults,
    )
    check_base_port(cfg, args.base_port)
    cfg = with_ros2(cfg, args.ros2, args.ros2_controller)
    external = check_external(cfg, args.external, args.realtime)
    run_dir = run_dir_of(args.out, cfg, "run")
    view = None if args.view is None else (args.view_host, args.view)
    foxglove = None if args.foxglove is None else (args.view_host, args.foxglove)
    return _run_and_record(
        cfg, run_dir, not args.realtime, args.quiet, None, "run", args.base_port, external, view, foxglove
    )


def cmd_controllers(args: argparse.Namespace) -> int:
    cfg = _with_fault_file(
        with_spec(with_seed(with_duration(load(args.config), args.duration), args.seed), args.spec),
        args.faults,
    )
    if len(args.mavlink) != cfg.n_followers:
        raise CliError(
            f"--mavlink needs one connection string per follower ({cfg.n_followers}, in id order), "
            f"got {len(args.mavlink)}"
        )
    run_dir = run_dir_of(args.out, cfg, "controllers")
    mavlink = {
        f.id: url for f, url in zip(sorted(cfg.followers, key=lambda f: f.id), args.mavlink, strict=True)
    }
    return _run_and_record(cfg, run_dir, args.lockstep, args.quiet, mavlink, "controllers")


def cmd_vehicles(args: argparse.Namespace) -> int:
    from swarm_sitl.running.run import compile_kernels  # the run machinery: 0.12 s (module doc)
    from swarm_sitl.running.supervisor import RunFailedError, Supervisor
    from swarm_sitl.running.vehicle_relay import start_relays
    from swarm_sitl.running.vehicles import port_lines, signing_key_file, start_vehicles

    cfg = load(args.config)
    check_base_port(cfg, args.base_port)
    relayed = _vehicle_faults(cfg, args.faults, args.lockstep) if args.faults else frozenset()
    if args.faults:
        cfg = _with_fault_file(cfg, args.faults)
    run_dir = run_dir_of(args.out, cfg, "vehicles")
    compile_kernels(cfg)
    sup = Supervisor(run_dir)
    relays = None
    try:
        key_file = signing_key_file(cfg, run_dir, own_vehicles=False)
        own = [f.id for f in cfg.followers if not f.mavlink]  # (a follower's ``mavlink:``: outside)
        endpoints, ground = start_vehicles(
            sup, cfg, args.lockstep, args.base_port, key_file, args.host, relayed, own
        )
        if relayed:
            relays = start_relays(cfg, endpoints, args.base_port, args.host, relayed)
            endpoints = {
                **endpoints,
                **{r.vehicle: f"udp:{r.address[0]}:{r.address[1]}" for r in relays.relays},
            }
        clock = f"lockstep, {cfg.control_dt_s:g} s per setpoint" if args.lockstep else "real time"
        print(f"{len(own)} vehicles of {cfg.name} ({clock}); .tlogs in {run_dir / 'tlogs'}")
        print(f"  MAVLink 2 signing with {key_file}" if key_file else "  MAVLink 2 signing off")
        print("\n".join(port_lines(endpoints, ground)))
        if relayed:
            print(f"  {args.faults} acts on the link(s) of vehicle(s) {sorted(relayed)} from now")
        print("Ctrl-C stops them", flush=True)
        while True:
            sup.check()
            time.sleep(0.1)
    except RunFailedError as e:
        raise CliError(str(e)) from None
    except KeyboardInterrupt:
        print("swarm-sitl: vehicles stopped", file=sys.stderr)
        return 0
    finally:
        sup.close()
        if relays is not None:
            links = relays.close()
            (run_dir / "links.json").write_text(json.dumps(links, indent=1) + "\n")
            for name, st in links.items():
                print(
                    f"  {name}: {st['received']} datagrams, {st['lost']} lost, {st['corrupt']} corrupted, "
                    f"{st['delayed']} delayed, {st['duplicated']} duplicated (links.json)"
                )


def _vehicle_faults(cfg: SwarmConfig, path: str, lockstep: bool) -> frozenset[int]:
    """The vehicles whose links ``vehicles --faults`` relays; a plan with anything else is refused."""
    plan = _with_fault_file(cfg, path).faults
    if lockstep:
        raise CliError(
            "vehicles --faults runs in real time only (in lockstep a lost setpoint needs a clock-only "
            "one in its place, which the controller sends: use run --faults)"
        )
    for j, f in enumerate(plan.plan):
        if f.mavlink is None:
            raise CliError(f"{path}: entry {j}: vehicles --faults acts on MAVLink links only (mavlink: i)")
    return frozenset(f.mavlink for f in plan.plan if f.mavlink is not None)


def add_sim(sub: Any) -> None:
    """``swarm-sitl sim``: the whole swarm in one process."""
    s = sub.add_parser("sim", help="run the whole swarm in one process and write a run directory")
    s.add_argument("config")
    s.add_argument(
        "--faults",
        metavar="FILE",
        help="fault plan (YAML: seed, plan) in place of the config's, flown as lockstep flies it",
    )
    add_run_outputs(s, "sim")
    s.set_defaults(func=cmd_sim)


def add_run(sub: Any) -> None:
    """``swarm-sitl run``: the swarm as processes."""
    r = sub.add_parser("run", help="run the swarm as processes: vehicles, controllers, leader, zenoh")
    r.add_argument("config")
    r.add_argument("--realtime", action="store_true", help="wall clock, as in flight (default: lockstep)")
    r.add_argument("--faults", metavar="FILE", help="fault plan (YAML: seed, plan) in place of the config's")
    r.add_argument(
        "--external",
        type=int,
        action="append",
        default=[],
        metavar="ID",
        help="follower whose controller you run yourself (another language, another tool): the run "
        "spawns its vehicle, writes RUN_DIR/external.json and waits for it (docs/bus.md); --realtime",
    )
    r.add_argument(
        "--view",
        type=port_number,
        nargs="?",
        const=DEFAULT_PORT,
        metavar="PORT",
        help=f"watch it in the browser: a page on 127.0.0.1:PORT (default {DEFAULT_PORT}; 0: a free one)",
    )
    r.add_argument(
        "--foxglove",
        type=port_number,
        nargs="?",
        const=FOXGLOVE_PORT,
        metavar="PORT",
        help="stream it to Foxglove: its WebSocket protocol on 127.0.0.1:PORT (default "
        f"{FOXGLOVE_PORT}; 0: a free one), the page's frames on the MCAP export's topics",
    )
    r.add_argument(
        "--ros2",
        action="store_true",
        help="republish the run on ROS 2 topics through its router, in rmw_zenoh's layout, for ROS 2 "
        "nodes to read (its ros2: section says the domain, namespace, distro and rate; docs/ros2.md)",
    )
    r.add_argument(
        "--ros2-controller",
        type=int,
        action="append",
        default=[],
        metavar="I",
        help="follower I is flown by a ROS 2 node, not by the law (implies --ros2): it reads its vehicle "
        "and in-neighbours and writes its setpoint and message as ROS 2 topics; in lockstep it answers "
        "each tick (docs/ros2.md)",
    )
    r.add_argument(
        "--view-host",
        default="127.0.0.1",
        help="the page's and the Foxglove stream's address (default: loopback only)",
    )
    add_base_port(r)
    add_run_outputs(r, "run")
    r.set_defaults(func=cmd_run)


def add_vehicles(sub: Any) -> None:
    """``swarm-sitl vehicles``: the simulated vehicles alone."""
    v = sub.add_parser("vehicles", help="start only the simulated vehicles and print their MAVLink endpoints")
    v.add_argument("config")
    v.add_argument("--lockstep", action="store_true", help="step one control period per stamped setpoint")
    add_base_port(v)
    v.add_argument(
        "--host",
        default="127.0.0.1",
        help="address the vehicles bind (default 127.0.0.1; another host's controllers need this "
        "machine's address on their network)",
    )
    v.add_argument("--out", help="directory for .tlogs and logs (default runs/<name>-vehicles-<time>)")
    v.add_argument(
        "--faults",
        metavar="FILE",
        help="a fault plan of mavlink: entries, applied at the vehicles' own ports (real time; "
        "counts in OUT/links.json at exit)",
    )
    v.set_defaults(func=cmd_vehicles)


def add_controllers(sub: Any) -> None:
    """``swarm-sitl controllers``: our controllers on given MAVLink endpoints."""
    cs = sub.add_parser("controllers", help="run the leader and controllers against given MAVLink endpoints")
    cs.add_argument("config")
    cs.add_argument(
        "--mavlink",
        nargs="+",
        required=True,
        metavar="URL",
        help="one pymavlink connection string per follower",
    )
    cs.add_argument(
        "--lockstep", action="store_true", help="the vehicles step in lockstep (default: real time)"
    )
    cs.add_argument("--faults", metavar="FILE", help="fault plan (YAML: seed, plan) in place of the config's")
    add_run_outputs(cs, "controllers")
    cs.set_defaults(func=cmd_controllers)
