"""The router's access rules, node by node, against the graph they come from: every node of a
generated 8-follower swarm, with and without kills in its plan (which add the watcher rules); and
the whole section, with ROS 2 and its controllers, as a document zenoh's router takes.

Each node's grants are derived here from the config's edge list alone, not from ``NodeKeys``, and
must be exactly the rules: a grant that widens (another follower's status, a wildcard, another
node's liveliness) would let a node forge what the leader's pacing and the supervisor trust."""

import pytest
import yaml

from swarm_sitl.bus import keys as zk
from swarm_sitl.bus.access import ROS2_USER, access_control, ros2_controller_user, user
from swarm_sitl.config.generator import GRAPHS, generate
from swarm_sitl.config.load import parse_config
from swarm_sitl.nodes.ros2_controller import control_topic

pytestmark = pytest.mark.unit
N = 8


def _swarm(graph: str, kills: bool):
    raw = yaml.safe_load(generate(N, graph, "grid", "helix", seed=4, duration_s=20.0))
    if kills:
        raw["faults"] = {
            "seed": 1,
            "plan": [{"controller": 3, "kill": True, "from_s": 5.0, "restart_after_s": 1.0}],
        }
    return parse_config(raw)


def _expected(cfg, node: int, watch: bool) -> dict[str, set[str]]:
    """What node ``node`` may do, from the edge list: publish its out-edges (and a follower its own
    status and state), subscribe to its in-edges, start and hold; the leader follows its
    out-neighbours' status; with kills in the plan every node follows its out-neighbours' status
    and liveliness."""
    s = cfg.name
    edges = [(e.src, e.dst) for e in cfg.build_graph().edges]
    ins = sorted({a for a, b in edges if b == node})
    outs = sorted({b for a, b in edges if a == node})
    watched = outs if (watch or node == 0) else []
    alive_of = set(ins) | (set(outs) if watch else set())
    own = {zk.status(s, node), zk.state(s, node)} if node > 0 else set()
    puts = {zk.edge(s, node, d) for d in outs} | own
    subs = {zk.edge(s, a, node) for a in ins} | {zk.status(s, f) for f in watched}
    subs |= {zk.start(s), zk.hold(s)}
    alive = {zk.alive(s, a) for a in alive_of}
    out = {
        "put": puts,
        "declare_subscriber": subs,
        "liveliness_token": {zk.alive(s, node)},
        "declare_liveliness_subscriber": alive,
        "liveliness_query": alive,
    }
    return {k: v for k, v in out.items() if v}


@pytest.mark.parametrize("kills", [False, True])
@pytest.mark.parametrize("graph", GRAPHS)
def test_every_nodes_grants_are_exactly_what_its_edges_and_the_plan_need(graph, kills):
    cfg = _swarm(graph, kills)
    nodes = [cfg.node_keys(n) for n in range(N + 1)]
    ac = access_control(cfg.name, nodes)
    assert ac["enabled"] and ac["default_permission"] == "deny"
    rules = {r["id"]: r for r in ac["rules"]}
    # egress (what the router forwards) is the swarm's keys; ingress is never a wildcard
    assert rules["egress"]["flows"] == ["egress"] and rules["egress"]["key_exprs"] == [f"swarm/{cfg.name}/**"]
    assert rules["egress"]["permission"] == "allow"
    # what the router forwards to a node: every kind it may have subscribed to, and the replies
    assert set(rules["egress"]["messages"]) == {
        "put",
        "declare_subscriber",
        "liveliness_token",
        "declare_liveliness_subscriber",
        "liveliness_query",
        "reply",
    }
    assert set(ac) == {"enabled", "default_permission", "rules", "subjects", "policies"}
    assert [s["id"] for s in ac["subjects"]] == [user(n) for n in range(N + 1)]
    assert all(s["usernames"] == [s["id"]] for s in ac["subjects"])
    assert all(p["rules"][0] == "egress" for p in ac["policies"])
    ids = [r["id"] for r in ac["rules"]]
    assert len(ids) == len(set(ids))  # one rule per node and kind, named after both
    for r in ac["rules"]:
        if r["id"] != "egress":
            assert r["flows"] == ["ingress"] and r["permission"] == "allow"
            assert not any("*" in k for k in r["key_exprs"]), r
    assert len(ac["subjects"]) == N + 1 and len(ac["policies"]) == N + 1
    for node in range(N + 1):
        (policy,) = [p for p in ac["policies"] if p["subjects"] == [user(node)]]
        granted: dict[str, set[str]] = {}
        for rid in policy["rules"]:
            if rid == "egress":
                continue
            (kind,) = rules[rid]["messages"]
            granted.setdefault(kind, set()).update(rules[rid]["key_exprs"])
        assert granted == _expected(cfg, node, kills), (graph, kills, node)


@pytest.mark.parametrize("ros2", [None, 0, 7])
def test_a_followers_status_and_state_are_granted_to_it_alone_and_ros2_reads_only_its_domain(ros2):
    cfg = _swarm("layered", kills=True)
    ac = access_control(cfg.name, [cfg.node_keys(n) for n in range(N + 1)], ros2)
    for f in range(1, N + 1):
        for key in (zk.status(cfg.name, f), zk.state(cfg.name, f)):
            putters = [r["id"] for r in ac["rules"] if "put" in r["messages"] and key in r["key_exprs"]]
            assert putters == [f"{user(f)}_put"], (f, putters)
    ros2_rules = {
        r["id"]
        for p in ac["policies"]
        if "ros2" in p["subjects"]
        for r in ac["rules"]
        if r["id"] in p["rules"]
    }

    def outside(who: str) -> list[dict]:  # its rules on keys not of the swarm's
        mine = {r for p in ac["policies"] if who in p["subjects"] for r in p["rules"]}
        return [
            r
            for r in ac["rules"]
            if r["id"] in mine and not all(k.startswith("swarm/") for k in r["key_exprs"])
        ]

    assert all(outside(user(f)) == [] for f in range(1, N + 1))  # (none flown by a ROS 2 node here)
    leader = outside(user(0))
    clock = [
        k for r in leader if "put" in r["messages"] and r["flows"] == ["ingress"] for k in r["key_exprs"]
    ]
    assert clock == ([] if ros2 is None else [f"{ros2}/clock/**"])  # the leader puts /clock, and only it
    # and sees nothing of ROS 2: no data, no reply, no other node's token (only who subscribes)
    assert {m for r in leader if r["flows"] == ["egress"] for m in r["messages"]} <= {"declare_subscriber"}
    assert {m for r in leader for m in r["messages"]} <= {"put", "liveliness_token", "declare_subscriber"}
    if ros2 is None:  # (a node's user sees nothing of ROS 2)
        assert not ros2_rules and all("ros2" not in s["usernames"] for s in ac["subjects"])
        return
    for r in ac["rules"]:
        if r["id"] in ros2_rules:  # never a key of the swarm's, and only its domain's
            assert all(k.startswith((f"{ros2}/", f"@ros2_lv/{ros2}/")) for k in r["key_exprs"]), r
            assert r["flows"] == ["egress"] or "put" not in r["messages"], r  # it never writes


#: zenoh 1.x's access control vocabulary (its DEFAULT_CONFIG.json5's ``access_control`` section):
#: what a rule may name, and the fields of each part of the section
ZENOH_MESSAGES = {
    "put",
    "delete",
    "declare_subscriber",
    "query",
    "declare_queryable",
    "reply",
    "liveliness_token",
    "declare_liveliness_subscriber",
    "liveliness_query",
}


@pytest.mark.parametrize("graph", GRAPHS)
@pytest.mark.parametrize(("ros2", "flown"), [(None, ()), (0, ()), (7, (1,)), (0, (2, 5, 8))])
def test_the_section_is_one_zenohs_router_takes_with_every_rule_and_subject_in_a_policy(graph, ros2, flown):
    """Whatever the graph, ROS 2 and the followers ROS 2 controllers fly: every word is one of
    zenoh's (its messages, ``ingress``/``egress``, ``allow``/``deny``), every rule and subject has
    its fields and a unique id, every policy names rules and subjects that exist, and every
    subject is in exactly one policy (zenoh reads one policy per subject)."""
    cfg = _swarm(graph, kills=True)
    controls = {i: control_topic("swarm", i, "").strip("/") for i in flown}
    ac = access_control(cfg.name, [cfg.node_keys(n) for n in range(N + 1)], ros2, controls)
    assert ac["enabled"] is True and ac["default_permission"] in ("allow", "deny")
    rule_ids = [r["id"] for r in ac["rules"]]
    assert len(set(rule_ids)) == len(rule_ids)
    for r in ac["rules"]:
        assert set(r) == {"id", "messages", "flows", "permission", "key_exprs"}, r
        assert r["messages"] and set(r["messages"]) <= ZENOH_MESSAGES, r
        assert r["flows"] and set(r["flows"]) <= {"ingress", "egress"}, r
        assert r["permission"] in ("allow", "deny") and isinstance(r["id"], str) and r["id"], r
        assert all(isinstance(k, str) and k for k in r["key_exprs"]), r
    subject_ids = []
    for s in ac["subjects"]:
        assert set(s) == {"id", "usernames"} and s["usernames"], s
        assert all(isinstance(u, str) and u for u in s["usernames"]), s
        subject_ids.append(s["id"])
    assert len(set(subject_ids)) == len(subject_ids)
    in_policies = [who for p in ac["policies"] for who in p["subjects"]]
    assert sorted(in_policies) == sorted(subject_ids)  # each subject in exactly one policy
    for p in ac["policies"]:
        assert p["rules"] and set(p["rules"]) <= set(rule_ids), p
    expected = {user(n) for n in range(N + 1)} | ({ROS2_USER} if ros2 is not None else set())
    expected |= {ros2_controller_user(i) for i in flown}
    assert set(subject_ids) >= expected


def _granted(ac: dict, who: str, message: str, flow: str) -> set[str]:
    """The keys subject ``who`` is allowed ``message`` on in ``flow``, read from its policy."""
    mine = {r for p in ac["policies"] if who in p["subjects"] for r in p["rules"]}
    return {
        k
        for r in ac["rules"]
        if r["id"] in mine and message in r["messages"] and flow in r["flows"]
        for k in r["key_exprs"]
    }


@pytest.mark.parametrize("graph", GRAPHS)
@pytest.mark.parametrize(("ros2", "flown"), [(0, (1,)), (7, (2, 5, 8))])
def test_a_flown_followers_bridge_and_ros2_node_each_put_what_the_other_reads_and_nothing_else(
    graph, ros2, flown
):
    """Follower i flown by a ROS 2 node: its bridge (``node_i``) puts ``odom`` and ``from_<s>`` for
    each in-neighbour s of the graph (derived here from the edge list) and reads ``setpoint`` and
    ``message``; the node (``ros2_controller_i``) the other way round; each is forwarded what it
    reads and neither puts on any other ROS 2 key. The leader puts ``/clock`` and reads nothing."""
    cfg = _swarm(graph, kills=False)
    ns = "swarm"
    controls = {i: control_topic(ns, i, "").strip("/") for i in flown}
    ac = access_control(cfg.name, [cfg.node_keys(n) for n in range(N + 1)], ros2, controls)
    edges = [(e.src, e.dst) for e in cfg.build_graph().edges]

    def keys(i: int, *whats: str) -> set[str]:
        return {f"{ros2}/{control_topic(ns, i, w).strip('/')}/**" for w in whats}

    def ros2_only(ks: set[str]) -> set[str]:
        return {k for k in ks if not k.startswith(("swarm/", "@ros2_lv/"))}

    for i in flown:
        bridge, node = user(i), ros2_controller_user(i)
        published = keys(i, "odom", *(f"from_{a}" for a, b in edges if b == i))
        commanded = keys(i, "setpoint", "message")
        for who, puts, reads in ((bridge, published, commanded), (node, commanded, published)):
            assert ros2_only(_granted(ac, who, "put", "ingress")) == puts, (who, graph)
            assert ros2_only(_granted(ac, who, "declare_subscriber", "ingress")) == reads, (who, graph)
            assert ros2_only(_granted(ac, who, "put", "egress")) >= reads, (who, graph)
    leader = user(0)
    assert ros2_only(_granted(ac, leader, "put", "ingress")) == {f"{ros2}/clock/**"}
    assert ros2_only(_granted(ac, leader, "declare_subscriber", "ingress")) == set()
