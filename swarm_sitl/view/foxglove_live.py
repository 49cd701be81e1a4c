"""A live run to Foxglove over its WebSocket protocol: ``run --foxglove [PORT]``.

The same stream as the page's (``live.LiveFeed``): each frame the feed makes, and each event it
reads, is logged here too, on the topics and schemas of the MCAP export where they carry the
same thing (``rundir.mcap_export``), so a Foxglove layout made on a finished run's file reads a
live run:

- ``/leader/pose``, ``/follower_<i>/pose``: ``foxglove.PoseInFrame`` (frame ``world``, ENU): the
  leader's reference, each follower's position as its status gives it, at its status's tick (a
  status carries no attitude: the identity, where the export has the vehicle's own);
- ``/follower_<i>/formation``: ``swarm_sitl.Formation``: its formation error [m] (null while it
  is down), and whether it is down or in failsafe;
- ``/edges``: ``swarm_sitl.EdgeAges``: each edge's age (``live``: how long its sender has been
  silent on the bus at its receiver's tick) [s];
- ``/events``: ``swarm_sitl.Event``, as the export's.

Log time: simulated time from 0, as in the export: the frame's, and a follower's own status's tick
for its pose and formation error (a lockstep run's followers report from different ticks).
Foxglove's SDK (``foxglove-sdk``, Foxglove's own: a native extension) serves the protocol from
threads of its own and drops what a slow client cannot take: logging here never waits for a client.
Nothing is logged to a channel no client has subscribed to. Each stream has its own SDK context, so
two runs in one process (tests) do not share channels.
"""

import json
import math
from typing import Any

from swarm_sitl.config.schema import SwarmConfig
from swarm_sitl.rundir.mcap_export import EVENT, POSE_IN_FRAME, pose_message, timestamp_ns
from swarm_sitl.view.frames import DOWN, FAILSAFE, Frame

DEFAULT_PORT = 8765  #: Foxglove's own default for a WebSocket connection
#: messages queued per client, past which the SDK drops what that client cannot take (a few
#: seconds of frames)
BACKLOG_MESSAGES = 1024

FORMATION = {
    "title": "swarm_sitl.Formation",
    "type": "object",
    "properties": {
        "t_s": {"type": "number"},
        "error_m": {"type": ["number", "null"]},
        "down": {"type": "boolean"},
        "failsafe": {"type": "boolean"},
    },
}
EDGE_AGES = {
    "title": "swarm_sitl.EdgeAges",
    "type": "object",
    "properties": {
        "t_s": {"type": "number"},
        "age_s": {"type": "object", "additionalProperties": {"type": ["number", "null"]}},
    },
}


class FoxgloveError(RuntimeError):
    """The stream cannot be served (a port in use, an address not ours); one line."""


class FoxgloveStream:
    """A Foxglove WebSocket server on ``host:port`` (0: a free one) for the run of ``cfg``."""

    def __init__(self, cfg: SwarmConfig, host: str = "127.0.0.1", port: int = DEFAULT_PORT):
        try:
            import foxglove  # (the native extension loads only for a run that streams)
        except ImportError:
            raise FoxgloveError(
                "the Foxglove stream needs foxglove-sdk: pip install 'swarm-sitl[foxglove]'"
            ) from None
        self._ctx = foxglove.Context()
        try:
            self._server = foxglove.start_server(
                name=f"swarm-sitl {cfg.name}",
                host=host,
                port=port,
                context=self._ctx,
                message_backlog_size=BACKLOG_MESSAGES,
            )
        except Exception as e:  # the SDK raises its own kinds; the line says what it says
            text = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
            raise FoxgloveError(f"cannot serve Foxglove on {host}:{port} ({text})") from None
        self.host = host

        def channel(topic: str, schema: dict[str, Any]) -> Any:
            return foxglove.Channel(
                topic,
                message_encoding="json",
                schema=foxglove.Schema(
                    name=schema["title"], encoding="jsonschema", data=json.dumps(schema).encode()
                ),
                context=self._ctx,
            )

        self._leader = channel("/leader/pose", POSE_IN_FRAME)
        self._poses = {f.id: channel(f"/follower_{f.id}/pose", POSE_IN_FRAME) for f in cfg.followers}
        self._formation = {f.id: channel(f"/follower_{f.id}/formation", FORMATION) for f in cfg.followers}
        self._edges = channel("/edges", EDGE_AGES)
        self._events = channel("/events", EVENT)
        self.logged = 0  #: messages logged (to every client subscribed to their channel)
        #: per follower, the tick instant it was last logged at [s] (a frame can carry a follower
        #: whose status has not moved since the frame before: not logged again)
        self._logged_t: dict[int, float] = {}

    @property
    def port(self) -> int:
        return int(self._server.port)

    @property
    def url(self) -> str:
        return f"ws://{self.host}:{self.port}"

    def subscribed(self) -> set[str]:
        """The topics some client has subscribed to now."""
        channels = [self._leader, self._edges, self._events, *self._poses.values(), *self._formation.values()]
        return {c.topic() for c in channels if c.has_sinks()}

    def frame(self, frame: Frame) -> None:
        """One of the feed's frames (``live.LiveFeed.update``'s)."""
        t = float(frame.t_s) if frame.t_s is not None else math.nan
        ns = timestamp_ns(t)
        leader = _known(frame.leader)
        if leader is not None:
            self._log(self._leader, pose_message(t, leader, None), ns)
        for key, at in frame.followers.items():
            i = int(key)
            t_i = t if at.t_s is None else float(at.t_s)  # (down: at the frame's time)
            if t_i <= self._logged_t.get(i, -math.inf):
                continue
            self._logged_t[i] = t_i
            p = _known(at.p)
            if p is not None:  # (None while it is down)
                self._log(self._poses[i], pose_message(t_i, p, None), timestamp_ns(t_i))
            formation = {
                "t_s": t_i,
                "error_m": at.err,  # (the feed's: None where it is not finite, ``frames.num``)
                "down": bool(at.state & DOWN),
                "failsafe": bool(at.state & FAILSAFE),
            }
            self._log(self._formation[i], formation, timestamp_ns(t_i))
        self._log(self._edges, {"t_s": t, "age_s": frame.edge_age_s}, ns)

    def events(self, events: list[dict[str, Any]]) -> None:
        """Events as the feed reads them (each with its ``t_s``)."""
        for e in events:
            self._log(self._events, e, timestamp_ns(float(e["t_s"])))

    def _log(self, channel: Any, message: dict[str, Any], ns: int) -> None:
        if channel.has_sinks():
            channel.log(json.dumps(message).encode(), log_time=ns)
            self.logged += 1

    def close(self) -> None:
        self._server.stop()


def _known(p: list[float | None]) -> list[float] | None:
    """A frame's position, if every coordinate of it is known (finite)."""
    known = [v for v in p if v is not None]
    return known if len(known) == len(p) else None
