"""A running swarm on ROS 2 topics: the run's ROS 2 face (``ros2:`` in the config, ``run --ros2``).

The supervisor's own zenoh session (the run's router, by default) republishes the run in
rmw_zenoh's layout (``ros2.wire``), so a ROS 2 node with ``rmw_zenoh_cpp`` that joins the router
sees a node ``swarm_sitl`` and its publishers (``ros2 topic list``) and reads their messages:

- each follower's ``pose`` and ``odom``, from the state its controller puts with each status
  (``bus.codec.State``: position, velocity, attitude, body rates; the odometry's twist in the
  body frame, as REP-105 has it);
- the leader's ``pose`` and ``odom``: its reference at the slowest follower's tick (the
  trajectory the leader flies, as the supervisor's formation readout reads it);
- each edge's newest message (``swarm_sitl_msgs/msg/Estimate``): what its sender's state says it
  sent (the leader's: its reference and derivatives), and the run's ``events``.

``/clock`` is the leader's (``nodes.ros2_clock``): it steps by ``dt``, every tick.

Each publisher has its liveliness token (its QoS: reliable, volatile, keep last 10) and its GID,
each put its 33-byte attachment (sequence number, source time, GID) and the type hashes of the
config's distro family. It reads only the followers' states, through rings on the Rust side
(zenoh's, the newest few of each key), never the edges (a subscriber on every edge in the
router's own process made a lockstep run of the paper's swarm 40 times slower), and runs on the
supervisor's loop at ``ros2.rate_hz`` of the wall clock
(``running.observers``): nothing of it is on a node's path, so a lockstep run is the same with it
as without it, and a run without ``ros2:`` has none of it. What it cannot decode is dropped and
counted (``dropped``); an error in it is said once and ends the face, never the run.
"""

import json
from pathlib import Path
from typing import Any

import numpy as np
import zenoh

from sim_vehicles.common.quaternion import rotate_inverse
from swarm_sitl.bus import keys as zenoh_keys
from swarm_sitl.bus.access import ROS2_USER, ros2_controller_user
from swarm_sitl.bus.codec import PayloadError, State, decode_state
from swarm_sitl.config.schema import SwarmConfig
from swarm_sitl.nodes.ros2_controller import control_topic
from swarm_sitl.ros2 import types, wire
from swarm_sitl.ros2.messages import Messages
from swarm_sitl.ros2.names import RunTopics
from swarm_sitl.ros2.publisher import Publisher
from swarm_sitl.rundir.events import EventTail
from swarm_sitl.rundir.layout import (
    procs_dir,
    ros2_join_path,
    zenoh_ros2_controller_password_path,
    zenoh_ros2_password_path,
)
from swarm_sitl.rundir.whole_files import write_text_whole

NODE = "swarm_sitl"  #: the face's node name, in the run's namespace
RING = 4  #: samples of each key kept between two looks (only the newest is republished)
_IDENTITY = np.array([1.0, 0.0, 0.0, 0.0])


class Ros2Face:
    """The run of ``cfg`` on ROS 2 topics through ``session`` (module docstring)."""

    def __init__(self, session: Any, cfg: SwarmConfig, run_dir: Path):
        self.session, self.cfg = session, cfg
        r = cfg.ros2
        self.zid = str(session.info.zid())
        self.distro = r.distro
        self.topics = RunTopics(r.namespace)
        self.dropped = 0  #: payloads on the bus that did not decode
        self.error: str | None = None  #: what ended the face (one line), if anything did
        self._m = Messages(r.distro)
        self._node = session.liveliness().declare_token(
            wire.node_token(r.domain_id, self.zid, 0, r.namespace, NODE)
        )
        self._pubs: dict[str, Publisher] = {}
        wanted = [(self.topics.events(), types.STRING)]
        wanted += [
            (self.topics.leader(w), t) for w, t in (("pose", types.POSE_STAMPED), ("odom", types.ODOMETRY))
        ]
        for f in cfg.followers:
            wanted += [(self.topics.follower(f.id, "pose"), types.POSE_STAMPED)]
            wanted += [(self.topics.follower(f.id, "odom"), types.ODOMETRY)]
        self._edges = cfg.graph_edges()
        wanted += [(self.topics.edge(s, d), types.ESTIMATE) for s, d in self._edges]
        for n, (topic, ros_type) in enumerate(wanted, start=1):
            self._pubs[topic] = Publisher(
                session, r.domain_id, self.zid, r.namespace, NODE, n, topic, ros_type, r.distro
            )
        ring = zenoh.handlers.RingChannel
        self._states = {
            f.id: session.declare_subscriber(zenoh_keys.state(cfg.name, f.id), ring(RING))
            for f in cfg.followers
        }
        self._newest: dict[int, State] = {}
        self._trajectory = cfg.trajectory()
        self._events = EventTail(procs_dir(run_dir))
        self._last_tick = -1
        self._outs: dict[int, list[int]] = {}
        for src, dst in self._edges:
            self._outs.setdefault(src, []).append(dst)

    def started(self, epoch_unix_s: float) -> None:
        """The run's start signal went out (its vehicles stamp their events with the UNIX time)."""
        self._events.epoch_unix_s = epoch_unix_s

    # -- on the supervisor's loop ------------------------------------------------------------------
    def act(self, run_s: float, now: float) -> None:
        """Republish the newest of each topic; an error ends the face (said in ``error``)."""
        if self.error is not None:
            return
        try:
            self._republish()
        except Exception as e:  # the face is never worth a run
            self.error = f"the ROS 2 face stopped: {type(e).__name__}: {e}"
            self.close()

    def _republish(self) -> None:
        for i, sub in self._states.items():
            s = self._newest_of(sub)
            if s is None or s.follower != i:  # (not its sender's: a peer-mode bus has no access control)
                continue
            self._newest[i] = s
            self._vehicle(
                f"follower_{i}", self.topics.follower(i, "pose"), self.topics.follower(i, "odom"), s
            )
            for dst in self._outs.get(i, []):
                self._put(self.topics.edge(i, dst), self._estimate(dst, s))
        self._leader()
        for e in self._events.read():
            self._put(self.topics.events(), self._m.string(json.dumps(e)))

    def _leader(self) -> None:
        """The leader's reference and its edges, at the slowest follower's newest tick."""
        if len(self._newest) < len(self._states):
            return
        slowest = min(self._newest.values(), key=lambda s: s.step)
        if slowest.step <= self._last_tick:
            return
        self._last_tick, t = slowest.step, slowest.t_s
        d = self._trajectory.derivatives(t)
        ref = State(0, slowest.step, t, d[0], d[1], _IDENTITY, np.zeros(3), np.concatenate(d[:4]))
        self._vehicle("leader", self.topics.leader("pose"), self.topics.leader("odom"), ref)
        for dst in self._outs.get(0, []):
            self._put(self.topics.edge(0, dst), self._estimate(dst, ref))

    def _newest_of(self, sub: Any) -> State | None:
        """The newest state in ``sub``'s ring that decodes (the others dropped and counted)."""
        newest = None
        while (sample := sub.try_recv()) is not None:
            try:
                newest = decode_state(sample.payload.to_bytes())
            except PayloadError:
                self.dropped += 1
        return newest

    def _put(self, topic: str, message: Any) -> None:
        self._pubs[topic].put(message)

    def _vehicle(self, child: str, pose_topic: str, odom_topic: str, s: State) -> None:
        m = self._m
        pose = m.pose(s.p_W, s.q_WB)
        self._put(pose_topic, m.pose_stamped(s.t_s, pose))
        v_body = rotate_inverse(np.asarray(s.q_WB, dtype=float), np.asarray(s.v_W, dtype=float))
        self._put(odom_topic, m.odometry(s.t_s, child, pose, v_body, s.omega_B))

    def _estimate(self, dst: int, s: State) -> Any:
        """What ``s``'s node sent ``dst`` at its tick (``s.values``)."""
        return self._m.estimate(s.t_s, s.follower, dst, s.step, s.p_W, s.values)

    def close(self) -> None:
        for sub in self._states.values():
            sub.undeclare()
        for p in self._pubs.values():
            p.close()
        self._node.undeclare()
        self._states, self._pubs = {}, {}


def write_ros2_join(cfg: SwarmConfig, hub: str | None, run_dir: Path, lockstep: bool = False) -> str:
    """``RUN_DIR/ros2_join.json``: how a ROS 2 node joins this run (and whether the run waits for
    a ROS 2 controller's answer to each tick: ``lockstep``); returns its one line."""
    r = cfg.ros2
    line = ros2_join_line(cfg, hub, run_dir)
    join: dict[str, Any] = {
        "endpoint": hub,
        "domain_id": r.domain_id,
        "namespace": r.namespace,
        "lockstep": lockstep,
    }
    if hub is not None and cfg.zenoh.mode == "router":
        join |= {"user": ROS2_USER, "password_file": str(zenoh_ros2_password_path(run_dir))}
        join["controllers"] = {  # who flies which follower, and only that one
            str(i): {
                "user": ros2_controller_user(i),
                "password_file": str(zenoh_ros2_controller_password_path(run_dir, i)),
                "topics": control_topic(r.namespace, i, "*"),
            }
            for i in r.controllers
        }
    # whole or absent: a ROS 2 user's script polls for it while the run starts
    write_text_whole(ros2_join_path(run_dir), json.dumps({**join, "line": line}, indent=1) + "\n")
    return line


def ros2_join_line(cfg: SwarmConfig, hub: str | None, run_dir: Path) -> str:
    """How a ROS 2 user joins this run (``docs/ros2.md``): the environment of a ROS 2 command."""
    r = cfg.ros2
    where = f"ROS 2 (domain {r.domain_id}, {r.namespace}/...): "
    if hub is None:  # client mode: the run's router is the configured one
        return where + "join the router at " + ", ".join(cfg.zenoh.connect) + " as any other ROS 2 node does"
    env = f'ZENOH_CONFIG_OVERRIDE=\'mode="client";connect/endpoints=["{hub}"]'
    if cfg.zenoh.mode == "router":
        password = zenoh_ros2_password_path(run_dir)
        auth = "transport/auth/usrpwd"
        env += f';{auth}/user="{ROS2_USER}";{auth}/password="\'"$(cat {password})"\'"'
    return where + f"{env}' ROS_DOMAIN_ID={r.domain_id} RMW_IMPLEMENTATION=rmw_zenoh_cpp ros2 topic list"
