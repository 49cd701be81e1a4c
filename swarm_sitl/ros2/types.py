"""The message types a run's ROS 2 topics use, their type hashes and their CDR encoding.

``rosbags``' type store holds ROS 2's message definitions (Jazzy's, and Humble's) and computes
each type's RIHS01 hash (REP-2016: the SHA-256 of the type's description) and its CDR bytes. We
add ours (``msg/*.msg``, package ``swarm_sitl_msgs``), so a ROS user can build the same package
and get the same hash. Why ``rosbags``: it is pure Python, writes and reads rosbag2 (``bag``),
and its CDR and hashes are checked in its own tests against ROS 2's; a second CDR encoder and a
second hash of our own would be code we keep for no user.

``TYPE_HASHED``: the distro families whose rmw_zenoh keys carry type hashes (Jazzy and later).
Humble's rmw_zenoh puts ``TypeHashNotSupported`` in their place (``type_hash``).
"""

import functools
from pathlib import Path
from typing import Any

MSG_DIR = Path(__file__).parent / "msg"
OURS = "swarm_sitl_msgs"
POSE_STAMPED = "geometry_msgs/msg/PoseStamped"
ODOMETRY = "nav_msgs/msg/Odometry"
CLOCK = "rosgraph_msgs/msg/Clock"
STRING = "std_msgs/msg/String"
ESTIMATE = f"{OURS}/msg/Estimate"
DISTROS = ("jazzy", "humble")  #: the distro families a run can speak
TYPE_HASHED = ("jazzy",)
NO_TYPE_HASH = "TypeHashNotSupported"


class Ros2TypesError(RuntimeError):
    """The type store cannot be had (``rosbags`` missing): one line saying how to get it."""


@functools.lru_cache(maxsize=4)
def store(distro: str = "jazzy") -> Any:
    """``distro``'s type store with our messages registered in it."""
    try:
        from rosbags.typesys import Stores, get_types_from_msg, get_typestore
    except ImportError:  # (a dependency of the package: only a broken install lacks it)
        raise Ros2TypesError("ROS 2 types need the 'rosbags' package: pip install rosbags") from None
    if distro not in DISTROS:
        raise Ros2TypesError(f"ROS 2 distro {distro!r}: one of {', '.join(DISTROS)}")
    ts = get_typestore(Stores.ROS2_JAZZY if distro == "jazzy" else Stores.ROS2_HUMBLE)
    for path in sorted(MSG_DIR.glob("*.msg")):
        ts.register(get_types_from_msg(path.read_text(), f"{OURS}/msg/{path.stem}"))
    return ts


def type_hash(ros_type: str, distro: str = "jazzy") -> str:
    """``RIHS01_<sha256>`` of ``ros_type``, or ``NO_TYPE_HASH`` where the distro has none."""
    if distro not in TYPE_HASHED:
        return NO_TYPE_HASH
    return str(store(distro).hash_rihs01(ros_type))


def message_definition(ros_type: str, distro: str = "jazzy") -> str:
    """The ``.msg`` text of ``ros_type`` with its dependencies (rosbag2's ``ros2msg`` schema)."""
    text, _ = store(distro).generate_msgdef(ros_type, ros_version=2)
    return str(text)


def encode(message: Any, ros_type: str, distro: str = "jazzy") -> bytes:
    """``message`` (an instance of ``store(distro).types[ros_type]``) in CDR, little-endian."""
    return bytes(store(distro).serialize_cdr(message, ros_type))


def decode(data: bytes, ros_type: str, distro: str = "jazzy") -> Any:
    return store(distro).deserialize_cdr(data, ros_type)


def new(ros_type: str, distro: str = "jazzy", **fields: Any) -> Any:
    """A message of ``ros_type`` with ``fields``."""
    return store(distro).types[ros_type](**fields)
