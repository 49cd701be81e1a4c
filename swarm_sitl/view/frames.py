"""The page's frame document, declared once: what a frame holds, by name, and how frames become
the document's columns. The replay (``replay``), the live feed (``live``), the Foxglove stream
(``foxglove_live``) and the page (``static/view.js``, which merges new columns by these names)
all follow it.

A frame is one instant of the run as the page shows it: the time, the leader's reference, each
follower (``FollowerAt``) and each edge's age. The document holds frames as columns, a list per
quantity (``Columns``): ``t_s``, ``leader``, ``followers[id].{p, err, state}``, ``edge_age_s[key]``.
Every number is rounded for the page and is ``None`` where it is not finite (strict JSON).
"""

import dataclasses
import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from typing import Any

#: a follower's state in a frame, bits: its controller recorded nothing (killed, not yet back), its
#: vehicle in its failsafe; 0: flying as asked
DOWN, FAILSAFE = 1, 2


def num(x: float, digits: int = 3) -> float | None:
    """``x`` as the document holds it: rounded to ``digits``, None where it is not finite."""
    return round(float(x), digits) if math.isfinite(x) else None


def xyz(v: Iterable[float]) -> list[float | None]:
    """A vector as the document holds it [m]."""
    return [num(x) for x in v]


@dataclass(frozen=True)
class FollowerAt:
    """One follower in one frame."""

    p: list[float | None]  #: its position, ENU [m] (``None`` x 3 while it is down)
    err: float | None  #: its formation error [m]
    state: int  #: ``DOWN | FAILSAFE`` bits (0: flying as asked)
    #: the instant of the tick it is shown at [s] (live: a follower's newest status is of its own
    #: tick; None: down). Not a column of the document: the Foxglove stream stamps with it
    t_s: float | None = field(default=None, metadata={"column": False})


@dataclass(frozen=True)
class Frame:
    """One instant of the run as the page shows it."""

    t_s: float | None  #: run time [s]
    leader: list[float | None]  #: the leader's reference position, ENU [m]
    followers: dict[str, FollowerAt]  #: by follower id (as a string: a JSON key)
    edge_age_s: dict[str, float | None]  #: by edge ``"src->dst"``: the age of what it carried [s]


#: the per-follower columns of the document, in ``FollowerAt``'s order
FOLLOWER_COLUMNS = tuple(f.name for f in dataclasses.fields(FollowerAt) if f.metadata.get("column", True))
#: the document's frame columns, in ``Frame``'s order
FRAME_COLUMNS = tuple(f.name for f in dataclasses.fields(Frame))

Columns = dict[str, Any]


def follower_columns(**columns: Sequence[Any]) -> dict[str, list[Any]]:
    """One follower's columns, each named as ``FollowerAt`` names it (``ValueError`` for a name
    it does not declare or one left out)."""
    if tuple(columns) != FOLLOWER_COLUMNS:
        raise ValueError(f"a follower's columns are {FOLLOWER_COLUMNS}, not {tuple(columns)}")
    return {k: list(v) for k, v in columns.items()}


def frame_columns(**columns: Any) -> Columns:
    """The document's frames, each column named as ``Frame`` names it (``ValueError`` as above)."""
    if tuple(columns) != FRAME_COLUMNS:
        raise ValueError(f"a document's frame columns are {FRAME_COLUMNS}, not {tuple(columns)}")
    return dict(columns)


def columns(frames: Sequence[Frame], follower_ids: Sequence[int]) -> Columns:
    """``frames`` as the document holds them: a list per quantity, by name."""
    ages: dict[str, list[float | None]] = {}
    for fr in frames:
        for k, a in fr.edge_age_s.items():
            ages.setdefault(k, []).append(a)
    return frame_columns(
        t_s=[fr.t_s for fr in frames],
        leader=[fr.leader for fr in frames],
        followers={
            str(i): follower_columns(
                **{c: [getattr(fr.followers[str(i)], c) for fr in frames] for c in FOLLOWER_COLUMNS}
            )
            for i in follower_ids
        },
        edge_age_s=ages,
    )


def no_frames() -> Columns:
    """The document's frames when there are none."""
    return columns([], [])


def event_line(e: dict[str, Any]) -> dict[str, Any]:
    """An event as the page lists it: its time, kind, source and the rest in one line."""
    rest = {k: v for k, v in e.items() if k not in ("t_s", "kind", "source", "unix_s")}
    text = ", ".join(f"{k} {v}" for k, v in rest.items())
    return {
        "t_s": num(float(e["t_s"]), 3),
        "kind": str(e["kind"]),
        "source": str(e.get("source", "")),
        "text": text,
    }
