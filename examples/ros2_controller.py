"""A ROS 2 node flying one follower of a running swarm, in a page of Python, with no ROS installed
(``pip install zenoh-ros2-sdk``; with ROS 2 Jazzy and rmw_zenoh, rclpy does the same on the same
topics).

    swarm-sitl run configs/paper.yaml --realtime --ros2-controller 4 --out runs/r2 &
    python examples/ros2_controller.py runs/r2 4

It joins the run's router as the user the run names for follower 4 (``RUN_DIR/ros2_join.json``),
reads its vehicle's odometry and its in-neighbours' messages on ``/swarm/follower_4/control/*``,
runs the paper's law (any law of the contract would do: ``docs/laws.md``) and publishes its
attitude setpoint and its own message there, stamped with the odometry's stamp, until the run
ends. In real time it answers once it has heard every in-neighbour; a lockstep run (``run``
without ``--realtime``, ``"lockstep"`` in ``ros2_join.json``) waits for its answer to each
odometry, from the first on. ``tests/test_ros2_controller.py`` runs this file.
"""

import json
import math
import os
import sys
import time
from pathlib import Path

import numpy as np


def fly(run_dir: Path, i: int, msgs: Path | None = None, answers: list | None = None) -> int:
    """Fly follower ``i`` of the run writing ``run_dir`` until it ends; returns the setpoints sent.
    ``msgs``: a folder of ``.msg`` files for the client's registry (it fetches ROS 2's otherwise);
    ``answers``: if given, each setpoint's ``(t_s, thrust_N)`` is appended to it."""
    while not (run_dir / "ros2_join.json").is_file():
        time.sleep(0.01)
    join = json.loads((run_dir / "ros2_join.json").read_text())
    me, lockstep = join["controllers"][str(i)], join["lockstep"]
    password = Path(me["password_file"]).read_text().strip()
    auth = "transport/auth/usrpwd"
    os.environ["ZENOH_CONFIG_OVERRIDE"] = (
        f'mode="client";{auth}/user="{me["user"]}";{auth}/password="{password}"'
    )
    from zenoh_ros2_sdk import ROS2Publisher, ROS2Subscriber
    from zenoh_ros2_sdk.message_registry import get_registry

    from swarm_sitl.config.load import load_config
    from swarm_sitl.laws.contract import Received, VehicleSample
    from swarm_sitl.nodes.assembly import build_law

    if msgs is not None:
        get_registry(str(msgs))
    cfg = load_config(run_dir / "config.yaml")
    law = build_law(cfg, i)
    host, port = join["endpoint"].removeprefix("tcp/").split(":")
    where = {"router_ip": host, "router_port": int(port)}
    base = f"{join['namespace']}/follower_{i}/control"
    setpoint = ROS2Publisher(f"{base}/setpoint", "swarm_sitl_msgs/msg/AttitudeSetpoint", **where)
    message = ROS2Publisher(f"{base}/message", "swarm_sitl_msgs/msg/Estimate", **where)
    T = setpoint.session_mgr.store.types
    sources = [s for s, _ in cfg.build_graph().in_neighbours(i)]
    inbox: dict[int, Received] = {}
    sent, last = [0], [math.inf]

    def on_message(src: int):
        def got(m) -> None:
            inbox[src] = Received(
                np.asarray(m.values, dtype=float), m.stamp.sec + m.stamp.nanosec * 1e-9, 0.0
            )

        return got

    def on_odom(m) -> None:  # one tick: the law on what the vehicle and the neighbours said
        last[0] = time.monotonic()
        t = m.header.stamp.sec + m.header.stamp.nanosec * 1e-9
        o, p, v = m.pose.pose.orientation, m.pose.pose.position, m.twist.twist.linear
        q = np.array([o.w, o.x, o.y, o.z])
        w, x, y, z = q  # the twist is in the body frame (REP-105): rotate it to the world's
        R = np.array(
            [
                [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
            ]
        )
        if not lockstep and set(inbox) != set(sources):
            return  # (real time: not yet heard from every in-neighbour; lockstep waits for each answer)
        sample = VehicleSample(t, np.array([p.x, p.y, p.z]), R @ np.array([v.x, v.y, v.z]), q)
        step = law.step(t, sample, {s: r._replace(age_s=t - r.t_s) for s, r in inbox.items()})
        c, stamp = step.command, m.header.stamp
        setpoint.publish(
            stamp=T["builtin_interfaces/msg/Time"](sec=stamp.sec, nanosec=stamp.nanosec),
            orientation=T["geometry_msgs/msg/Quaternion"](w=c.q_c[0], x=c.q_c[1], y=c.q_c[2], z=c.q_c[3]),
            body_rate=T["geometry_msgs/msg/Vector3"](x=c.omega_c_B[0], y=c.omega_c_B[1], z=c.omega_c_B[2]),
            thrust_n=float(c.thrust_N),
        )
        message.publish(
            stamp=T["builtin_interfaces/msg/Time"](sec=stamp.sec, nanosec=stamp.nanosec),
            src=i,
            dst=0,
            step=round(t / cfg.control_dt_s),
            sender_position=T["geometry_msgs/msg/Point"](x=p.x, y=p.y, z=p.z),
            values=np.asarray(step.message, dtype=float),
        )
        sent[0] += 1
        if answers is not None:
            answers.append((t, float(c.thrust_N)))

    subs = [ROS2Subscriber(f"{base}/odom", "nav_msgs/msg/Odometry", on_odom, **where)]
    subs += [
        ROS2Subscriber(f"{base}/from_{s}", "swarm_sitl_msgs/msg/Estimate", on_message(s), **where)
        for s in sources
    ]
    # until the run has written itself (or its odometry has stopped for 5 s: a run that failed)
    while not (run_dir / "summary.json").is_file() and time.monotonic() < last[0] + 5:
        time.sleep(0.1)
    for s in [*subs, setpoint, message]:
        s.close()
    return sent[0]


if __name__ == "__main__":
    print(f"{fly(Path(sys.argv[1]), int(sys.argv[2]))} setpoints sent")
