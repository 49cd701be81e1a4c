"""One ROS 2 publisher in rmw_zenoh's layout (``wire``) on a zenoh session: its liveliness token,
its GID, and each put in CDR with its 33-byte attachment. Congestion drops a put rather than wait
for it: nothing of a run waits for what ROS 2 sees. The run's face and a ROS-flown follower's
bridge publish through it."""

import time
from typing import Any

import zenoh

from swarm_sitl.ros2 import types, wire


class Publisher:
    """``ros_type`` on ``topic`` for node ``node`` (in ``namespace``) of the session ``zid``,
    entity ``entity_id``, of ``distro``'s definitions."""

    def __init__(
        self,
        session: Any,
        domain_id: int,
        zid: str,
        namespace: str,
        node: str,
        entity_id: int,
        topic: str,
        ros_type: str,
        distro: str,
    ):
        h = types.type_hash(ros_type, distro)
        self.ros_type, self.distro = ros_type, distro
        token = wire.publisher_token(
            domain_id, zid, 0, entity_id, namespace, node, topic, ros_type, h, wire.Qos()
        )
        self.gid = wire.gid(token)
        self.sequence = 0
        self.token = session.liveliness().declare_token(token)
        self.pub = session.declare_publisher(
            wire.data_key(domain_id, topic, ros_type, h), congestion_control=zenoh.CongestionControl.DROP
        )

    def put(self, message: Any) -> None:
        self.put_cdr(types.encode(message, self.ros_type, self.distro))

    def put_cdr(self, payload: bytes) -> None:
        """A message of this publisher's type, in CDR already."""
        self.sequence += 1
        attachment = wire.Attachment(self.sequence, time.time_ns(), self.gid).pack()
        self.pub.put(payload, attachment=attachment)

    def close(self) -> None:
        self.pub.undeclare()
        self.token.undeclare()
