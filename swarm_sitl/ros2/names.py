"""ROS 2 names, and where a run's topics are.

The rules are ROS 2's (design.ros2.org, "Topic and Service name mapping"; rcl's name validation):
a fully qualified topic name starts with ``/``; its tokens are separated by single ``/``, are made
of ASCII letters, digits and ``_``, and do not start with a digit; it does not end with ``/``. A
node name is one such token. Our bus's keys (``swarm/<name>/edge/1/4``) have tokens that start
with a digit: no ROS 2 name can be one, so a run's ROS 2 topics have names of their own.

A run's topics (``RunTopics``), under the run's namespace (``ros2.namespace``, default ``/swarm``),
one namespace per vehicle as ROS swarm stacks have it:

- ``/clock``: the simulated time (``rosgraph_msgs/msg/Clock``), for ``use_sim_time``;
- ``<ns>/follower_<i>/pose`` and ``<ns>/follower_<i>/odom``: the vehicle (``PoseStamped``,
  ``Odometry``; frame ``world``, ENU; the odometry's twist in the body frame FLU, as REP-105 has it);
- ``<ns>/leader/pose`` and ``<ns>/leader/odom``: the leader's reference;
- ``<ns>/edge/from_<src>/to_<dst>``: what ``src`` sent ``dst`` (``swarm_sitl_msgs/msg/Estimate``);
- ``<ns>/events``: the run's events, one JSON line each (``std_msgs/msg/String``).
"""

import re
from dataclasses import dataclass

_TOKEN = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")


class RosNameError(ValueError):
    """A name ROS 2 refuses; the message says which rule it breaks."""


def check_token(token: str, what: str = "name") -> str:
    """``token`` if it is a legal ROS 2 name token (a node name, a namespace's part)."""
    if not token:
        raise RosNameError(f"{what}: empty")
    if token[0].isdigit():
        raise RosNameError(f"{what} {token!r}: a ROS 2 name token does not start with a digit")
    if not _TOKEN.fullmatch(token):
        raise RosNameError(f"{what} {token!r}: a ROS 2 name token is ASCII letters, digits and '_'")
    return token


def check_topic(name: str) -> str:
    """``name`` if it is a legal fully qualified ROS 2 topic name."""
    if not name.startswith("/"):
        raise RosNameError(f"topic {name!r}: a fully qualified name starts with '/'")
    if name == "/" or name.endswith("/"):
        raise RosNameError(f"topic {name!r}: a topic name does not end with '/'")
    for token in name[1:].split("/"):
        if not token:
            raise RosNameError(f"topic {name!r}: '//' is not allowed")
        check_token(token, f"topic {name!r}: token")
    return name


def check_namespace(ns: str) -> str:
    """``ns`` (``/``, or a fully qualified name) if ROS 2 takes it as a namespace."""
    return ns if ns == "/" else check_topic(ns)


@dataclass(frozen=True)
class RunTopics:
    """The fully qualified names of a run's topics under namespace ``ns`` (module docstring)."""

    ns: str = "/swarm"

    def __post_init__(self) -> None:
        check_namespace(self.ns)

    def _under(self, *tokens: str) -> str:
        return check_topic("/".join([self.ns.rstrip("/"), *tokens]))

    clock = "/clock"

    def follower(self, i: int, what: str) -> str:
        """``what`` (``pose`` or ``odom``) of follower ``i``."""
        return self._under(f"follower_{i}", what)

    def leader(self, what: str) -> str:
        return self._under("leader", what)

    def edge(self, src: int, dst: int) -> str:
        return self._under("edge", f"from_{src}", f"to_{dst}")

    def events(self) -> str:
        return self._under("events")
