"""What ``falsify`` may do to a swarm: the space file, the plan a point of it is, and its cost.

A space file (YAML)::

    seeds: [0, 1, 2]              # the plan's seed is searched among these (default [0])
    entries:
      - {edges: all, loss: [0.0, 1.0]}                 # one loss on every edge, p in [0, 1]
      - {edges: each, loss: [0.5, 1.0]}                # one loss entry per edge, each its own p
      - {edges: each, drop: true, window_s: [5, 40], max_duration_s: 10}   # a cut per edge
      - {edges: [[0, 1], [1, 4]], delay_s: [0.0, 0.5], window_s: [20, 40]}

Each entry names its edges (``all``: every edge under one parameter, written as a sweep's
``link.HOW`` writes it, an ``into: i`` plan entry per follower, so a search and a campaign fly the
same plans; ``each``: one plan entry per graph edge, each with its own; or a list of edges of the
graph), one how (``loss: [lo, hi]``, ``delay_s: [lo, hi]``,
``drop: true``) and optionally a window (``window_s: [a, b]``: the fault acts from ``from_s`` to
``until_s`` within it, both searched, at most ``max_duration_s`` long; without one it acts over the
whole run). With more than one item (an entry times its edges) each item is also on or off. Without
a file the space is loss, cuts and delays on every edge (``DEFAULT``).

A plan's cost (``--cost``): ``severity`` (the default) is the sum over its entries of severity
times duration [s] (loss: p; a cut: 1; a delay: ``delay_s / estimator.staleness_s``, at most 1: an
estimate past staleness is as good as lost); ``edges`` is the number of graph edges it touches.
"""

import math
from typing import Annotated, Any, Literal, Protocol

from pydantic import BaseModel, ConfigDict, Field, model_validator

from swarm_sitl.config.schema import SwarmConfig

COSTS = ("severity", "edges")
Edge = tuple[Annotated[int, Field(ge=0)], Annotated[int, Field(ge=1)]]


class Trial(Protocol):
    """What a sampler gives values from (Optuna's ``Trial``)."""

    def suggest_float(self, name: str, low: float, high: float) -> float: ...
    def suggest_categorical(self, name: str, choices: Any) -> Any: ...


class SpaceEntry(BaseModel):
    """One entry of a space: edges x one how x a window."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    edges: Literal["all", "each"] | list[Edge] = "each"
    loss: tuple[float, float] | None = None  #: p's range, within [0, 1]
    delay_s: tuple[float, float] | None = None  #: the delay's range [s]
    drop: Literal[True] | None = None  #: a cut
    window_s: tuple[float, float] | None = None  #: the fault acts within [a, b] [s] (default: the run)
    max_duration_s: Annotated[float, Field(gt=0)] | None = None  #: and at most this long [s]

    @model_validator(mode="after")
    def _one_how(self) -> "SpaceEntry":
        hows = [h for h in ("loss", "delay_s", "drop") if getattr(self, h) is not None]
        if len(hows) != 1:
            raise ValueError(f"needs exactly one of loss, delay_s, drop (got {', '.join(hows) or 'none'})")
        for name in ("loss", "delay_s", "window_s"):
            r = getattr(self, name)
            if r is not None and not r[0] < r[1]:
                raise ValueError(f"{name}: an empty range [{r[0]:g}, {r[1]:g}] (needs low < high)")
        if self.loss is not None and not 0 <= self.loss[0] < self.loss[1] <= 1:
            raise ValueError(f"loss: [{self.loss[0]:g}, {self.loss[1]:g}] is not within [0, 1]")
        if self.delay_s is not None and self.delay_s[0] < 0:
            raise ValueError("delay_s: a delay is at least 0 s")
        if self.window_s is not None and self.window_s[0] < 0:
            raise ValueError("window_s: starts at 0 s or later")
        return self

    @property
    def how(self) -> str:
        return "loss" if self.loss is not None else ("delay_s" if self.delay_s is not None else "drop")


class Space(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)

    seeds: list[Annotated[int, Field(ge=0)]] = [0]  #: the plan's seed is one of these
    entries: list[SpaceEntry] = Field(min_length=1)

    def check_against(self, cfg: SwarmConfig) -> None:
        """An edge not in the graph, or a window past the run: ``ValueError`` naming the entry."""
        graph = set(cfg.graph_edges())
        for j, e in enumerate(self.entries):
            if isinstance(e.edges, list):
                for s, d in e.edges:
                    if (s, d) not in graph:
                        raise ValueError(f"entries.{j}: edge [{s}, {d}] is not an edge of the graph")
            if e.window_s is not None and e.window_s[1] > cfg.duration_s + 1e-9:
                raise ValueError(
                    f"entries.{j}: window_s ends at {e.window_s[1]:g} s, after the run ({cfg.duration_s:g} s)"
                )
        if not self.seeds:
            raise ValueError("seeds: at least one")


def default_space(cfg: SwarmConfig) -> Space:
    """Loss, cuts and delays on every edge (a cut at most a quarter of the run)."""
    return Space(
        entries=[
            SpaceEntry(edges="each", loss=(0.0, 1.0)),
            SpaceEntry(
                edges="each", drop=True, window_s=(0.0, cfg.duration_s), max_duration_s=cfg.duration_s / 4
            ),
            SpaceEntry(edges="each", delay_s=(0.0, cfg.estimator.staleness_s * 1.2)),
        ]
    )


class Item(BaseModel):
    """One plan entry a space may hold: space entry ``j`` on ``edge`` (None: every edge)."""

    model_config = ConfigDict(frozen=True)

    j: int
    edge: tuple[int, int] | None
    entry: SpaceEntry

    @property
    def name(self) -> str:
        where = "all" if self.edge is None else f"{self.edge[0]}-{self.edge[1]}"
        return f"{self.j}.{self.entry.how}.{where}"


def items(space: Space, cfg: SwarmConfig) -> list[Item]:
    out = []
    for j, e in enumerate(space.entries):
        if e.edges == "all":
            out.append(Item(j=j, edge=None, entry=e))
        else:
            edges = cfg.graph_edges() if e.edges == "each" else [tuple(x) for x in e.edges]
            out += [Item(j=j, edge=(int(s), int(d)), entry=e) for s, d in edges]
    return out


def plan_of(trial: Trial, space: Space, its: list[Item], cfg: SwarmConfig) -> dict[str, Any]:
    """The trial's point of the space, as a plan of its items (``expand`` makes it a fault plan:
    an entry over every edge is one entry here, so shrinking drops or lowers it whole)."""
    seed = space.seeds[0] if len(space.seeds) == 1 else int(trial.suggest_categorical("seed", space.seeds))
    entries = []
    for it in its:
        if len(its) > 1 and not trial.suggest_categorical(f"{it.name}.on", [False, True]):
            continue
        e = it.entry
        f: dict[str, Any] = {}
        if e.loss is not None:
            f["loss"] = trial.suggest_float(f"{it.name}.p", max(e.loss[0], 1e-6), e.loss[1])
        elif e.delay_s is not None:
            f["delay_s"] = trial.suggest_float(f"{it.name}.d", max(e.delay_s[0], 1e-9), e.delay_s[1])
        else:
            f["drop"] = True
        if e.window_s is not None:
            a, b = e.window_s
            longest = min(b - a, e.max_duration_s or math.inf)
            dt = cfg.control_dt_s
            start = trial.suggest_float(f"{it.name}.from", a, b - dt)
            dur = trial.suggest_float(f"{it.name}.dur", dt, max(longest, 2 * dt))
            f["from_s"], f["until_s"] = start, min(b, start + dur)
        elif e.max_duration_s is not None:
            f["until_s"] = min(cfg.duration_s, e.max_duration_s)
        entries.append({"edges": "all", **f} if it.edge is None else {"edge": list(it.edge), **f})
    return {"seed": seed, "plan": entries}


def expand(plan: dict[str, Any], cfg: SwarmConfig) -> dict[str, Any]:
    """A plan of items (``plan_of``) as a fault plan (``faults:``'s mapping): an entry over every
    edge becomes an ``into: i`` entry per follower, as a sweep's ``link.HOW`` writes it."""
    out = []
    for f in plan["plan"]:
        if f.get("edges") == "all":
            rest = {k: v for k, v in f.items() if k != "edges"}
            out += [{"into": x.id, **rest} for x in cfg.followers]
        else:
            out.append(f)
    return {"seed": plan["seed"], "plan": out}


def cost(plan: dict[str, Any], cfg: SwarmConfig, how: str = "severity") -> float:
    """A fault plan's cost (module docstring)."""
    if how == "edges":
        touched: set[tuple[int, int]] = set()
        for f in plan["plan"]:
            if "into" in f:
                touched |= {(a, b) for a, b in cfg.graph_edges() if b == f["into"]}
            else:
                touched.add((f["edge"][0], f["edge"][1]))
        return float(len(touched))
    total = 0.0
    for f in plan["plan"]:
        dur = min(f.get("until_s", cfg.duration_s), cfg.duration_s) - f.get("from_s", 0.0)
        if "loss" in f:
            severity = f["loss"]
        elif "delay_s" in f:
            severity = min(1.0, f["delay_s"] / cfg.estimator.staleness_s)
        else:
            severity = 1.0
        total += severity * dur
    return total
