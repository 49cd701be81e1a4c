"""Zenoh sessions of a swarm: how a node joins the bus (``ZenohSection``, the config's ``zenoh:``
section), the run's router with access control, a plain router for several hosts, and the
supervisor's start signal. What crosses the bus, and whose it is, is ``node_bus``, ``keys``,
``codec`` and ``access``.
"""

import contextlib
import json
import os
import re
from collections.abc import Iterable, Iterator
from typing import Any, Literal

import zenoh
from pydantic import BaseModel, ConfigDict

from swarm_sitl.bus import keys as zenoh_keys
from swarm_sitl.bus.codec import encode_hold, encode_start


class ZenohSection(BaseModel):
    """How each process joins the zenoh bus; everything stays on loopback unless configured.

    - ``router`` (default): the supervisor's session is the run's zenoh router, on ``listen`` (the
      first endpoint is the nodes'; ``tcp/127.0.0.1:0``: a free port); every node is a client of
      it that authenticates with its own user and password, and the router's access control lets
      each use only its own keys (``bus.access``);
    - ``peer``: no authentication, no access control: the nodes are peers that listen on
      ``listen``, meet at the supervisor's session and connect to each other directly;
    - ``client``: the supervisor and every node are clients of the router(s) in ``connect`` (a
      zenohd of your own: its authentication and access control are its config; a node gives
      the user and password in ``SWARM_SITL_ZENOH_USER``/``SWARM_SITL_ZENOH_PASSWORD`` if set).
    """

    model_config = ConfigDict(extra="forbid", frozen=True)

    mode: Literal["router", "peer", "client"] = "router"  #: who routes the bus (above)
    #: zenoh endpoints to listen on: the router's (``router``) or each peer's (``peer``)
    listen: list[str] = ["tcp/127.0.0.1:0"]
    connect: list[str] = []  #: zenoh endpoints every session connects to (a router, other peers)
    multicast_scouting: bool = False  #: find peers by multicast (off: nothing leaves loopback unasked)


def zenoh_config(
    spec: ZenohSection, extra_connect: Iterable[str] = (), credentials: tuple[str, str] | None = None
) -> zenoh.Config:
    """A node's session: a client of the run's router (``router``, ``client``) or a peer, with
    ``credentials`` (user, password) to authenticate with if given."""
    c = zenoh.Config()
    c.insert_json5("mode", json.dumps("peer" if spec.mode == "peer" else "client"))
    if spec.mode == "peer":
        c.insert_json5("listen/endpoints", json.dumps(list(spec.listen)))
    c.insert_json5("connect/endpoints", json.dumps([*spec.connect, *extra_connect]))
    c.insert_json5("scouting/multicast/enabled", json.dumps(spec.multicast_scouting))
    if credentials is not None:
        c.insert_json5(
            "transport/auth/usrpwd", json.dumps({"user": credentials[0], "password": credentials[1]})
        )
    return c


def open_session(
    spec: ZenohSection, extra_connect: Iterable[str] = (), credentials: tuple[str, str] | None = None
) -> zenoh.Session:
    return zenoh.open(zenoh_config(spec, extra_connect, credentials))


RUNTIME_ENV = "ZENOH_RUNTIME"  #: the variable zenoh reads its threads from
#: zenoh's runtime (``ZENOH_RUNTIME``, RON) for a process whose session routes the swarm: one worker
#: thread that receives, routes and sends. zenoh's default gives receiving (two threads), sending,
#: accepting, its network tasks and the application pools of their own, so each routed estimate
#: crosses from thread to thread, a wake-up at each. Measured (``docs/performance.md``): 10-14 % less
#: wall time and 7-11 % less CPU for a lockstep run; the nodes' sessions were slower with it and
#: keep zenoh's default.
ROUTER_RUNTIME = (
    "(app: (worker_threads: 1), rx: (handover: app), tx: (handover: app), "
    "acc: (handover: app), net: (handover: app))"
)


@contextlib.contextmanager
def router_runtime() -> Iterator[None]:
    """Open the process's first zenoh session inside this to give it ``ROUTER_RUNTIME``.

    zenoh reads ``ZENOH_RUNTIME`` once per process, when its first session starts: a process that
    opened one before keeps the runtime it has, and a runtime the user set is left alone. The
    variable is taken back on the way out, so the processes started afterwards keep zenoh's
    defaults."""
    if RUNTIME_ENV in os.environ:
        yield
        return
    os.environ[RUNTIME_ENV] = ROUTER_RUNTIME
    try:
        yield
    finally:
        os.environ.pop(RUNTIME_ENV, None)


def _router_config(listen: list[str]) -> zenoh.Config:
    """A router on ``listen``, found by nobody's multicast, that opens at once: zenoh's
    ``scouting/delay`` (500 ms by default) holds a session's open while it scouts for peers, and
    a router that is only listened to has none to find (it was half a second of every run's
    start)."""
    c = zenoh.Config()
    c.insert_json5("mode", json.dumps("router"))
    c.insert_json5("listen/endpoints", json.dumps(listen))
    c.insert_json5("scouting/multicast/enabled", "false")
    c.insert_json5("scouting/delay", "0")
    return c


def open_router(listen: list[str], users_file: str, access_control: dict[str, Any]) -> zenoh.Session:
    """The run's router (``zenoh.mode: router``): it authenticates every session against
    ``users_file`` (``user:password`` lines) and applies ``access_control`` to what they send and
    receive (``access``). Its own puts and subscriptions are local, not subject to it."""
    c = _router_config(listen)
    c.insert_json5("transport/auth/usrpwd", json.dumps({"dictionary_file": users_file}))
    c.insert_json5("access_control", json.dumps(access_control))
    return zenoh.open(c)


def open_plain_router(listen: list[str], users_file: str | None = None) -> zenoh.Session:
    """A router for a swarm over several hosts (``swarm-sitl router``): no access control, and
    authentication against ``users_file`` if given (``user:password`` lines)."""
    c = _router_config(listen)
    if users_file:
        c.insert_json5("transport/auth/usrpwd", json.dumps({"dictionary_file": users_file}))
    return zenoh.open(c)


def error_line(e: Exception) -> str:
    """The first line of a zenoh error (they carry the Rust source location after it)."""
    text = str(e).strip()
    if not text:
        return type(e).__name__
    return re.sub(r"\s+at\s+/\S+:\d+\.?$", "", text.splitlines()[0])  # not zenoh's source location


def publish_start(session: zenoh.Session, swarm: str, epoch_unix_s: float) -> None:
    session.put(zenoh_keys.start(swarm), encode_start(epoch_unix_s))


def publish_hold(session: zenoh.Session, swarm: str, tick: int) -> None:
    """Lockstep: the last tick a node may finish before it waits (``bus.hold``)."""
    session.put(zenoh_keys.hold(swarm), encode_hold(tick))
