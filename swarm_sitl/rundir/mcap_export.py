"""A run directory as one MCAP file that Foxglove opens: ``swarm-sitl export RUN_DIR``.

Channels (JSON messages, each with its JSON schema; log and publish time = the tick's simulated
time from 0):

- ``/follower_<i>/pose`` and ``/leader/pose``: ``foxglove.PoseInFrame`` (frame ``world``, ENU): the
  vehicle's position and attitude, the leader's reference position; Foxglove's 3-D panel draws the
  formation from these;
- ``/follower_<i>/state``: ``swarm_sitl.FollowerState``: velocity, body rates, the estimates of
  the leader's state, the errors, the command (force, thrust, command attitude and rate);
- ``/edge/<src>/<dst>``: ``swarm_sitl.Estimate``: what node ``src`` published for ``dst`` at each
  tick (the leader's reference for ``src`` 0), one channel per edge of the graph (whether the
  plan delivered it is in ``summary.json``'s ``links``);
- ``/leader/reference``: ``swarm_sitl.Reference``: p_r, v_r, a_r;
- ``/events``: ``swarm_sitl.Event``: ``events.jsonl``, each at its time.

Foxglove's own schemas (``foxglove.PoseInFrame``) in their JSON-schema form, with JSON encoding:
any Foxglove (and ``mcap`` reader) decodes them without a protobuf or flatbuffer toolchain, and the
custom channels read as plain JSON in its raw-message and plot panels. Why not ``foxglove-sdk``:
it is a native extension for live logging; a finished run is a file to write once, which the
``mcap`` library (the format's own, pure Python) does.
"""

import json
import math
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
from mcap.writer import Writer

from swarm_sitl.config.load import load_recorded
from swarm_sitl.rundir.events import read_events
from swarm_sitl.rundir.load import load_run

_VEC = {"type": "object", "properties": {k: {"type": "number"} for k in "xyz"}}
_QUAT = {"type": "object", "properties": {k: {"type": "number"} for k in "xyzw"}}
_TIME = {"type": "object", "properties": {"sec": {"type": "integer"}, "nsec": {"type": "integer"}}}
POSE_IN_FRAME = {
    "title": "foxglove.PoseInFrame",
    "type": "object",
    "properties": {
        "timestamp": _TIME,
        "frame_id": {"type": "string"},
        "pose": {"type": "object", "properties": {"position": _VEC, "orientation": _QUAT}},
    },
}


def _vectors(title: str, names: list[str]) -> dict[str, Any]:
    arr = {"type": "array", "items": {"type": "number"}}
    return {
        "title": title,
        "type": "object",
        "properties": {"t_s": {"type": "number"}, **{n: arr for n in names}},
    }


FOLLOWER_FIELDS = [
    "v_W",
    "omega_B",
    "p_hat",
    "v_hat",
    "a_hat",
    "pos_err_m",
    "vel_err_mps",
    "est_pos_err_m",
    "u",
    "q_c",
    "omega_c",
]
ESTIMATE_FIELDS = ["p_hat", "v_hat", "a_hat", "a_hat_dot"]
REFERENCE_FIELDS = ["p_r", "v_r", "a_r"]
EVENT = {  # the fields of each kind are its own (``rundir.events``): declared open
    "title": "swarm_sitl.Event",
    "type": "object",
    "properties": {"t_s": {"type": "number"}, "kind": {"type": "string"}},
    "required": ["t_s", "kind"],
    "additionalProperties": True,
}


def timestamp_ns(t_s: float) -> int:
    return max(0, round(t_s * 1e9))


def pose_message(t_s: float, p: np.ndarray | list[float], q_wxyz: np.ndarray | None) -> dict[str, Any]:
    """A ``foxglove.PoseInFrame`` in ``world`` (ENU) at ``t_s``; ``q_wxyz`` None: the identity."""
    ns = timestamp_ns(t_s)
    w, x, y, z = (1.0, 0.0, 0.0, 0.0) if q_wxyz is None else (float(v) for v in q_wxyz)
    return {
        "timestamp": {"sec": ns // 1_000_000_000, "nsec": ns % 1_000_000_000},
        "frame_id": "world",
        "pose": {
            "position": {"x": float(p[0]), "y": float(p[1]), "z": float(p[2])},
            "orientation": {"x": x, "y": y, "z": z, "w": w},
        },
    }


def _finite_rows(t: np.ndarray) -> Iterator[int]:
    return (k for k in range(len(t)) if math.isfinite(t[k]))


def write_mcap(run_dir: str | Path, path: str | Path) -> dict[str, int]:
    """Write ``run_dir`` as MCAP to ``path``; returns the message count per channel."""
    run_dir = Path(run_dir)
    rec = load_run(run_dir)
    cfg = load_recorded(run_dir)
    trajectory = cfg.trajectory()
    counts: dict[str, int] = {}
    with open(path, "wb") as f:
        w = Writer(f)
        w.start(profile="", library="swarm-sitl")

        def schema(s: dict[str, Any]) -> int:
            return w.register_schema(name=s["title"], encoding="jsonschema", data=json.dumps(s).encode())

        ids = {
            "pose": schema(POSE_IN_FRAME),
            "state": schema(_vectors("swarm_sitl.FollowerState", FOLLOWER_FIELDS)),
            "estimate": schema(_vectors("swarm_sitl.Estimate", ESTIMATE_FIELDS)),
            "reference": schema(_vectors("swarm_sitl.Reference", REFERENCE_FIELDS)),
            "event": schema(EVENT),
        }
        channels: dict[str, int] = {}

        def put(topic: str, kind: str, t_s: float, message: dict[str, Any]) -> None:
            if topic not in channels:
                channels[topic] = w.register_channel(
                    topic=topic, message_encoding="json", schema_id=ids[kind]
                )
            ns = timestamp_ns(t_s)
            w.add_message(channels[topic], log_time=ns, data=json.dumps(message).encode(), publish_time=ns)
            counts[topic] = counts.get(topic, 0) + 1

        L = rec.leader
        for k in _finite_rows(L["t_s"]):
            t = float(L["t_s"][k])
            put("/leader/pose", "pose", t, pose_message(t, L["p_r"][k], None))
            put("/leader/reference", "reference", t, _row(t, L, REFERENCE_FIELDS, k))
        for i, a in sorted(rec.followers.items()):
            for k in _finite_rows(a["t_s"]):
                t = float(a["t_s"][k])
                if not np.all(np.isfinite(a["p_W"][k])):
                    continue
                put(f"/follower_{i}/pose", "pose", t, pose_message(t, a["p_W"][k], a["q_WB"][k]))
                put(f"/follower_{i}/state", "state", t, _row(t, a, FOLLOWER_FIELDS, k))
        for src, dst in cfg.graph_edges():
            for k in _finite_rows(L["t_s"] if src == 0 else rec.followers[src]["t_s"]):
                if src == 0:  # the reference and its derivatives, as the leader publishes them
                    t = float(L["t_s"][k])
                    d = trajectory.derivatives(t)
                    est = {"t_s": t, **{n: d[j].tolist() for j, n in enumerate(ESTIMATE_FIELDS)}}
                elif all(n in rec.followers[src] for n in ESTIMATE_FIELDS):  # the paper's message
                    a = rec.followers[src]
                    t = float(a["t_s"][k])
                    est = _row(t, a, ESTIMATE_FIELDS, k)
                else:  # another law's message is its own: not recorded as such
                    break
                put(f"/edge/{src}/{dst}", "estimate", t, est)
        for e in read_events(run_dir / "events.jsonl"):
            put("/events", "event", float(e["t_s"]), e)
        w.finish()
    return counts


def _row(t_s: float, arrays: dict[str, np.ndarray], names: list[str], k: int) -> dict[str, Any]:
    return {"t_s": t_s, **{n: np.asarray(arrays[n][k], dtype=float).tolist() for n in names if n in arrays}}
