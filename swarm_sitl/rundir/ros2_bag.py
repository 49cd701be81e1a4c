"""A run directory as a rosbag2 file: ``swarm-sitl export RUN_DIR --ros2``.

The bag (MCAP storage, rosbag2 metadata version 9, written by ``rosbags``) holds the run's ROS 2
topics (``names.RunTopics``) as a ROS 2 node would have recorded them, each message in CDR with
its type's definition and RIHS01 hash in the bag's metadata, each at its tick's simulated time
(ns from the run's start; ``/clock`` carries the same):

- ``/clock`` at every tick of the leader;
- each follower's ``pose`` (``PoseStamped``: p_W, q_WB) and ``odom`` (``Odometry``: the same
  pose, its twist in the body frame FLU: R(q_WB)^T v_W and omega_B, as REP-105 puts a child
  frame's twist), frame ``world`` (ENU), child frame ``follower_<i>``;
- the leader's reference as ``pose`` and ``odom`` (identity attitude, v_r);
- each edge's message (``swarm_sitl_msgs/msg/Estimate``) at the sender's ticks (the leader's: its
  reference and derivatives, as it publishes them), for the paper's law;
- ``events`` (``std_msgs/msg/String``, one JSON object each).

rosbags' reader, ``ros2 bag info``/``play`` (Jazzy) and Foxglove open it.
"""

import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from sim_vehicles.common.quaternion import rotate_inverse
from swarm_sitl.config.load import load_recorded
from swarm_sitl.ros2 import types
from swarm_sitl.ros2.messages import Messages
from swarm_sitl.ros2.names import RunTopics
from swarm_sitl.rundir.events import read_events
from swarm_sitl.rundir.load import load_run

ESTIMATE_FIELDS = ("p_hat", "v_hat", "a_hat", "a_hat_dot")  #: the paper's message, in its order


class BagError(RuntimeError):
    """The bag cannot be written (one line: where, and why)."""


def write_bag(
    run_dir: str | Path, out: str | Path, ns: str = "/swarm", distro: str = "jazzy"
) -> dict[str, int]:
    """Write ``run_dir`` as a rosbag2 directory ``out`` (which must not exist); the message count
    per topic."""
    from rosbags.rosbag2 import StoragePlugin, Writer

    run_dir, out = Path(run_dir), Path(out)
    if out.exists():
        raise BagError(f"{out}: exists (rosbag2 writes a new directory)")
    rec = load_run(run_dir)
    cfg = load_recorded(run_dir)
    topics = RunTopics(ns)
    m = Messages(distro)
    counts: dict[str, int] = {}
    with Writer(out, version=9, storage_plugin=StoragePlugin.MCAP) as w:
        connections: dict[str, Any] = {}

        def put(topic: str, ros_type: str, t_s: float, message: Any) -> None:
            c = connections.get(topic)
            if c is None:
                c = connections[topic] = w.add_connection(
                    topic,
                    ros_type,
                    typestore=types.store(distro),
                    rihs01=types.type_hash(ros_type, distro) if distro in types.TYPE_HASHED else None,
                )
            w.write(c, max(0, round(t_s * 1e9)), types.encode(message, ros_type, distro))
            counts[topic] = counts.get(topic, 0) + 1

        L = rec.leader
        zero = np.zeros(3)
        for k in _finite(L["t_s"]):
            t = float(L["t_s"][k])
            put(topics.clock, types.CLOCK, t, m.clock(t))
            pose = m.pose(L["p_r"][k], None)
            put(topics.leader("pose"), types.POSE_STAMPED, t, m.pose_stamped(t, pose))
            put(topics.leader("odom"), types.ODOMETRY, t, m.odometry(t, "leader", pose, L["v_r"][k], zero))
        for i, a in sorted(rec.followers.items()):
            for k in _finite(a["t_s"]):
                if not np.all(np.isfinite(a["p_W"][k])):
                    continue
                t = float(a["t_s"][k])
                q = a["q_WB"][k]
                pose = m.pose(a["p_W"][k], q)
                put(
                    topics.follower(i, "pose"),
                    types.POSE_STAMPED,
                    t,
                    m.pose_stamped(t, pose),
                )
                v_body = np.asarray(rotate_inverse(np.asarray(q, float), np.asarray(a["v_W"][k], float)))
                odom = m.odometry(t, f"follower_{i}", pose, v_body, a["omega_B"][k])
                put(topics.follower(i, "odom"), types.ODOMETRY, t, odom)
        trajectory = cfg.trajectory()
        for src, dst in cfg.graph_edges():
            a = L if src == 0 else rec.followers[src]
            if src != 0 and not all(n in a for n in ESTIMATE_FIELDS):
                continue  # another law's message is its own: not recorded as such
            for k in _finite(a["t_s"]):
                t = float(a["t_s"][k])
                if src == 0:  # the reference and its derivatives, as the leader publishes them
                    values = np.concatenate(trajectory.derivatives(t)[:4])
                    p = L["p_r"][k]
                else:
                    values = np.concatenate([a[n][k] for n in ESTIMATE_FIELDS])
                    p = a["p_W"][k]
                if not np.all(np.isfinite(values)):
                    continue
                est = m.estimate(t, src, dst, int(k), p, values)
                put(topics.edge(src, dst), types.ESTIMATE, t, est)
        for e in read_events(run_dir / "events.jsonl"):
            if math.isfinite(e["t_s"]):
                put(topics.events(), types.STRING, float(e["t_s"]), m.string(json.dumps(e)))
    return counts


def _finite(t: np.ndarray) -> list[int]:
    return [k for k in range(len(t)) if math.isfinite(t[k])]
