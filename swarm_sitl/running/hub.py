"""The supervisor's own zenoh session: the run's router (or its peer or client), and its view of
the bus: which nodes are ready, and each follower's progress and formation error.
"""

import socket
import threading
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import zenoh

from swarm_sitl.bus import access as zenoh_access
from swarm_sitl.bus import keys as zenoh_keys
from swarm_sitl.bus.codec import Status, decode_status, decode_waiting
from swarm_sitl.bus.session import error_line, open_router, open_session, router_runtime
from swarm_sitl.config.schema import SwarmConfig
from swarm_sitl.nodes.ros2_controller import control_topic
from swarm_sitl.rundir.layout import (
    zenoh_ros2_controller_password_path,
    zenoh_ros2_password_path,
    zenoh_users_path,
)
from swarm_sitl.running.supervisor import RunFailedError, Supervisor


def free_tcp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


#: status samples kept per follower between two looks of the supervisor (only the latest is used)
STATUS_RING = 8


class RunMonitor:
    """The supervisor's own view of the bus: readiness of every node and followers' status.

    Status samples wait in a ring per follower (zenoh's, on the Rust side) until the supervisor
    looks, a few times a second: in lockstep they come hundreds of times a second, and a Python
    callback for each would wake the supervisor and take the GIL that often for nothing."""

    def __init__(self, session: Any, cfg: SwarmConfig):
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

    def latest(self) -> dict[int, Status]:
        """Each follower's newest status."""
        self._read_status()
        return dict(self.status)

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
    """The supervisor's zenoh session and the endpoint the nodes connect to (``ZenohSection``): in
    ``router`` mode a router on ``zenoh.listen`` (by default a free loopback port) that
    authenticates each node with a fresh password (given to the node's processes in their
    environment) and holds it to its keys; in ``peer`` mode a peer on a free loopback port where
    the peers meet; in ``client`` mode a client of the configured router, and no endpoint of ours."""
    try:
        return _open_hub(cfg, run_dir, sup)
    except zenoh.ZError as e:
        raise RunFailedError(f"zenoh ({cfg.zenoh.mode} mode): {error_line(e)}") from None


def _open_hub(cfg: SwarmConfig, run_dir: Path, sup: Supervisor) -> tuple[str | None, Any]:
    if cfg.zenoh.mode == "client":
        return None, open_session(cfg.zenoh, credentials=zenoh_access.credentials_from_env())
    if cfg.zenoh.mode == "peer":
        hub = f"tcp/127.0.0.1:{free_tcp_port()}"
        return hub, open_session(cfg.zenoh.model_copy(update={"listen": [hub]}))
    listen = [_with_free_port(e) for e in cfg.zenoh.listen]
    ros2 = zenoh_ros2_password_path(run_dir) if cfg.ros2.enabled else None
    flown = {i: zenoh_ros2_controller_password_path(run_dir, i) for i in cfg.ros2.controllers}
    passwords = zenoh_access.write_credentials(cfg.n_followers, zenoh_users_path(run_dir), ros2, flown)
    controls = {i: control_topic(cfg.ros2.namespace, i, "").strip("/") for i in cfg.ros2.controllers}
    sup.env_for = lambda process: zenoh_access.credentials_env(process, passwords)
    nodes = [cfg.node_keys(n) for n in range(cfg.n_followers + 1)]
    with router_runtime():
        router = open_router(
            listen,
            str(zenoh_users_path(run_dir)),
            zenoh_access.access_control(
                cfg.name, nodes, cfg.ros2.domain_id if cfg.ros2.enabled else None, controls
            ),
        )
    return listen[0].replace("/0.0.0.0:", "/127.0.0.1:"), router


def _with_free_port(endpoint: str) -> str:
    """``tcp/127.0.0.1:0`` with a free port in place of 0 (the nodes must be told the port)."""
    if endpoint.startswith("tcp/127.0.0.1:") and endpoint.endswith(":0"):
        return f"tcp/127.0.0.1:{free_tcp_port()}"
    return endpoint
