"""The messages a run's ROS 2 topics carry, built once: ``Messages(distro)`` makes each from our
arrays (ENU world, FLU body, SI; quaternions ``[w, x, y, z]``), for the rosbag2 export, the face of
a running swarm and the bridge of a follower a ROS 2 node flies."""

import struct
from typing import Any

import numpy as np

from swarm_sitl.ros2 import types

WORLD = "world"  #: the frame every pose is in (ENU)
_CDR_LE = b"\x00\x01\x00\x00"  #: the encapsulation header of little-endian plain CDR
_RATES = (21, 28, 35)  #: the twist covariance's angular diagonal (row-major 6 x 6)


class Messages:
    """Message builders of ``distro``'s type store."""

    def __init__(self, distro: str = "jazzy"):
        self.T = types.store(distro).types
        self._no_covariance = np.zeros(36)
        self._rates_unknown = np.zeros(36)
        self._rates_unknown[list(_RATES)] = -1.0  # (REP-style: no estimate of these)

    def stamp(self, t_s: float) -> Any:
        """``builtin_interfaces/Time`` of ``t_s`` (simulated seconds from the run's start)."""
        sec, nanosec = stamp_ns(t_s)
        return self.T["builtin_interfaces/msg/Time"](sec=sec, nanosec=nanosec)

    def point(self, v: Any) -> Any:
        return self.T["geometry_msgs/msg/Point"](x=float(v[0]), y=float(v[1]), z=float(v[2]))

    def vector3(self, v: Any) -> Any:
        return self.T["geometry_msgs/msg/Vector3"](x=float(v[0]), y=float(v[1]), z=float(v[2]))

    def pose(self, p_W: Any, q_WB: Any | None) -> Any:
        """``geometry_msgs/Pose``; ``q_WB`` None: the identity."""
        w, x, y, z = (1.0, 0.0, 0.0, 0.0) if q_WB is None else (float(c) for c in q_WB)
        return self.T["geometry_msgs/msg/Pose"](
            position=self.point(p_W), orientation=self.T["geometry_msgs/msg/Quaternion"](x=x, y=y, z=z, w=w)
        )

    def header(self, t_s: float) -> Any:
        return self.T["std_msgs/msg/Header"](stamp=self.stamp(t_s), frame_id=WORLD)

    def pose_stamped(self, t_s: float, pose: Any) -> Any:
        return self.T[types.POSE_STAMPED](header=self.header(t_s), pose=pose)

    def odometry(self, t_s: float, child: str, pose: Any, v_body: Any, omega_B: Any) -> Any:
        """``nav_msgs/Odometry`` in ``world`` with its twist in the body frame ``child`` (REP-105);
        body rates not known (NaN) are zeros with -1 on their covariance's diagonal."""
        rates = np.asarray(omega_B, dtype=float)
        known = bool(np.all(np.isfinite(rates)))
        twist = self.T["geometry_msgs/msg/Twist"](
            linear=self.vector3(v_body), angular=self.vector3(rates if known else np.zeros(3))
        )
        return self.T[types.ODOMETRY](
            header=self.header(t_s),
            child_frame_id=child,
            pose=self.T["geometry_msgs/msg/PoseWithCovariance"](pose=pose, covariance=self._no_covariance),
            twist=self.T["geometry_msgs/msg/TwistWithCovariance"](
                twist=twist, covariance=self._no_covariance if known else self._rates_unknown
            ),
        )

    def estimate(self, t_s: float, src: int, dst: int, step: int, sender_p_W: Any, values: Any) -> Any:
        """``swarm_sitl_msgs/Estimate``: what ``src`` sent ``dst`` at its tick ``step``."""
        return self.T[types.ESTIMATE](
            stamp=self.stamp(t_s),
            src=src,
            dst=dst,
            step=step,
            sender_position=self.point(sender_p_W),
            values=np.asarray(values, dtype=float),
        )

    def clock(self, t_s: float) -> Any:
        return self.T[types.CLOCK](clock=self.stamp(t_s))

    def string(self, text: str) -> Any:
        return self.T[types.STRING](data=text)


def stamp_ns(t_s: float) -> tuple[int, int]:
    """``(sec, nanosec)`` of ``t_s`` as ``builtin_interfaces/Time`` holds it."""
    ns = max(0, round(t_s * 1e9))
    return ns // 1_000_000_000, ns % 1_000_000_000


def clock_cdr(t_s: float) -> bytes:
    """The CDR of ``Messages.clock(t_s)`` without building the message (the leader puts one every
    tick): the header, ``int32 sec``, ``uint32 nanosec``."""
    return struct.pack("<4siI", _CDR_LE, *stamp_ns(t_s))
