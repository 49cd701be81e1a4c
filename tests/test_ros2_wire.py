"""rmw_zenoh's wire layout and ROS 2's names as ``swarm_sitl.ros2`` writes them: key expressions
and liveliness tokens byte for byte as ros2/rmw_zenoh's ``docs/design.md`` prints them, QoS tokens
and attachments as an independent implementation (``zenoh-ros2-sdk``) encodes and decodes them,
type hashes from two independent implementations (``rosbags`` and ``zenoh-ros2-sdk``) and against
the hashes ROS 2 publishes, and the name rules over random names."""

import math
import random
import re

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st
from zenoh_ros2_sdk.attachment import Attachment as SdkAttachment
from zenoh_ros2_sdk.qos import QosDurability, QosProfile, QosReliability
from zenoh_ros2_sdk.utils import compute_type_hash_from_msg

from swarm_sitl.ros2 import types, wire
from swarm_sitl.ros2.messages import Messages, clock_cdr
from swarm_sitl.ros2.names import RosNameError, RunTopics, check_token, check_topic
from tests.support import msg_files

pytestmark = pytest.mark.unit

#: design.md's examples (demo_nodes_cpp), as printed there
STRING_HASH = "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18"
CHATTER = f"0/chatter/std_msgs::msg::dds_::String_/{STRING_HASH}"
CHATTER_NS = f"0/robot1/chatter/std_msgs::msg::dds_::String_/{STRING_HASH}"
LISTENER = "@ros2_lv/2/aac3178e146ba6f1fc6e6a4085e77f21/0/0/NN/%/%/listener"
LISTENER_SUB = (
    "@ros2_lv/2/aac3178e146ba6f1fc6e6a4085e77f21/0/10/MS/%/%/listener/%chatter/"
    f"std_msgs::msg::dds_::String_/{STRING_HASH}/::,10:,:,:,,"
)
TALKER_PUB = (
    "@ros2_lv/2/8b20917502ee955ac4476e0266340d5c/0/10/MP/%/%/talker/%chatter/"
    f"std_msgs::msg::dds_::String_/{STRING_HASH}/::,7:,:,:,,"
)
#: published by ROS 2 (rosidl) and quoted by other implementations
PUBLISHED = {
    "std_msgs/msg/String": STRING_HASH,
    "geometry_msgs/msg/PoseStamped": (
        "RIHS01_10f3786d7d40fd2b54367835614bff85d4ad3b5dab62bf8bca0cc232d73b4cd8"
    ),
}


def test_keys_and_tokens_are_design_mds_examples_byte_for_byte():
    h = types.type_hash(types.STRING)
    assert wire.data_key(0, "/chatter", types.STRING, h) == CHATTER
    assert wire.data_key(0, "/robot1/chatter", types.STRING, h) == CHATTER_NS
    assert wire.node_token(2, "aac3178e146ba6f1fc6e6a4085e77f21", 0, "/", "listener") == LISTENER
    sub = wire.publisher_token(
        2, "aac3178e146ba6f1fc6e6a4085e77f21", 0, 10, "/", "listener", "/chatter", types.STRING, h,
        wire.Qos(depth=10), kind=wire.SUBSCRIPTION,
    )  # fmt: skip
    assert sub == LISTENER_SUB
    pub = wire.publisher_token(
        2,
        "8b20917502ee955ac4476e0266340d5c",
        0,
        10,
        "",
        "talker",
        "/chatter",
        types.STRING,
        h,
        wire.Qos(depth=7),
    )
    assert pub == TALKER_PUB


@pytest.mark.parametrize("ros_type", sorted(PUBLISHED))
def test_a_types_hash_is_the_one_ros2_publishes(ros_type):
    assert types.type_hash(ros_type) == PUBLISHED[ros_type]


def _dependencies(ros_type: str) -> tuple[str, dict[str, str]]:
    """The ``.msg`` text of ``ros_type``, and of each type it uses by name."""
    files = msg_files(ros_type)
    return files.pop(ros_type), files


@pytest.mark.parametrize(
    "ros_type", [types.ESTIMATE, types.POSE_STAMPED, types.ODOMETRY, types.CLOCK, types.STRING]
)
def test_every_type_a_run_uses_hashes_the_same_in_two_implementations(ros_type):
    main, deps = _dependencies(ros_type)
    assert compute_type_hash_from_msg(ros_type, main, deps) == types.type_hash(ros_type)


def test_our_message_is_the_shipped_msg_file_and_humble_keys_carry_no_hash():
    main, _ = _dependencies(types.ESTIMATE)
    shipped = (types.MSG_DIR / "Estimate.msg").read_text()
    fields = [ln.split("#")[0].split() for ln in shipped.splitlines() if ln.split("#")[0].strip()]
    assert [ln.split() for ln in main.strip().splitlines()] == fields
    assert types.type_hash(types.ESTIMATE, "humble") == types.NO_TYPE_HASH


@pytest.mark.parametrize("seed", range(20))
def test_qos_tokens_are_what_an_independent_implementation_encodes_and_reads(seed):
    rng = random.Random(seed)
    q = wire.Qos(
        depth=rng.randrange(1, 1000), reliable=rng.random() < 0.5, transient_local=rng.random() < 0.5
    )
    sdk = QosProfile(
        reliability=QosReliability.RELIABLE if q.reliable else QosReliability.BEST_EFFORT,
        durability=QosDurability.TRANSIENT_LOCAL if q.transient_local else QosDurability.VOLATILE,
        history_depth=q.depth,
    )
    assert q.token() == sdk.encode()
    assert QosProfile.decode(q.token()) == sdk


@pytest.mark.parametrize("seed", range(20))
def test_an_attachment_is_33_bytes_as_an_independent_implementation_packs_it(seed):
    rng = random.Random(seed)
    a = wire.Attachment(rng.randrange(1, 2**62), rng.randrange(0, 2**62), rng.randbytes(16))
    data = a.pack()
    assert len(data) == 33 == wire.ATTACHMENT_BYTES
    assert data == SdkAttachment(a.sequence, a.timestamp_ns, a.gid).to_bytes()
    assert wire.Attachment.unpack(data) == a
    with pytest.raises(ValueError, match="an attachment has 33 bytes"):
        wire.Attachment.unpack(data[: rng.randrange(0, 33)])
    with pytest.raises(ValueError, match="GID has 16 bytes"):
        wire.Attachment.unpack(data[:16] + bytes([rng.choice([0, 8, 15, 17, 255])]) + data[17:])


def test_a_gid_is_16_bytes_and_differs_between_publishers():
    tokens = {f"@ros2_lv/0/{z}/0/{e}/MP/%/%/n/%t/T/H/::,10:,:,:,," for z in ("a1", "b2") for e in range(50)}
    gids = {wire.gid(t) for t in tokens}
    assert len(gids) == len(tokens) and all(len(g) == wire.GID_BYTES for g in gids)


_LEGAL_TOKEN = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")


@pytest.mark.parametrize("seed", range(10))
def test_a_name_is_taken_exactly_when_every_token_follows_ros2s_rules(seed):
    rng = random.Random(seed)
    alphabet = "ab_Z09/-.%"
    for _ in range(300):
        name = "/" + "".join(rng.choice(alphabet) for _ in range(rng.randrange(0, 12)))
        tokens = name[1:].split("/")
        legal = name != "/" and all(_LEGAL_TOKEN.fullmatch(t) for t in tokens)
        if legal:
            assert check_topic(name) == name
        else:
            with pytest.raises(RosNameError):
                check_topic(name)
    with pytest.raises(RosNameError, match="does not start with a digit"):
        check_token("4")


@pytest.mark.parametrize("n", [1, 4, 32, 255])
def test_every_topic_of_a_run_is_a_legal_ros2_name_and_they_are_distinct(n):
    topics = RunTopics("/fleet_a")
    names = [topics.clock, topics.leader("pose"), topics.leader("odom"), topics.events()]
    names += [topics.follower(i, w) for i in range(1, n + 1) for w in ("pose", "odom")]
    names += [topics.edge(s, d) for s in range(n) for d in range(1, n + 1) if s != d][:2000]
    assert len(set(names)) == len(names)
    assert all(check_topic(x) == x for x in names)
    with pytest.raises(RosNameError):
        RunTopics("/swarm/4")


@settings(max_examples=300, deadline=None)
@given(st.floats(0.0, 2.0**31 - 1.0, allow_nan=False) | st.integers(0, 10**7).map(lambda k: k * 0.01))
def test_the_leaders_clock_bytes_are_rosbags_cdr_of_the_same_clock(t_s):
    """``clock_cdr`` packs by hand what the leader puts every tick: the CDR ``rosbags`` encodes for
    the same ``Clock``, over any time a run can reach (ticks of 10 ms among them)."""
    assert clock_cdr(t_s) == types.encode(Messages().clock(t_s), types.CLOCK)
    back = types.decode(clock_cdr(t_s), types.CLOCK).clock
    assert back.sec * 10**9 + back.nanosec == round(t_s * 1e9)


names_ = st.lists(
    st.from_regex(_LEGAL_TOKEN, fullmatch=True).filter(lambda t: len(t) < 12), min_size=1, max_size=3
)


@settings(max_examples=200, deadline=None)
@example(ns=["Xa"], node="X", topic=["Xray", "X_2"])  # (a key strips '/' alone, not what follows it)
@given(ns=st.one_of(st.just(["/"]), names_), node=st.from_regex(_LEGAL_TOKEN, fullmatch=True), topic=names_)
def test_a_namespaced_nodes_keys_and_tokens_carry_its_namespace_and_topic_as_design_md_writes_them(
    ns, node, topic
):
    """A key carries the topic without its leading '/' (its tokens as they are, ``X`` first among
    them); a token carries the namespace and the topic with each '/' as '%', the root namespace
    as a lone '%'; read back (``demangle``) they are the names given."""
    namespace = "/" if ns == ["/"] else "/" + "/".join(ns)
    full = "/" + "/".join(topic)
    h = types.type_hash(types.STRING)
    key = wire.data_key(0, full, types.STRING, h)
    assert key.split("/")[1:-2] == topic and key.split("/")[0] == "0"
    fields = wire.node_token(3, "ab12", 7, namespace, node).split("/")
    assert fields[:6] == ["@ros2_lv", "3", "ab12", "7", "7", "NN"] and fields[8] == node and len(fields) == 9
    assert wire.demangle(fields[7]) == ("" if namespace == "/" else namespace) and "/" not in fields[7]
    pub = wire.publisher_token(3, "ab12", 7, 9, namespace, node, full, types.STRING, h, wire.Qos()).split("/")
    assert pub[6:10] == [fields[6], fields[7], node, wire.mangle(full)] and wire.demangle(pub[9]) == full
    with pytest.raises(RosNameError, match=re.escape(f"topic {full + '/9'!r}: token '9'")):  # names both
        check_topic(full + "/9")


@pytest.mark.parametrize("known", [True, False])
def test_an_odometrys_body_rates_not_known_are_zeros_with_minus_one_on_their_covariance(known):
    """REP-105's twist in the body frame; rates NaN (a vehicle that does not report them): zeros,
    and -1 on the angular diagonal of the twist's covariance (row-major 6 x 6) says "no estimate"."""
    m = Messages()
    rates = [0.1, -0.2, 0.3] if known else [math.nan] * 3
    o = m.odometry(1.5, "follower_2", m.pose([1.0, 2.0, 3.0], None), [4.0, 5.0, 6.0], rates)
    a = o.twist.twist.angular
    assert [a.x, a.y, a.z] == (rates if known else [0.0, 0.0, 0.0])
    cov = np.asarray(o.twist.covariance).reshape(6, 6)
    assert np.array_equal(np.diag(cov), [0, 0, 0] + ([0, 0, 0] if known else [-1, -1, -1]))
    assert np.count_nonzero(cov) == (0 if known else 3) and not np.any(o.pose.covariance)
