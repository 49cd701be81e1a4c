"""Who may use which zenoh key: each node's keys from the graph, its credentials, and the router's
access-control rules that hold it to them.

In ``zenoh.mode: router`` (the default) the supervisor's session is the zenoh router of the run
and every node is a client of it. The router authenticates each session by user name and password
(zenoh's ``usrpwd``: a session without them, or with wrong ones, is refused at connect) and its
access control (default deny) lets node ``i`` (user ``node_<i>``; 0 is the leader):

- put on its out-edges ``edge/<i>/<d>``, on its ``status/<i>`` and ``state/<i>``; declare its
  ``alive/<i>``;
- subscribe to its in-edges ``edge/<s>/<i>``, to ``start`` and ``hold``, and to the status and
  liveliness of the nodes it watches (the leader paces itself on its out-neighbours; a fault plan's watchers);

A run with ``ros2:`` on admits ROS 2 nodes too, as user ``ros2`` (``ROS2_USER``; its password in
the run directory, ``rundir.layout.zenoh_ros2_password_path``): read-only on the ROS 2 domain's
keys (``ros2_rules``: subscribe to ``<domain>/**``, declare and follow liveliness tokens under
``@ros2_lv/<domain>/**``), and nothing of ``swarm/**``, which it can neither read nor write. The
leader puts ``/clock`` there (``ros2_clock_rules``), and a follower a ROS 2 node flies meets it
on its own control topics (``ros2_controller_rules``).

and nothing else: a put on another node's edge or on ``start``, a subscription to another node's
in-edge or to a wildcard, is dropped by zenoh itself. Only the supervisor's own session, inside
the router, publishes ``start`` and ``hold``. ``NodeKeys`` is also what the
node's bus declares (``node_bus``), so the rules and the bus cannot disagree.
"""

import os
import secrets
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from sim_vehicles.runtime.secret_file import write_secret
from swarm_sitl.bus import keys as zenoh_keys
from swarm_sitl.laws.graph import Graph

USER_ENV = "SWARM_SITL_ZENOH_USER"  #: the user name a node's session authenticates with
PASSWORD_ENV = "SWARM_SITL_ZENOH_PASSWORD"  #: and its password (environment: not on a command line)


@dataclass(frozen=True)
class NodeKeys:
    """The zenoh keys node ``node`` uses, by the other nodes they concern."""

    node: int
    in_sources: list[int]  #: it subscribes to their estimates for it
    out_dests: list[int]  #: it publishes its estimate for them
    watch_status: list[int]  #: followers whose status it follows
    watch_alive: list[int]  #: nodes besides ``in_sources`` whose liveliness it follows


def node_keys(graph: Graph, node: int, watch: bool) -> NodeKeys:
    """Node ``node``'s keys on ``graph``. ``watch`` (a fault plan that kills processes): a node
    follows its out-neighbours' liveliness and status too (lockstep: a restarted one resumes where
    the slowest reader is)."""
    outs = list(graph.out_neighbours(node))
    watched = sorted(set(outs)) if watch else []
    if node == 0:
        return NodeKeys(0, [], outs, outs, watched)
    return NodeKeys(node, [s for s, _ in graph.in_neighbours(node)], outs, watched, watched)


def user(node: int) -> str:
    return f"node_{node}"


def process_node(process: str) -> int | None:
    """The node a supervised process is (``leader`` 0, ``controller_<i>`` i), or None."""
    if process == "leader":
        return 0
    if process.startswith("controller_"):
        return int(process.removeprefix("controller_"))
    return None


def credentials_env(process: str, passwords: dict[int, str]) -> dict[str, str]:
    """The environment that gives ``process`` its node's zenoh credentials (none to a vehicle)."""
    node = process_node(process)
    return {} if node is None else {USER_ENV: user(node), PASSWORD_ENV: passwords[node]}


def credentials_from_env() -> tuple[str, str] | None:
    """(user, password) from ``USER_ENV``/``PASSWORD_ENV``, if both are set."""
    u, pw = os.environ.get(USER_ENV), os.environ.get(PASSWORD_ENV)
    return (u, pw) if u and pw else None


def _rules(swarm: str, k: NodeKeys) -> dict[str, list[str]]:
    """Ingress rights of a node: key expressions by message kind."""
    puts = [zenoh_keys.edge(swarm, k.node, d) for d in k.out_dests]
    if k.node > 0:
        puts += [zenoh_keys.status(swarm, k.node), zenoh_keys.state(swarm, k.node)]
    subs = [zenoh_keys.edge(swarm, s, k.node) for s in k.in_sources]
    subs += [zenoh_keys.status(swarm, f) for f in k.watch_status]
    subs += [zenoh_keys.start(swarm), zenoh_keys.hold(swarm)]
    alive = [zenoh_keys.alive(swarm, n) for n in dict.fromkeys([*k.in_sources, *k.watch_alive])]
    rules = {
        "put": puts,
        "declare_subscriber": subs,
        "liveliness_token": [zenoh_keys.alive(swarm, k.node)],
        "declare_liveliness_subscriber": alive,
        "liveliness_query": alive,
    }
    return {kind: keys for kind, keys in rules.items() if keys}


ROS2_USER = "ros2"  #: the user ROS 2 nodes join a run's router as (a run with ``ros2:`` on)


def ros2_rules(domain_id: int) -> list[dict[str, Any]]:
    """What user ``ROS2_USER`` may do: read the ROS 2 topics of ``domain_id`` and take part in
    its graph's discovery (its own nodes' liveliness tokens), and nothing else."""
    data, graph = f"{domain_id}/**", f"@ros2_lv/{domain_id}/**"
    return [
        {
            "id": "ros2_egress",
            "messages": ["put", "liveliness_token", "declare_liveliness_subscriber", "reply"],
            "flows": ["egress"],
            "permission": "allow",
            "key_exprs": [data, graph],
        },
        {
            "id": "ros2_ingress",
            "messages": ["declare_subscriber"],
            "flows": ["ingress"],
            "permission": "allow",
            "key_exprs": [data],
        },
        {
            "id": "ros2_graph",
            "messages": ["liveliness_token", "declare_liveliness_subscriber", "liveliness_query"],
            "flows": ["ingress"],
            "permission": "allow",
            "key_exprs": [graph],
        },
    ]


def _allow(rule_id: str, messages: list[str], flow: str, keys: list[str]) -> dict[str, Any]:
    return {"id": rule_id, "messages": messages, "flows": [flow], "permission": "allow", "key_exprs": keys}


def ros2_controller_user(follower: int) -> str:
    """The user the ROS 2 node flying follower ``follower`` joins as (``ros2.controllers``)."""
    return f"ros2_controller_{follower}"


def _ros2_grants(
    who: str, domain_id: int, puts: list[str], reads: list[str], follows_graph: bool = True
) -> list[dict[str, Any]]:
    """What ``who`` may do on a ROS 2 domain's keys: put on ``puts``, subscribe to ``reads``,
    declare its liveliness tokens and, ``follows_graph``, follow the graph's; and what the router
    forwards to it: what it reads, the domain's subscriptions (without them its publishers would
    send nothing; the whole domain's, since a reader's ``<domain>/**`` is not within one
    topic's keys), and, ``follows_graph``, the graph."""
    graph = f"@ros2_lv/{domain_id}/**"
    discovery = ["liveliness_token", "declare_liveliness_subscriber", "liveliness_query"]
    seen = ["liveliness_token", "declare_liveliness_subscriber", "reply"]
    granted = [
        ("put", ["put"], "ingress", puts),
        ("sub", ["declare_subscriber"], "ingress", reads),
        ("graph", discovery if follows_graph else ["liveliness_token"], "ingress", [graph]),
        ("data", ["put", "reply"], "egress", reads),
        ("interest", ["declare_subscriber"], "egress", [f"{domain_id}/**"] if puts else []),
        ("seen", seen, "egress", [graph] if follows_graph else []),
    ]
    return [_allow(f"{who}_ros2_{name}", m, flow, keys) for name, m, flow, keys in granted if keys]


def ros2_controller_rules(
    domain_id: int, follower: int, control: str, sources: list[int]
) -> dict[str, list[dict[str, Any]]]:
    """What the bridge of follower ``follower`` (its controller process, ``node_<i>``) and the
    ROS 2 node flying it may do on the domain's keys under ``control`` (the follower's
    ``<ns>/follower_<i>/control`` without its leading ``/``): the bridge puts ``odom`` and
    ``from_<s>`` for each of its in-neighbours ``sources`` and reads ``setpoint`` and
    ``message``; the node the other way round, and only there. Both take part in the graph's
    discovery."""
    base = f"{domain_id}/{control}"
    ours = [f"{base}/odom/**", *(f"{base}/from_{s}/**" for s in sources)]
    theirs = [f"{base}/setpoint/**", f"{base}/message/**"]
    node, user_ = user(follower), ros2_controller_user(follower)
    return {
        node: _ros2_grants(node, domain_id, ours, theirs),
        user_: _ros2_grants(user_, domain_id, theirs, ours),
    }


def ros2_clock_rules(domain_id: int) -> dict[str, list[dict[str, Any]]]:
    """The leader (``node_0``) puts ``/clock`` (``nodes.ros2_clock``) and declares its node's and
    publisher's tokens, and sees nothing of ROS 2: no topic, no other node of the graph."""
    return {user(0): _ros2_grants(user(0), domain_id, [f"{domain_id}/clock/**"], [], follows_graph=False)}


def access_control(
    swarm: str,
    nodes: list[NodeKeys],
    ros2_domain: int | None = None,
    ros2_controls: dict[int, str] | None = None,
) -> dict[str, Any]:
    """The router's ``access_control`` section for swarm ``swarm`` of ``nodes`` (the leader's keys
    and each follower's): default deny; each node's ingress limited to its keys (``_rules``);
    egress (what the router forwards to a node) to the swarm's keys, of which a node receives only
    what it subscribed to. ``ros2_domain``: ROS 2 nodes admitted as ``ROS2_USER`` on that
    domain, read-only (``ros2_rules``); ``ros2_controls``: per follower flown by a ROS 2 node, its
    control topics' prefix (``ros2_controller_rules``)."""
    rules: list[dict[str, Any]] = [
        {
            "id": "egress",
            "messages": [
                "put",
                "declare_subscriber",
                "liveliness_token",
                "declare_liveliness_subscriber",
                "liveliness_query",
                "reply",
            ],
            "flows": ["egress"],
            "permission": "allow",
            "key_exprs": [f"swarm/{swarm}/**"],
        }
    ]
    subjects: list[dict[str, Any]] = []
    policies: list[dict[str, Any]] = []
    for k in nodes:
        node = k.node
        ids = []
        for kind, keys in _rules(swarm, k).items():
            ids.append(f"{user(node)}_{kind}")
            rules.append(
                {
                    "id": ids[-1],
                    "messages": [kind],
                    "flows": ["ingress"],
                    "permission": "allow",
                    "key_exprs": keys,
                }
            )
        subjects.append({"id": user(node), "usernames": [user(node)]})
        policies.append({"rules": ["egress", *ids], "subjects": [user(node)]})
    if ros2_domain is not None:
        extra = ros2_rules(ros2_domain)
        rules += extra
        subjects.append({"id": ROS2_USER, "usernames": [ROS2_USER]})
        policies.append({"rules": [r["id"] for r in extra], "subjects": [ROS2_USER]})
        sources = {k.node: k.in_sources for k in nodes}
        grantings = [ros2_clock_rules(ros2_domain)]
        for follower, control in (ros2_controls or {}).items():
            grantings.append(ros2_controller_rules(ros2_domain, follower, control, sources[follower]))
        for granting in grantings:
            for who, granted in granting.items():
                rules += granted
                ids = [r["id"] for r in granted]
                mine = [p for p in policies if p["subjects"] == [who]]
                if mine:  # (one policy per subject: a second one for it is not read)
                    mine[0]["rules"] += ids
                else:
                    subjects.append({"id": who, "usernames": [who]})
                    policies.append({"rules": ids, "subjects": [who]})
    return {
        "enabled": True,
        "default_permission": "deny",
        "rules": rules,
        "subjects": subjects,
        "policies": policies,
    }


def write_credentials(
    n_followers: int,
    path: Path,
    ros2_password_path: Path | None = None,
    ros2_controllers: dict[int, Path] | None = None,
) -> dict[int, str]:
    """A fresh random password for each node of a swarm of ``n_followers``, and the router's
    dictionary of them at ``path`` (``user:password`` lines, readable by this user only).
    ``ros2_password_path``: ``ROS2_USER`` too, its password alone in that file (for the ROS 2
    user's one line, ``docs/ros2.md``)."""
    passwords = {n: secrets.token_hex(16) for n in range(n_followers + 1)}
    lines = [f"{user(n)}:{pw}\n" for n, pw in passwords.items()]
    if ros2_password_path is not None:
        ros2 = secrets.token_hex(16)
        write_secret(ros2_password_path, ros2 + "\n")
        lines.append(f"{ROS2_USER}:{ros2}\n")
    for follower, password_path in (ros2_controllers or {}).items():  # each alone in its file
        pw = secrets.token_hex(16)
        write_secret(password_path, pw + "\n")
        lines.append(f"{ros2_controller_user(follower)}:{pw}\n")
    write_secret(path, "".join(lines))
    return passwords
