"""rmw_zenoh's wire layout (ros2/rmw_zenoh, ``docs/design.md``), written from its description.

- A topic's data is put on ``<domain_id>/<fully qualified name without its leading '/'>/
  <DDS type name>/<type hash>`` (``data_key``), e.g. ``0/chatter/std_msgs::msg::dds_::String_/
  RIHS01_df66...``; the payload is the message in CDR, little-endian (``types.encode``).
- Every put carries a 33-byte attachment (``Attachment``): the publisher's sequence number (int64),
  the source timestamp in ns since the UNIX epoch (int64), the GID's length (one byte, 16) and the
  publisher's GID (16 bytes), little-endian.
- A ROS 2 graph sees a node and its publishers by their liveliness tokens (``node_token``,
  ``publisher_token``) under ``@ros2_lv/<domain_id>/<zenoh session id>/<node id>/<entity id>/
  <kind>/<enclave>/<namespace>/<node name>[/<topic>/<type>/<hash>/<qos>]``, each name mangled
  (``/`` -> ``%``; an empty namespace or enclave is ``%``), with the QoS in rmw_zenoh's compact form
  (``Qos.token``): ``<reliability>:<durability>:<history kind>,<depth>:<deadline s>,<ns>:
  <lifespan s>,<ns>:<liveliness kind>,<lease s>,<ns>``, each field left empty where it is the
  default profile's (reliable, volatile, keep last; infinite deadline, lifespan and lease;
  automatic liveliness), the depth always written: a publisher keeping the last 7 is
  ``::,7:,:,:,,``.

ROS 2 Humble's rmw_zenoh has no type hashes: its keys and tokens carry ``TypeHashNotSupported``
where Jazzy and later carry the hash (``types.TYPE_HASHED``).
"""

import hashlib
import struct
from dataclasses import dataclass

ADMIN_SPACE = "@ros2_lv"
NODE, PUBLISHER, SUBSCRIPTION = "NN", "MP", "MS"
GID_BYTES = 16
_ATTACHMENT = struct.Struct("<qqB16s")  #: sequence number, timestamp [ns], GID length, GID
ATTACHMENT_BYTES = _ATTACHMENT.size  # 33


def dds_type_name(ros_type: str) -> str:
    """``pkg/msg/Name`` as DDS names it: ``pkg::msg::dds_::Name_``."""
    pkg, kind, name = ros_type.split("/")
    return f"{pkg}::{kind}::dds_::{name}_"


def mangle(name: str) -> str:
    """A name in a liveliness token: each ``/`` as ``%`` (an empty one: ``%``)."""
    return name.replace("/", "%") if name else "%"


def demangle(name: str) -> str:
    """A name as a liveliness token has it, back (``%`` -> ``/``; a lone ``%``: empty)."""
    return "" if name == "%" else name.replace("%", "/")


def data_key(domain_id: int, topic: str, ros_type: str, type_hash: str) -> str:
    """The key a topic's messages are put on."""
    return f"{domain_id}/{topic.lstrip('/')}/{dds_type_name(ros_type)}/{type_hash}"


@dataclass(frozen=True)
class Qos:
    """A publisher's QoS, as far as a run's topics use it."""

    depth: int = 10
    reliable: bool = True
    transient_local: bool = False  #: late joiners get the last ``depth`` (``/clock``: volatile)

    def token(self) -> str:
        """The QoS part of a liveliness token (module docstring)."""
        reliability = "" if self.reliable else "2"  # RMW_QOS_POLICY_RELIABILITY_BEST_EFFORT
        durability = "1" if self.transient_local else ""  # ..._DURABILITY_TRANSIENT_LOCAL
        return f"{reliability}:{durability}:,{self.depth}:,:,:,,"


def node_token(domain_id: int, zid: str, node_id: int, namespace: str, node: str, enclave: str = "") -> str:
    """A node's liveliness token."""
    return (
        f"{ADMIN_SPACE}/{domain_id}/{zid}/{node_id}/{node_id}/{NODE}/"
        f"{mangle(enclave)}/{_namespace(namespace)}/{node}"
    )


def publisher_token(
    domain_id: int,
    zid: str,
    node_id: int,
    entity_id: int,
    namespace: str,
    node: str,
    topic: str,
    ros_type: str,
    type_hash: str,
    qos: Qos,
    enclave: str = "",
    kind: str = PUBLISHER,
) -> str:
    """A publisher's (or, with ``kind`` ``MS``, a subscription's) liveliness token."""
    return (
        f"{ADMIN_SPACE}/{domain_id}/{zid}/{node_id}/{entity_id}/{kind}/{mangle(enclave)}/"
        f"{_namespace(namespace)}/{node}/{mangle(topic)}/{dds_type_name(ros_type)}/{type_hash}/{qos.token()}"
    )


def _namespace(namespace: str) -> str:
    return "%" if namespace in ("", "/") else mangle(namespace)


def gid(token: str) -> bytes:
    """A publisher's 16-byte GID: unique to its liveliness token (its session, node and entity)."""
    return hashlib.sha256(token.encode()).digest()[:GID_BYTES]


@dataclass(frozen=True)
class Attachment:
    """What every put of a publisher carries beside its payload."""

    sequence: int  #: the publisher's count of its messages, from 1
    timestamp_ns: int  #: the source's time, ns since the UNIX epoch
    gid: bytes  #: the publisher's (``GID_BYTES``)

    def pack(self) -> bytes:
        return _ATTACHMENT.pack(self.sequence, self.timestamp_ns, len(self.gid), self.gid)

    @classmethod
    def unpack(cls, data: bytes) -> "Attachment":
        """``ValueError`` (one line) for bytes that are not one."""
        if len(data) != ATTACHMENT_BYTES:
            raise ValueError(f"an attachment has {ATTACHMENT_BYTES} bytes, not {len(data)}")
        seq, t_ns, n, g = _ATTACHMENT.unpack(data)
        if n != GID_BYTES:
            raise ValueError(f"an attachment's GID has {GID_BYTES} bytes, not {n}")
        return cls(seq, t_ns, g)
