"""zenoh's own authentication and access control hold every node to its keys.

A router built as ``run`` builds it (``bus.session.open_router`` with ``bus.access``'s rules for
paper.yaml) and client sessions that use only zenoh's public API: which sessions get in, and which
puts and subscriptions zenoh itself lets through. Every refusal is checked against a message that
the same session sends after it and that does arrive (so "nothing came" is not "too early").
"""

import os
import stat
import time

import pytest
import zenoh

from swarm_sitl.bus import keys as zenoh_keys
from swarm_sitl.bus.access import access_control, user, write_credentials
from swarm_sitl.bus.session import open_router
from swarm_sitl.rundir.layout import zenoh_users_path
from swarm_sitl.running.hub import free_tcp_port
from tests.zenoh_client import client_session

pytestmark = pytest.mark.unit
SWARM = "paper"


@pytest.fixture
def router(paper_cfg, tmp_path):
    passwords = write_credentials(paper_cfg.n_followers, zenoh_users_path(tmp_path))
    endpoint = f"tcp/127.0.0.1:{free_tcp_port()}"
    nodes = [paper_cfg.node_keys(n) for n in range(paper_cfg.n_followers + 1)]
    r = open_router([endpoint], str(zenoh_users_path(tmp_path)), access_control(paper_cfg.name, nodes))
    sessions: list[zenoh.Session] = []

    def node(n: int) -> zenoh.Session:
        sessions.append(client_session(endpoint, (user(n), passwords[n])))
        return sessions[-1]

    node.router = r  # type: ignore[attr-defined]
    yield endpoint, passwords, node, tmp_path
    for s in sessions:
        s.close()
    r.close()


class Inbox:
    def __init__(self, session: zenoh.Session, key: str):
        self.got: list[tuple[str, bytes]] = []
        self.sub = session.declare_subscriber(
            key, lambda s: self.got.append((str(s.key_expr), s.payload.to_bytes()))
        )

    def wait_for(self, payload: bytes, timeout_s: float = 5.0) -> None:
        end = time.monotonic() + timeout_s
        while not any(p == payload for _, p in self.got):
            assert time.monotonic() < end, f"{payload!r} never came: {self.got}"
            time.sleep(0.01)


def _put_until(session: zenoh.Session, key: str, payload: bytes, inbox: Inbox) -> None:
    """Put again until it arrives: a subscription takes a moment to reach the publisher."""
    end = time.monotonic() + 5.0
    while not any(p == payload for _, p in inbox.got):
        assert time.monotonic() < end, f"{key} never delivered"
        session.put(key, payload)
        time.sleep(0.05)


def test_the_dictionary_is_private_and_has_one_user_per_node(router, paper_cfg):
    _, passwords, _, run_dir = router
    path = zenoh_users_path(run_dir)
    assert stat.S_IMODE(os.stat(path).st_mode) == 0o600
    lines = path.read_text().splitlines()
    assert lines == [f"node_{n}:{passwords[n]}" for n in range(paper_cfg.n_followers + 1)]
    assert len(set(passwords.values())) == len(passwords) and all(len(p) == 32 for p in passwords.values())


def test_a_session_without_credentials_or_with_wrong_ones_is_refused(router):
    endpoint, passwords, _, _ = router
    for creds in (None, ("node_1", "0" * 32), ("node_9", passwords[1]), ("", "")):
        with pytest.raises(zenoh.ZError):
            client_session(endpoint, creds).close()


def test_a_node_publishes_only_on_its_out_edges_and_its_status(router):
    """Node 1 (out-edge 1->4) cannot put on 2->4, 0->4 or start: node 4's subscriptions never see
    them, while the put on its own edge that follows them arrives."""
    _, _, node, _ = router
    n1, n4 = node(1), node(4)
    # node 4 may not subscribe to a wildcard (a session of its own: a session hands what it gets
    # for one subscription to its every subscription that matches)...
    inbox = Inbox(node(4), f"swarm/{SWARM}/**")
    own = [Inbox(n4, zenoh_keys.edge(SWARM, s, 4)) for s in (1, 2)]  # ...but to its in-edges
    start = Inbox(n4, zenoh_keys.start(SWARM))
    _put_until(n1, zenoh_keys.edge(SWARM, 1, 4), b"warm-up", own[0])
    for key in (zenoh_keys.edge(SWARM, 2, 4), zenoh_keys.edge(SWARM, 0, 4), zenoh_keys.start(SWARM)):
        n1.put(key, b"forged")
    n1.put(zenoh_keys.edge(SWARM, 1, 4), b"real")
    own[0].wait_for(b"real")
    time.sleep(0.2)
    assert own[1].got == [] and start.got == [] and inbox.got == []


def test_a_node_subscribes_only_to_its_in_edges_start_and_what_it_watches(router):
    """The leader puts on 0->1 and 0->2; node 1 reads 0->1, and its subscriptions to 0->2 and to a
    wildcard stay empty while node 2's own one gets the message."""
    _, _, node, _ = router
    n0, n1, n2 = node(0), node(1), node(2)
    mine = Inbox(n1, zenoh_keys.edge(SWARM, 0, 1))
    theirs = Inbox(n1, zenoh_keys.edge(SWARM, 0, 2))
    wild = Inbox(node(1), f"swarm/{SWARM}/edge/*/*")  # a session of its own (above)
    witness = Inbox(n2, zenoh_keys.edge(SWARM, 0, 2))
    _put_until(n0, zenoh_keys.edge(SWARM, 0, 1), b"warm-up", mine)
    _put_until(n0, zenoh_keys.edge(SWARM, 0, 2), b"to node 2", witness)
    n0.put(zenoh_keys.edge(SWARM, 0, 1), b"to node 1")
    mine.wait_for(b"to node 1")
    time.sleep(0.2)
    assert theirs.got == [] and wild.got == []


def test_the_start_signal_status_and_liveliness_reach_the_nodes_that_use_them(router, paper_cfg):
    """What the rules must let through: the router's own start to every node, a follower's status
    to the leader (it paces on its out-neighbours), and an in-neighbour's liveliness, not the
    liveliness one node declares for another."""
    _, _, node, _ = router
    n0, n1, n4 = node(0), node(1), node(4)
    assert paper_cfg.node_keys(0).watch_status == [1, 2, 3] and paper_cfg.node_keys(4).in_sources == [1, 2]
    start = Inbox(n1, zenoh_keys.start(SWARM))
    _put_until(node.router, zenoh_keys.start(SWARM), b"epoch", start)
    status = Inbox(n0, zenoh_keys.status(SWARM, 1))
    _put_until(n1, zenoh_keys.status(SWARM, 1), b"status", status)
    alive: list[str] = []
    subs = [
        n4.liveliness().declare_subscriber(
            zenoh_keys.alive(SWARM, s), lambda s: alive.append(str(s.key_expr)), history=True
        )
        for s in (1, 2)
    ]
    forged = n1.liveliness().declare_token(zenoh_keys.alive(SWARM, 2))
    token = n1.liveliness().declare_token(zenoh_keys.alive(SWARM, 1))
    end = time.monotonic() + 5
    while not alive and time.monotonic() < end:
        time.sleep(0.01)
    time.sleep(0.2)
    assert alive == [zenoh_keys.alive(SWARM, 1)]
    for thing in (forged, token, *subs):
        thing.undeclare()
