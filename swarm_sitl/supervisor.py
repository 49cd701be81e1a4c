"""Spawn, supervise and tear down the processes of a swarm; the one place that owns child processes.

``Supervisor`` starts each child in its own session with its output in ``RUN_DIR/logs/<name>.log``
and ``SWARM_SITL_PARENT_PID`` set (children die with it, ``sim_vehicles.lifeline``). Whatever
happens (completion, Ctrl-C, a child failing, an exception here), ``close()`` sends SIGTERM to every
child still running, waits, then SIGKILLs: no orphan process, no port left bound.

``run_swarm`` is the whole run: vehicles (optional: ``controllers`` uses endpoints given by the
user), then the leader and one controller per follower, all-or-nothing: each must report ready
(its zenoh liveliness token, declared once its MAVLink handshake is done) within
``run.start_timeout_s`` or the run ends before it starts. Then the start signal, progress while it
runs, and the merge of what each process recorded.
"""

import contextlib
import json
import math
import os
import re
import secrets
import signal
import site
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any

import numpy as np

from sim_vehicles.mavlink.signing import SigningKeyError, read_key
from sim_vehicles.runtime.lifeline import ENV as PARENT_ENV
from sim_vehicles.runtime.lifeline import settle_heap
from sim_vehicles.runtime.secret_file import write_secret
from swarm_sitl.bus import keys as zenoh_keys
from swarm_sitl.bus.codec import Status, decode_status, decode_waiting
from swarm_sitl.config.load import ConfigError
from swarm_sitl.config.schema import SwarmConfig
from swarm_sitl.fork_server import ENTRY_MODULES, ForkedProcess, ForkServer, ForkServerError, module_argv
from swarm_sitl.rundir.layout import (
    procs_dir,
    signing_key_path,
    start_path,
    supervisor_events_path,
    vehicle_events_path,
    vehicle_stats_path,
    vehicle_truth_path,
    zenoh_users_path,
)

TERM_GRACE_S = 5.0
SUPERVISE_EVERY_S = 0.05  #: how often a run looks at its children (each look polls every one of them)
_LISTENING = re.compile(r"listening on udp:([0-9.]+):(\d+)")
_GROUND_STATION = re.compile(r"ground station on udp:([0-9.]+):(\d+)")
#: ``--base-port B``: vehicle i listens for its controller on B + i and for a ground station on
#: B + GCS_PORT_OFFSET + i, and its ground-station port sends to GCS_REMOTE until one speaks to it:
#: with B = 14580, PX4 SITL's scheme (offboard 14580 + i, ground station 18570 + i -> 14550)
PX4_BASE_PORT = 14580
GCS_PORT_OFFSET = 3990
GCS_REMOTE = "127.0.0.1:14550"


class RunFailedError(RuntimeError):
    """A process of the run failed; the message names it."""


STOPPED_GRACE_S = 0.5  #: a child stopped (SIGSTOP) this long, unplanned, fails the run [s]


@dataclass
class Child:
    name: str
    proc: "subprocess.Popen[bytes] | ForkedProcess"
    log_path: Path
    must_finish: bool  #: leader/controllers end by themselves; vehicles run until torn down
    process: str = ""  #: the process it is an incarnation of (``controller_2`` for ``controller_2.1``)
    retired: bool = False  #: gone as the fault plan said (killed, or replaced by a restart)
    stopped_since: float = math.inf  #: when it was first seen stopped [monotonic s]

    @property
    def pid(self) -> int:
        return self.proc.pid

    def stopped(self) -> bool:
        """Whether the process is stopped (SIGSTOP, or a debugger), from ``/proc`` (Linux)."""
        try:
            stat = Path(f"/proc/{self.proc.pid}/stat").read_text()
        except OSError:
            return False
        return stat.rsplit(")", 1)[-1].split()[0] in ("T", "t")

    def last_line(self) -> str:
        try:
            lines = [ln for ln in self.log_path.read_text(errors="replace").splitlines() if ln.strip()]
        except OSError:
            return ""
        return lines[-1].strip() if lines else ""


@dataclass
class Supervisor:
    run_dir: Path
    children: list[Child] = field(default_factory=list)
    _logs: list[IO[bytes]] = field(default_factory=list)
    #: whether a child's exit (with its code) is one a fault plan made (``process_faults``)
    planned_exit: Callable[[Child, int], bool] = lambda child, code: False
    #: whether a stopped child was stopped by the plan
    planned_stop: Callable[[str], bool] = lambda process: False
    #: environment a process's children get besides ``child_env()`` (its zenoh credentials)
    env_for: Callable[[str], dict[str, str]] = lambda process: {}
    #: when set, children that run ``python -P -m sim_vehicles|swarm_sitl`` are forked from it
    fork_server: ForkServer | None = None

    def child(self, process: str) -> Child | None:
        """The live incarnation of ``process``, if any."""
        live = [c for c in self.children if c.process == process and not c.retired]
        return live[-1] if live else None

    def spawn(self, name: str, argv: list[str], must_finish: bool, process: str | None = None) -> Child:
        log_dir = self.run_dir / "logs"
        log_dir.mkdir(parents=True, exist_ok=True)
        log_path = log_dir / f"{name}.log"
        env = {
            **child_env(),
            PARENT_ENV: str(os.getpid()),
            "PYTHONUNBUFFERED": "1",
            **self.env_for(process or name),
        }
        proc: subprocess.Popen[bytes] | ForkedProcess
        prefix = module_argv("")[:-1]
        if (
            self.fork_server is not None
            and argv[: len(prefix)] == prefix
            and argv[len(prefix)] in ENTRY_MODULES
        ):
            try:
                proc = self.fork_server.spawn(argv[len(prefix)], argv[len(prefix) + 1 :], env, log_path)
            except ForkServerError as e:
                raise RunFailedError(f"{name}: {e}") from None
        else:
            log = open(log_path, "wb")  # noqa: SIM115  (closed in close())
            self._logs.append(log)
            proc = subprocess.Popen(
                argv,
                stdout=log,
                stderr=subprocess.STDOUT,
                stdin=subprocess.DEVNULL,
                env=env,
                start_new_session=True,
            )
        child = Child(name, proc, log_path, must_finish, process or name)
        self.children.append(child)
        return child

    def check(self) -> None:
        """Raise ``RunFailedError`` if a child failed, or a vehicle stopped while it was needed,
        or a child is stopped (SIGSTOP) that the plan did not stop: named first, since the others
        are only waiting on it."""
        now = time.monotonic()
        for c in self.children:
            if c.retired or c.proc.poll() is not None:
                continue
            if not c.stopped() or self.planned_stop(c.process):
                c.stopped_since = math.inf
                continue
            c.stopped_since = min(c.stopped_since, now)
            if now - c.stopped_since > STOPPED_GRACE_S:
                raise RunFailedError(
                    f"{c.name} is stopped (SIGSTOP or a debugger) and no fault plan stopped it; "
                    "the others wait on it"
                )
        for c in self.children:
            if c.retired:
                continue
            code = c.proc.poll()
            if code is None:
                continue
            if code != 0 or not c.must_finish:
                if self.planned_exit(c, code):
                    continue
                why = getattr(c.proc, "error", "") or c.last_line()
                raise RunFailedError(f"{c.name} exited with code {code}" + (f": {why}" if why else ""))

    def finished(self) -> bool:
        return all(c.proc.poll() == 0 for c in self.children if c.must_finish and not c.retired)

    def close(self) -> None:
        alive = [c for c in self.children if c.proc.poll() is None]
        for c in alive:
            with contextlib.suppress(ProcessLookupError):
                c.proc.send_signal(signal.SIGCONT)  # a stopped process takes SIGTERM only once it runs
                c.proc.send_signal(signal.SIGTERM)
        end = time.monotonic() + TERM_GRACE_S
        for c in alive:
            try:
                c.proc.wait(timeout=max(0.0, end - time.monotonic()))
            except subprocess.TimeoutExpired:
                with contextlib.suppress(ProcessLookupError):
                    os.killpg(c.proc.pid, signal.SIGKILL)
                c.proc.wait()
        for log in self._logs:
            log.close()
        self._logs.clear()
        if self.fork_server is not None:
            self.fork_server.close()
            self.fork_server = None


def compile_kernels(cfg: SwarmConfig) -> None:
    """Compile (or load) the numerical kernels here, once, before the children start: on a fresh
    install every vehicle and controller would otherwise compile the same kernels at the same time
    (52 s of start-up for paper.yaml on 2 cores, instead of about 20 s)."""
    from swarm_sitl.sim import run_sim

    run_sim(cfg, n_steps=1)
    settle_heap()


def start_fork_server(cfg_path: Path, run_dir: Path) -> ForkServer:
    """A fork server (``fork_server``) that has imported everything and loaded the kernels of
    ``cfg_path`` (compiling them on a fresh install), its errors in ``logs/fork_server.log``."""
    log_dir = run_dir / "logs"
    log_dir.mkdir(parents=True, exist_ok=True)
    env = {**child_env(), PARENT_ENV: str(os.getpid()), "PYTHONUNBUFFERED": "1"}
    argv = [*module_argv("swarm_sitl.fork_server"), str(cfg_path)]
    return ForkServer(argv, env, log_dir / "fork_server.log")


def uses_fork_server(cfg: SwarmConfig) -> bool:
    return cfg.run.start == "fork" and sys.platform.startswith("linux")


def free_tcp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def child_env(base: Mapping[str, str] | None = None) -> dict[str, str]:
    """``base`` (default ``os.environ``) with the directory this package was imported from first on
    ``PYTHONPATH``, unless it is a site directory that every child searches anyway (putting one
    before the standard library would reorder more than our packages). So a child started with
    ``module_argv`` finds the same ``sim_vehicles`` and ``swarm_sitl`` as this process, installed
    or run from a checkout without installing."""
    env = dict(os.environ if base is None else base)
    root = Path(__file__).resolve().parents[1]
    sites = [*site.getsitepackages(), site.getusersitepackages()]
    if any(Path(d).resolve() == root for d in sites if d):
        return env
    env["PYTHONPATH"] = os.pathsep.join([str(root), *([env["PYTHONPATH"]] if env.get("PYTHONPATH") else [])])
    return env


def signing_key_file(cfg: SwarmConfig, run_dir: Path, own_vehicles: bool) -> Path | None:
    """The passphrase file every vehicle link of this run is signed with (``SigningSpec``), or
    None: the one the config gives, else for vehicles this run spawns a fresh random one written
    to ``RUN_DIR/mavlink_signing.key``, readable by this user only."""
    if not cfg.signing.enabled:
        return None
    if cfg.signing.passphrase_file is not None:
        try:  # refused now, in one line, rather than in every child
            read_key(cfg.signing.passphrase_file)
        except SigningKeyError as e:
            raise RunFailedError(f"signing.passphrase_file: {e}") from None
        return Path(cfg.signing.passphrase_file)
    if not own_vehicles:
        return None
    path = signing_key_path(run_dir)
    write_secret(path, secrets.token_hex(32) + "\n")
    return path


def vehicle_argv(
    cfg: SwarmConfig,
    i: int,
    run_dir: Path,
    lockstep: bool,
    port: int = 0,
    key_file: Path | None = None,
    gcs_port: int = 0,
    gcs_remote: str | None = None,
    host: str = "127.0.0.1",
) -> list[str]:
    f, v, g = cfg.follower(i), cfg.vehicle, cfg.gains
    argv = [
        *module_argv("sim_vehicles"),
        "--id",
        str(i),
        "--host",
        host,
        "--port",
        str(port),
        "--position",
        *map(repr, f.initial_position_m),
        "--velocity",
        *map(repr, f.initial_velocity_mps),
        "--quaternion",
        *map(repr, f.initial_quaternion_wxyz),
        "--mass-kg",
        repr(v.mass_kg),
        "--inertia-kgm2",
        *map(repr, v.inertia_kgm2),
        "--max-thrust-n",
        repr(v.max_thrust_N),
        "--max-rate-rps",
        *map(repr, v.max_rate_rps),
        "--gravity-mps2",
        repr(cfg.gravity_mps2),
        "--l-q",
        repr(g.l_q),
        "--k-q",
        repr(g.k_q),
        "--setpoint-timeout-s",
        repr(v.setpoint_timeout_s),
        "--failsafe-action",
        v.failsafe_action,
        "--events",
        str(vehicle_events_path(run_dir, i)),
        "--stats",
        str(vehicle_stats_path(run_dir, i)),
        *(["--signing-key-file", str(key_file)] if key_file is not None else []),
        "--gcs-port",
        str(gcs_port),
        *(["--gcs-remote", gcs_remote] if gcs_remote else []),
        "--attitude-hz",
        repr(cfg.rates.attitude_hz),
        "--tlog",
        str(run_dir / "tlogs" / f"vehicle_{i}.tlog"),
        "--truth",
        str(vehicle_truth_path(run_dir, i)),
    ]
    if lockstep:
        argv += ["--lockstep-period-s", repr(cfg.control_dt_s)]
    return argv


def start_vehicles(
    sup: Supervisor,
    cfg: SwarmConfig,
    lockstep: bool,
    base_port: int = 0,
    key_file: Path | None = None,
    host: str = "127.0.0.1",
) -> tuple[dict[int, str], dict[int, str]]:
    """Spawn one vehicle per follower bound to ``host``, signing with ``key_file``'s key if given,
    on the ports of ``base_port`` (``PX4_BASE_PORT``; 0: free ports); returns ``{id:
    "udp:host:port"}`` of their controller ports and of their ground-station ports once each is
    listening."""
    run_dir = sup.run_dir
    (run_dir / "tlogs").mkdir(parents=True, exist_ok=True)
    procs_dir(run_dir).mkdir(parents=True, exist_ok=True)
    children = {}
    for f in cfg.followers:
        port, gcs_port = (base_port + f.id, base_port + GCS_PORT_OFFSET + f.id) if base_port else (0, 0)
        argv = vehicle_argv(
            cfg, f.id, run_dir, lockstep, port, key_file, gcs_port, GCS_REMOTE if base_port else None, host
        )
        children[f.id] = sup.spawn(f"vehicle_{f.id}", argv, False)
    endpoints: dict[int, str] = {}
    ground: dict[int, str] = {}
    end = time.monotonic() + cfg.run.start_timeout_s
    while len(endpoints) < len(children):
        sup.check()
        for i, c in children.items():
            if i not in endpoints:
                with contextlib.suppress(OSError):
                    log = c.log_path.read_text(errors="replace")
                    m, g = _LISTENING.search(log), _GROUND_STATION.search(log)
                    if m and g:
                        endpoints[i] = f"udp:{m.group(1)}:{m.group(2)}"
                        ground[i] = f"udp:{g.group(1)}:{g.group(2)}"
        if time.monotonic() > end:
            late = sorted(set(children) - set(endpoints))
            raise RunFailedError(
                f"vehicle(s) {late} did not start listening within {cfg.run.start_timeout_s:g} s"
            )
        time.sleep(0.02)
    return endpoints, ground


def port_lines(endpoints: Mapping[int, str], ground: Mapping[int, str]) -> list[str]:
    """One line per vehicle: where its controller and a ground station reach it."""
    return [
        f"  vehicle {i}: controller udpout:{endpoints[i].removeprefix('udp:')}, ground station "
        f"udpout:{ground[i].removeprefix('udp:')}  (MAVLink system id {i})"
        for i in sorted(endpoints)
    ]


def node_argv(
    cfg_path: Path, role: str, lockstep: bool, hub: str | None, run_dir: Path, extra: list[str]
) -> list[str]:
    """A node's command line; ``hub`` is the supervisor's zenoh endpoint (peer mode) or None
    (client mode: the nodes reach the router the config names)."""
    argv = [*module_argv("swarm_sitl.nodes"), role, str(cfg_path), "--out", str(run_dir), *extra]
    if hub is not None:
        argv += ["--connect", hub]
    return [*argv, "--lockstep"] if lockstep else argv


#: status samples kept per follower between two looks of the supervisor (only the latest is used)
STATUS_RING = 8


class RunMonitor:
    """The supervisor's own view of the bus: readiness of every node and followers' status.

    Status samples wait in a ring per follower (zenoh's, on the Rust side) until the supervisor
    looks, a few times a second: in lockstep they come hundreds of times a second, and a Python
    callback for each would wake the supervisor and take the GIL that often for nothing."""

    def __init__(self, session: Any, cfg: SwarmConfig):
        import zenoh

        self.cfg = cfg
        self._trajectory = cfg.trajectory()
        self._offsets = {f.id: np.asarray(f.offset_m, dtype=float) for f in cfg.followers}
        self._lock = threading.Lock()
        self.ready: set[int] = set()
        self.status: dict[int, Status] = {}
        self.dropped = 0
        self._subs = [
            session.liveliness().declare_subscriber(
                zenoh_keys.alive(cfg.name, node), self._on_alive(node), history=True
            )
            for node in range(cfg.n_followers + 1)
        ]
        self._status_subs = [
            session.declare_subscriber(
                zenoh_keys.status(cfg.name, f.id), zenoh.handlers.RingChannel(STATUS_RING)
            )
            for f in cfg.followers
        ]

    def _on_alive(self, node: int) -> Callable[[Any], None]:
        def cb(sample: Any) -> None:
            import zenoh

            with self._lock:
                if sample.kind == zenoh.SampleKind.PUT:
                    self.ready.add(node)

        return cb

    def _read_status(self) -> None:
        for f, sub in zip(self.cfg.followers, self._status_subs, strict=True):
            statuses, bad = decode_waiting(sub, decode_status)
            self.dropped += bad
            for s in statuses:
                if s.follower == f.id:  # else not its sender's (a peer-mode bus has no access control)
                    self.status[s.follower] = s
                else:
                    self.dropped += 1

    def errors_m(self) -> dict[int, float]:
        """Each follower's |p - p_r - delta| at its latest status."""
        self._read_status()
        out = {}
        for i, s in self.status.items():
            p_r = self._trajectory.derivatives(s.sample_t_s)[0]
            out[i] = float(np.linalg.norm(s.p_W - p_r - self._offsets[i]))
        return out

    def min_step(self, leave_out: set[int] | None = None) -> int:
        """The slowest follower's tick (-1 until every one has reported), ``leave_out``: those
        that are down (a fault plan's)."""
        self._read_status()
        ids = [f.id for f in self.cfg.followers if not leave_out or f.id not in leave_out]
        if any(i not in self.status for i in ids):
            return -1
        return min((self.status[i].step for i in ids), default=-1)

    def close(self) -> None:
        for s in [*self._subs, *self._status_subs]:
            s.undeclare()


def open_hub(cfg: SwarmConfig, run_dir: Path, sup: Supervisor) -> tuple[str | None, Any]:
    """The supervisor's zenoh session and the endpoint the nodes connect to (``ZenohSpec``): in
    ``router`` mode a router on ``zenoh.listen`` (by default a free loopback port) that
    authenticates each node with a fresh password (given to the node's processes in their
    environment) and holds it to its keys; in ``peer`` mode a peer on a free loopback port where
    the peers meet; in ``client`` mode a client of the configured router, and no endpoint of ours."""
    import zenoh

    from swarm_sitl.bus.session import error_line

    try:
        return _open_hub(cfg, run_dir, sup)
    except zenoh.ZError as e:
        raise RunFailedError(f"zenoh ({cfg.zenoh.mode} mode): {error_line(e)}") from None


def _open_hub(cfg: SwarmConfig, run_dir: Path, sup: Supervisor) -> tuple[str | None, Any]:
    from swarm_sitl.bus import access as zenoh_access
    from swarm_sitl.bus.session import open_router, open_session, router_runtime

    if cfg.zenoh.mode == "client":
        return None, open_session(cfg.zenoh, credentials=zenoh_access.credentials_from_env())
    if cfg.zenoh.mode == "peer":
        hub = f"tcp/127.0.0.1:{free_tcp_port()}"
        return hub, open_session(cfg.zenoh.model_copy(update={"listen": [hub]}))
    listen = [_with_free_port(e) for e in cfg.zenoh.listen]
    passwords = zenoh_access.write_credentials(cfg.n_followers, zenoh_users_path(run_dir))
    sup.env_for = lambda process: zenoh_access.credentials_env(process, passwords)
    nodes = [cfg.node_keys(n) for n in range(cfg.n_followers + 1)]
    with router_runtime():
        router = open_router(
            listen, str(zenoh_users_path(run_dir)), zenoh_access.access_control(cfg.name, nodes)
        )
    return listen[0].replace("/0.0.0.0:", "/127.0.0.1:"), router


def _with_free_port(endpoint: str) -> str:
    """``tcp/127.0.0.1:0`` with a free port in place of 0 (the nodes must be told the port)."""
    if endpoint.startswith("tcp/127.0.0.1:") and endpoint.endswith(":0"):
        return f"tcp/127.0.0.1:{free_tcp_port()}"
    return endpoint


@dataclass
class RunResult:
    run_wall_s: float  #: from the start signal to the last controller done
    startup_wall_s: float  #: from spawning to every process ready
    endpoints: dict[int, str]


def run_swarm(
    cfg: SwarmConfig,
    run_dir: Path,
    lockstep: bool,
    mavlink: dict[int, str] | None = None,
    on_progress: Callable[[int, dict[int, float]], None] | None = None,
    base_port: int = 0,
    on_vehicles: Callable[[list[str]], None] | None = None,
) -> RunResult:
    """Run the swarm; vehicles are spawned (on ``base_port``'s ports, ``start_vehicles``; their
    ports go to ``on_vehicles``) unless ``mavlink`` gives each follower's endpoint."""
    from swarm_sitl.bus.session import publish_start
    from swarm_sitl.faults.processes import LostAircraftError, ProcessFaults

    if lockstep:
        try:
            cfg.faults.check_lockstep()
        except ValueError as e:
            raise ConfigError(str(e)) from None
    run_dir.mkdir(parents=True, exist_ok=True)
    cfg_path = run_dir / "config.yaml"
    cfg_path.write_text(cfg.to_yaml())
    procs_dir(run_dir).mkdir(parents=True, exist_ok=True)
    t_spawn = time.monotonic()
    sup = Supervisor(run_dir)
    if uses_fork_server(cfg):
        sup.fork_server = start_fork_server(cfg_path, run_dir)  # it compiles or loads the kernels
    else:
        compile_kernels(cfg)
    hub, session = open_hub(cfg, run_dir, sup)
    monitor = RunMonitor(session, cfg)
    faults = None
    if cfg.faults.plan:
        events = supervisor_events_path(run_dir)
        faults = ProcessFaults(cfg.faults, cfg.control_dt_s, cfg.run.stop_on_loss, sup, lockstep, events)
        sup.planned_exit = faults.planned_exit
    try:
        key_file = signing_key_file(cfg, run_dir, own_vehicles=mavlink is None)
        if mavlink is None:
            endpoints, ground = start_vehicles(sup, cfg, lockstep, base_port, key_file)
            if on_vehicles is not None:
                on_vehicles(port_lines(endpoints, ground))
        else:
            endpoints = dict(mavlink)
        signing = ["--signing-key-file", str(key_file)] if key_file is not None else []
        node_args = {"leader": ["leader"]}
        for f in cfg.followers:
            url = endpoints[f.id]
            url = "udpout:" + url.removeprefix("udp:") if mavlink is None else url
            node_args[f"controller_{f.id}"] = ["controller", "--id", str(f.id), "--mavlink", url, *signing]

        def argv(process: str, incarnation: int = 0, resume_tick: int = 0) -> list[str]:
            role, *extra = node_args[process]
            if incarnation:
                extra += ["--incarnation", str(incarnation), "--resume-tick", str(resume_tick)]
            return node_argv(cfg_path, role, lockstep, hub, run_dir, extra)

        if faults is not None:
            faults.set_restart(argv)
            sup.planned_stop = faults.frozen
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
        next_start_put = 0.0
        next_progress = 0.0
        while not sup.finished():
            if faults is not None:
                try:
                    faults.act(time.time() - epoch, monitor.min_step(faults.down | faults.lost))
                except LostAircraftError as e:
                    raise RunFailedError(str(e)) from None
            sup.check()
            now = time.monotonic()
            if now >= next_start_put:  # again and again: a late subscriber still gets it
                publish_start(session, cfg.name, epoch)
                next_start_put = now + 0.5
            if on_progress is not None and now >= next_progress:
                on_progress(monitor.min_step(), monitor.errors_m())
                next_progress = now + 0.25
            time.sleep(SUPERVISE_EVERY_S)
        run_wall = time.monotonic() - t_start
        if on_progress is not None:
            on_progress(cfg.n_control_steps, monitor.errors_m())
        return RunResult(run_wall, startup, endpoints)
    finally:
        if faults is not None:
            faults.close()
        monitor.close()
        sup.close()
        session.close()
