"""The swarm as processes, start to end: ``run_swarm`` runs it, ``record_run`` runs it and writes
its run directory whatever happened.

``run_swarm``: vehicles (optional: ``controllers`` uses endpoints given by the user), then the
leader and one controller per follower, all-or-nothing: each must report ready (its zenoh
liveliness token, declared once its MAVLink handshake is done) within ``run.start_timeout_s`` or
the run ends before it starts. Then the start signal, the fault plan's process faults, progress
while it runs, and every process torn down at the end (``supervisor``).
"""

import contextlib
import json
import os
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from sim_vehicles.runtime.event_log import EventLog
from sim_vehicles.runtime.lifeline import settle_heap
from sim_vehicles.runtime.secret_file import write_secret
from swarm_sitl.bus import access as zenoh_access
from swarm_sitl.bus import keys as zenoh_keys
from swarm_sitl.bus.hold import LockstepHold
from swarm_sitl.bus.session import publish_hold, publish_start
from swarm_sitl.config.load import ConfigError
from swarm_sitl.config.schema import SwarmConfig
from swarm_sitl.faults.processes import LostAircraftError, ProcessFaults, process_faults
from swarm_sitl.nodes.assembly import first_tick, reported_vehicle_params
from swarm_sitl.nodes.law_host import LawError
from swarm_sitl.rundir.layout import (
    external_path,
    procs_dir,
    router_events_path,
    start_path,
    supervisor_events_path,
)
from swarm_sitl.rundir.merge import merge_run
from swarm_sitl.rundir.metrics import bound_failures
from swarm_sitl.rundir.outputs import write_outputs
from swarm_sitl.rundir.plugins import keep as keep_plugins
from swarm_sitl.rundir.whole_files import WriteError
from swarm_sitl.running import ends
from swarm_sitl.running.children import PARENT_ENV, child_env, module_argv
from swarm_sitl.running.fork_server import ForkServer, can_fork_here
from swarm_sitl.running.hub import RunMonitor, open_hub
from swarm_sitl.running.observers import Observer, supervise
from swarm_sitl.running.ros2_face import Ros2Face, write_ros2_join
from swarm_sitl.running.router_watch import RouterWatch
from swarm_sitl.running.sim import run_sim
from swarm_sitl.running.supervisor import RunFailedError, Supervisor
from swarm_sitl.running.vehicles import port_lines, signing_key_file, start_vehicles
from swarm_sitl.view.live import LiveFeed

VIEW_EVERY_S = 0.05  #: how often the page's live feed is given the bus's statuses (20 Hz) [s]
START_EVERY_S = 0.5  #: how often the start signal is put again, for late subscribers [s]
PROGRESS_EVERY_S = 0.25  #: how often ``on_progress`` is called [s]


def compile_kernels(cfg: SwarmConfig) -> None:
    """Compile (or load) the numerical kernels here, once, before the children start: on a fresh
    install every vehicle and controller would otherwise compile the same kernels at the same time
    (52 s of start-up for paper.yaml on 2 cores, instead of about 20 s)."""
    run_sim(cfg, n_steps=1)
    settle_heap()


def start_fork_server(cfg_path: Path, run_dir: Path, here: bool = False) -> ForkServer:
    """A fork server (``fork_server``) that has imported everything and loaded the kernels of
    ``cfg_path`` (compiling them on a fresh install), its errors in ``logs/fork_server.log``;
    ``here``: forked from this process where ``fork_server.can_fork_here`` (the caller vouches
    that it never opened a zenoh session), else a new interpreter."""
    log_dir = run_dir / "logs"
    log_dir.mkdir(parents=True, exist_ok=True)
    env = {**child_env(), PARENT_ENV: str(os.getpid()), "PYTHONUNBUFFERED": "1"}
    argv = [*module_argv("swarm_sitl.running.fork_server"), str(cfg_path)]
    return ForkServer(argv, env, log_dir / "fork_server.log", here=here and can_fork_here())


def uses_fork_server(cfg: SwarmConfig) -> bool:
    return cfg.run.start == "fork" and sys.platform.startswith("linux")


def node_argv(
    cfg_path: Path, role: str, lockstep: bool, hub: str | None, run_dir: Path, extra: list[str]
) -> list[str]:
    """A node's command line; ``hub`` is the supervisor's zenoh endpoint (peer mode) or None
    (client mode: the nodes reach the router the config names)."""
    argv = [*module_argv("swarm_sitl.nodes"), role, str(cfg_path), "--out", str(run_dir), *extra]
    if hub is not None:
        argv += ["--connect", hub]
    return [*argv, "--lockstep"] if lockstep else argv


def external_controllers(
    cfg: SwarmConfig,
    run_dir: Path,
    external: tuple[int, ...],
    endpoints: dict[int, str],
    hub: str | None,
    env_for: Callable[[str], dict[str, str]],
) -> list[str]:
    """Write ``RUN_DIR/external.json`` (mode 0600: it holds zenoh passwords) with what each
    external controller needs (``docs/bus.md``), and say it in lines to print."""
    connect = [hub] if hub is not None else list(cfg.zenoh.connect)
    nodes = {}
    for i in external:
        env = env_for(f"controller_{i}")
        nodes[str(i)] = {
            "mavlink": endpoints[i],
            "zenoh_user": env.get(zenoh_access.USER_ENV),
            "zenoh_password": env.get(zenoh_access.PASSWORD_ENV),
        }
    info = {
        "swarm": cfg.name,
        "control_dt_s": cfg.control_dt_s,
        "zenoh": {"mode": "client" if cfg.zenoh.mode != "peer" else "peer", "connect": connect},
        "controllers": nodes,
    }
    path = external_path(run_dir)
    write_secret(path, json.dumps(info, indent=1) + "\n")
    where = " ".join(connect) or "(scouting)"
    return [
        f"controller {i}: yours (--external): its vehicle on {nodes[str(i)]['mavlink']}, the bus at "
        f"{where}; credentials in {path}; the run starts once it declares "
        f"{zenoh_keys.alive(cfg.name, i)} (within {cfg.run.start_timeout_s:g} s)"
        for i in external
    ]


@dataclass
class RunResult:
    run_wall_s: float  #: from the start signal to the last controller done
    startup_wall_s: float  #: from spawning to every process ready
    endpoints: dict[int, str]


@dataclass(frozen=True)
class RunRequest:
    """What a run of the swarm as processes takes (``run_swarm``, ``record_run``)."""

    cfg: SwarmConfig
    run_dir: Path  #: where it writes (created)
    lockstep: bool = True  #: lockstep (equal to ``sim``), or real time
    #: each follower's vehicle endpoint (a pymavlink connection string); None: our vehicles
    mavlink: dict[int, str] | None = None
    base_port: int = 0  #: our vehicles' ports (``vehicles.PX4_BASE_PORT``'s scheme; 0: free ports)
    external: tuple[int, ...] = ()  #: followers whose controller is the user's (``run --external``)
    #: called with the slowest follower's tick and each follower's error as the run goes
    on_progress: Callable[[int, dict[int, float]], None] | None = None
    #: called with lines to show: our vehicles' ports, what an external controller must do
    on_vehicles: Callable[[list[str]], None] | None = None
    #: the page's live feed (``run --view``), given what the supervisor reads as the run goes
    view: LiveFeed | None = None
    #: the caller's process never opened a zenoh session (``swarm-sitl run``'s): the run's fork
    #: server may be forked from it (``start_fork_server``)
    fork_here: bool = False


def run_swarm(request: RunRequest) -> RunResult:
    """Run the swarm; vehicles are spawned (on ``base_port``'s ports, ``start_vehicles``; their
    ports go to ``on_vehicles``) unless ``mavlink`` gives each follower's endpoint. The followers
    in ``external`` get no controller from the run: each one's is the user's, told where to meet
    its vehicle and the bus (``external_controllers``), and the run waits for it as for its own."""
    cfg, run_dir, lockstep = request.cfg, request.run_dir, request.lockstep
    if lockstep:
        try:
            cfg.faults.check_lockstep()
        except ValueError as e:
            raise ConfigError(str(e)) from None
    run_dir.mkdir(parents=True, exist_ok=True)
    cfg_path = run_dir / "config.yaml"
    try:  # the nodes fly the plug-ins kept in the run directory (``rundir.plugins``)
        cfg_path.write_text(keep_plugins(cfg, run_dir))
    except OSError as e:
        raise RunFailedError(f"cannot write {cfg_path} ({e.strerror or e})") from None
    procs_dir(run_dir).mkdir(parents=True, exist_ok=True)
    t_spawn = time.monotonic()
    exits = ends.RunExits(run_dir, cfg.control_dt_s)
    sup = Supervisor(run_dir, rules=exits)
    try:
        if not cfg.law.is_paper:  # a user's law that cannot take its first tick fails here, named
            for f in cfg.followers:
                first_tick(cfg, f.id, *reported_vehicle_params(cfg))
        if uses_fork_server(cfg):
            # it compiles or loads the kernels
            sup.fork_server = start_fork_server(cfg_path, run_dir, request.fork_here)
        else:
            compile_kernels(cfg)
    except LawError as e:
        sup.close()
        raise RunFailedError(str(e)) from None
    try:
        hub, session = open_hub(cfg, run_dir, sup)
    except BaseException:  # (the fork server is up: it goes too, now, not when it sees us gone)
        sup.close()
        raise
    with contextlib.ExitStack() as closing:  # (what is opened below closes in reverse order)
        closing.callback(session.close)
        closing.callback(sup.close)
        monitor = RunMonitor(session, cfg)
        closing.callback(monitor.close)
        return _fly(request, sup, exits, hub, session, monitor, closing, t_spawn)
    raise AssertionError("unreachable")  # (mypy: ExitStack may swallow an exception)


def _fly(
    request: RunRequest,
    sup: Supervisor,
    exits: ends.RunExits,
    hub: str | None,
    session: Any,
    monitor: RunMonitor,
    closing: contextlib.ExitStack,
    t_spawn: float,
) -> RunResult:
    """``run_swarm`` once its supervisor and the run's bus are up: spawn, start, supervise."""
    cfg, run_dir, lockstep = request.cfg, request.run_dir, request.lockstep
    on_progress, view = request.on_progress, request.view
    cfg_path = run_dir / "config.yaml"
    hold = view.hold if view is not None and lockstep else None
    if hold is not None:  # the page's pause and step
        hold.put = lambda tick: publish_hold(session, cfg.name, tick)
    router = None
    if cfg.zenoh.mode == "client":
        router = RouterWatch(
            session, cfg.zenoh.connect, EventLog(router_events_path(run_dir), "supervisor"), lockstep
        )
        closing.callback(router.close)
    faults = None
    if cfg.faults.plan:
        events = supervisor_events_path(run_dir)
        faults = process_faults(cfg.faults, cfg.control_dt_s, cfg.run.stop_on_loss, sup, lockstep, events)
        closing.callback(faults.close)
        exits.faults = faults
    if view is not None:
        closing.callback(view.finish)
    face = None
    if cfg.ros2.enabled:  # the run on ROS 2 topics, through this session
        face = Ros2Face(session, cfg, run_dir)
        closing.callback(face.close)
        line = write_ros2_join(cfg, hub, run_dir, lockstep)
        if request.on_vehicles is not None:
            request.on_vehicles([line])
    node_args, endpoints = _spawn_vehicles(request, sup, hub)

    def argv(process: str, incarnation: int = 0, resume_tick: int = 0) -> list[str]:
        role, *extra = node_args[process]
        if incarnation:
            extra += ["--incarnation", str(incarnation), "--resume-tick", str(resume_tick)]
        return node_argv(cfg_path, role, lockstep, hub, run_dir, extra)

    if faults is not None:
        faults.set_restart(argv)
    for process in node_args:
        sup.spawn(process, argv(process), True)
    end = time.monotonic() + cfg.run.start_timeout_s
    while len(monitor.ready) < cfg.n_followers + 1:
        sup.check()
        if time.monotonic() > end:
            missing = sorted(set(range(cfg.n_followers + 1)) - monitor.ready)
            raise RunFailedError(f"node(s) {missing} not ready within {cfg.run.start_timeout_s:g} s")
        time.sleep(0.02)
    startup = time.monotonic() - t_spawn
    epoch = time.time() + (0.0 if lockstep else 0.5)
    start_path(run_dir).write_text(json.dumps({"epoch_unix_s": epoch, "lockstep": lockstep}) + "\n")
    t_start = time.monotonic()
    if view is not None:
        view.started(epoch)
    observers = []  # what the loop does, in this order, each when due
    if faults is not None:
        observers.append(Observer(_acting(faults, monitor)))
    observers.append(Observer(lambda run_s, now: sup.check()))
    if not lockstep:  # a controller that stops ticking, a run that does not end (ends)
        watch = ends.TickWatch(cfg, run_dir, time.monotonic() + (epoch - time.time()))
        observers.append(Observer(lambda run_s, now: watch.check(sup.children, now)))
        if not cfg.run.stop_on_loss:  # an unplanned exit is recorded and ridden through
            exits.lost = ends.LostLog(run_dir, epoch)
            closing.callback(exits.lost.close)
    if router is not None:
        observers.append(Observer(lambda run_s, now: router.check(run_s)))
    # again and again: a late subscriber still gets it
    observers.append(Observer(lambda run_s, now: publish_start(session, cfg.name, epoch), START_EVERY_S))
    if on_progress is not None:
        observers.append(
            Observer(lambda run_s, now: on_progress(monitor.min_step(), monitor.errors_m()), PROGRESS_EVERY_S)
        )
    if view is not None:
        observers.append(Observer(_feeding(view, hold, faults, monitor), VIEW_EVERY_S))
    if face is not None:
        face.started(epoch)
        observers.append(Observer(face.act, 1.0 / cfg.ros2.rate_hz))
    supervise(sup, observers, epoch)
    run_wall = time.monotonic() - t_start
    if on_progress is not None:
        on_progress(cfg.n_control_steps, monitor.errors_m())
    if face is not None and face.error is not None:
        print(f"swarm-sitl: {face.error} (the run flew on)", file=sys.stderr)
    if sup.lost:
        flew_on = " (the swarm flew on to the end: run.stop_on_loss false)"
        raise RunFailedError(ends.lost_line(sup.lost) + flew_on)
    return RunResult(run_wall, startup, endpoints)


def _spawn_vehicles(
    request: RunRequest, sup: Supervisor, hub: str | None
) -> tuple[dict[str, list[str]], dict[int, str]]:
    """Our vehicles spawned, the outside ones and the external controllers told where to meet:
    each node's role and arguments (by process name), and each follower's vehicle endpoint."""
    cfg, run_dir, lockstep, mavlink = request.cfg, request.run_dir, request.lockstep, request.mavlink
    on_vehicles, external = request.on_vehicles, request.external
    # a follower whose vehicle is outside the run (its ``mavlink:``) is reached where it says
    outside = {f.id: f.mavlink for f in cfg.followers if f.mavlink} if mavlink is None else dict(mavlink)
    own = [f.id for f in cfg.followers if f.id not in outside]
    key_file = signing_key_file(cfg, run_dir, own_vehicles=bool(own))
    endpoints: dict[int, str] = {}
    if own:
        endpoints, ground = start_vehicles(sup, cfg, lockstep, request.base_port, key_file, only=own)
        if on_vehicles is not None:
            on_vehicles(port_lines(endpoints, ground))
    endpoints.update(outside)
    signing = ["--signing-key-file", str(key_file)] if key_file is not None else []
    node_args = {"leader": ["leader"]}
    if external:
        lines = external_controllers(cfg, run_dir, external, endpoints, hub, sup.env_for)
        if on_vehicles is not None:
            on_vehicles(lines)
    for f in cfg.followers:
        if f.id in external:
            continue
        url = endpoints[f.id]
        url = "udpout:" + url.removeprefix("udp:") if f.id in own else url
        # (a vehicle outside signs only if the config gives its key: signing.passphrase_file)
        signs = signing if f.id in own or cfg.signing.passphrase_file is not None else []
        node_args[f"controller_{f.id}"] = ["controller", "--id", str(f.id), "--mavlink", url, *signs]
    return node_args, endpoints


def _acting(faults: ProcessFaults, monitor: RunMonitor) -> Callable[[float, float], None]:
    """The process fault plan, acting at the run's time on the slowest follower's tick."""

    def act(run_s: float, now: float) -> None:
        try:
            faults.act(run_s, monitor.min_step(faults.down | faults.lost))
        except LostAircraftError as e:
            raise RunFailedError(str(e)) from None

    return act


def _feeding(
    view: LiveFeed, hold: LockstepHold | None, faults: ProcessFaults | None, monitor: RunMonitor
) -> Callable[[float, float], None]:
    """The page's live feed, given the bus's statuses (and the page's hold, acting on them)."""

    def feed(run_s: float, now: float) -> None:
        down = faults.down | faults.lost if faults is not None else set()
        statuses = monitor.latest()
        if hold is not None:
            hold.act(statuses, down, now)
        view.update(statuses, monitor.errors_m(), down)

    return feed


@dataclass
class Outcome:
    """How a multi-process run ended, and what it recorded."""

    summary: dict[str, Any]
    failure: str | None  #: the process that failed, in one line (None: none did)
    interrupted: bool  #: Ctrl-C (or SIGTERM) ended it
    run_wall_s: float  #: from the start signal to the last controller done (nan if it did not end)
    startup_wall_s: float  #: from spawning to every process ready (nan if it did not start)
    bound_failures: list[str]  #: followers past ``run.max_formation_error_m``, one line each
    interruption: KeyboardInterrupt | None = None  #: what interrupted it (Ctrl-C, or a signal)
    #: the run directory could not be written (a full disk): the line that says so and how to
    #: rebuild it from the raw records (None: it was written)
    lost_outputs: str | None = None


def record_run(request: RunRequest) -> Outcome:
    """Run the swarm as processes (``run_swarm``) and write its run directory from
    what the processes recorded, however the run ended (a ``KeyboardInterrupt`` is caught and
    reported as ``interrupted``)."""
    cfg, run_dir = request.cfg, request.run_dir
    failure: str | None = None
    interrupted: KeyboardInterrupt | None = None
    run_wall = startup = float("nan")
    try:
        result = run_swarm(request)
        run_wall, startup = result.run_wall_s, result.startup_wall_s
    except RunFailedError as e:
        failure = str(e)
    except KeyboardInterrupt as e:  # Ctrl-C, or SIGTERM/SIGHUP as the CLI raises them
        interrupted = e
    try:
        summary = write_outputs(cfg, merge_run(cfg, run_dir), run_dir, processes=True)
    except WriteError as e:
        lost = (
            f"{e}; every process's raw records are kept in {procs_dir(run_dir)}: "
            f"`swarm-sitl merge {run_dir}` writes the run directory from them"
        )
        return Outcome({}, failure, interrupted is not None, run_wall, startup, [], interrupted, lost)
    bound = bound_failures(summary, cfg.run.max_formation_error_m) if failure is None else []
    return Outcome(summary, failure, interrupted is not None, run_wall, startup, bound, interrupted)
