"""A requirement of a config's ``spec:``: a name, what it ranges over, and a formula.

.. code-block:: yaml

    spec:
      - name: holds_formation
        over: followers                      # each follower; or: follower 3, followers within
        formula: "always[20, end] (pos_err_m < 0.05)"   #   2 hops, in-neighbours of 4, pairs
      - name: keeps_apart
        over: pairs
        formula: "always (distance_m > 1.0)"

``over`` is what the formula's signals belong to: a follower (``followers``, ``follower I``,
``followers within K hops`` of the leader, ``in-neighbours of I``: signals of ``FOLLOWER_SIGNALS``),
a pair of followers (``pairs``: ``PAIR_SIGNALS``) or an edge of the graph (``edges``, ``edges into
I``, ``edges out of I``, ``edge S -> D``, with S or I 0 for the leader: ``EDGE_SIGNALS``, what the
receiver saw of it). The requirement holds for the run when it
holds for every member; its robustness is the least of its members'. Checked when the config is
read (``check_against``): a formula that does not parse, a signal its members have not, an
unknown follower, or an interval that starts after the run, is one line naming the requirement.
"""

import re
from dataclasses import dataclass
from typing import Any, NamedTuple

from pydantic import BaseModel, ConfigDict, Field, field_validator

from swarm_sitl.specs.formula import FormulaError, first_start_s, parse, signals_of

#: what a follower's formula may read, and its unit
FOLLOWER_SIGNALS = {
    "pos_err_m": "m: |p - p_r - delta_i|, the formation error",
    "vel_err_mps": "m/s: |v - v_r|",
    "est_pos_err_m": "m: |p_hat - p_r|, the leader estimate's error (a law that records p_hat)",
    "altitude_m": "m: the vehicle's height (ENU z)",
    "speed_mps": "m/s: |v|",
    "thrust_frac": "1: the commanded thrust over the vehicle's maximum",
    "failsafe": "1 while the vehicle is in its setpoint-loss failsafe, else 0",
}
#: what a pair's formula may read
PAIR_SIGNALS = {"distance_m": "m: the distance between the two vehicles"}
#: what an edge's formula may read, as its receiver saw it (``recording``'s ``in_age_s``)
EDGE_SIGNALS = {
    "age_s": "s: the age of the newest estimate the receiver had from the sender at its tick "
    "(NaN before the first: a requirement on it fails there)",
    "delivered_frac": "1: of the receiver's ticks so far, the fraction at which a newer estimate "
    "from the sender had come since the tick before",
}

_OVER = re.compile(
    r"^(?:(?P<all>followers)|follower (?P<one>\d+)|followers within (?P<hops>\d+) hops?"
    r"|in-neighbours of (?P<into>\d+)|(?P<pairs>pairs)|(?P<edges>edges)|edges into (?P<edges_into>\d+)"
    r"|edges out of (?P<edges_out>\d+)|edge (?P<src>\d+) ?-> ?(?P<dst>\d+))$"
)


class SpecError(ValueError):
    """A requirement that cannot be judged; one line naming it."""


@dataclass(frozen=True)
class Over:
    """What a requirement ranges over."""

    kind: str  #: ``followers``, ``follower``, ``within``, ``into``, ``pairs``, ``edges``,
    #: ``edges_into``, ``edges_out``, ``edge``
    value: int = 0  #: the follower, the hops, the node whose in-neighbours (or edges), the sender
    dst: int = 0  #: ``edge``: its receiver

    @property
    def on_edges(self) -> bool:
        return self.kind.startswith("edge")

    def members(self, graph: Any, followers: list[int]) -> list[Any]:
        """The followers (or pairs of followers, or ``Edge``s) it ranges over on ``graph``."""
        if self.on_edges:
            edges = [Edge(int(s), int(d)) for d in followers for s, _ in graph.in_neighbours(d)]
            if self.kind == "edges_into":
                return [e for e in edges if e.dst == self.value]
            if self.kind == "edges_out":
                return [e for e in edges if e.src == self.value]
            if self.kind == "edge":
                return [e for e in edges if (e.src, e.dst) == (self.value, self.dst)]
            return edges
        if self.kind == "followers":
            return list(followers)
        if self.kind == "follower":
            return [self.value]
        if self.kind == "pairs":
            return [(a, b) for k, a in enumerate(followers) for b in followers[k + 1 :]]
        if self.kind == "into":
            return sorted(s for s, _ in graph.in_neighbours(self.value) if s != 0)
        hops = graph.hops_from(0)  # (``laws.graph.Graph``)
        return sorted(i for i in followers if hops.get(i, self.value + 1) <= self.value)


class Edge(NamedTuple):
    """An edge of the graph a requirement ranges over: what ``dst`` saw of ``src``'s estimates."""

    src: int
    dst: int


def parse_over(text: str) -> Over:
    m = _OVER.match(" ".join(text.split()))
    if m is None:
        raise ValueError(
            f"over: {text!r} is not 'followers', 'follower I', 'followers within K hops', "
            "'in-neighbours of I', 'pairs', 'edges', 'edges into I', 'edges out of I' or 'edge S -> D'"
        )
    if m["edges"]:
        return Over("edges")
    if m["edges_into"]:
        return Over("edges_into", int(m["edges_into"]))
    if m["edges_out"]:
        return Over("edges_out", int(m["edges_out"]))
    if m["src"]:
        return Over("edge", int(m["src"]), int(m["dst"]))
    if m["all"]:
        return Over("followers")
    if m["pairs"]:
        return Over("pairs")
    if m["one"]:
        return Over("follower", int(m["one"]))
    if m["hops"]:
        return Over("within", int(m["hops"]))
    return Over("into", int(m["into"]))


class Requirement(BaseModel):
    """One named requirement (module docstring)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    name: str = Field(pattern=r"^[A-Za-z0-9_-]+$")  #: how the summary and the lines name it
    over: str = "followers"  #: what its formula ranges over
    formula: str  #: signal temporal logic (``specs.formula``) over its members' signals

    @field_validator("formula")
    @classmethod
    def _parses(cls, text: str) -> str:
        try:
            parse(text)
        except FormulaError as e:
            raise ValueError(f"formula: {e}") from None
        return text

    @field_validator("over")
    @classmethod
    def _over(cls, text: str) -> str:
        parse_over(text)
        return text

    @property
    def target(self) -> Over:
        return parse_over(self.over)

    @property
    def tree(self) -> Any:
        return parse(self.formula)

    def check_against(
        self, followers: list[int], duration_s: float, edges: list[tuple[int, int]] | None = None
    ) -> None:
        """``SpecError`` naming this requirement if its members or its intervals do not fit a run
        (``edges``: the graph's, for a requirement over edges)."""
        over = self.target
        known = (
            PAIR_SIGNALS if over.kind == "pairs" else (EDGE_SIGNALS if over.on_edges else FOLLOWER_SIGNALS)
        )
        unknown = sorted(signals_of(self.tree) - set(known))
        if unknown:
            raise SpecError(
                f"spec {self.name}: no signal {', '.join(unknown)} for {self.over} "
                f"(there: {', '.join(known)})"
            )
        if over.kind == "edge" and edges is not None and (over.value, over.dst) not in edges:
            raise SpecError(f"spec {self.name}: no edge {over.value} -> {over.dst} in the graph")
        if over.kind in ("edges_into", "edges_out") and edges is not None:
            side = 1 if over.kind == "edges_into" else 0
            if not any(e[side] == over.value for e in edges):
                way = "into" if side else "out of"
                raise SpecError(f"spec {self.name}: no edge {way} {over.value} in the graph")
        if over.kind in ("follower", "into") and over.value not in followers:
            raise SpecError(
                f"spec {self.name}: no follower {over.value} (followers {followers[0]}..{followers[-1]})"
            )
        start = first_start_s(self.tree)
        if start >= duration_s:
            raise SpecError(
                f"spec {self.name}: its formula first looks at {start:g} s, after the run's end "
                f"({duration_s:g} s)"
            )
