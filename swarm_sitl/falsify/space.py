"""What ``falsify`` may do to a swarm: the space file, the plan a point of it is, and its cost.

A space file (YAML)::

    seeds: [0, 1, 2]              # the plan's seed is searched among these (default [0])
    entries:
      - {edges: all, loss: [0.0, 1.0]}                 # one loss on every edge, p in [0, 1]
      - {edges: each, loss: [0.5, 1.0]}                # one loss entry per edge, each its own p
      - {edges: each, drop: true, window_s: [5, 40], max_duration_s: 10}   # a cut per edge
      - {edges: [[0, 1], [1, 4]], delay_s: [0.0, 0.5], window_s: [20, 40]}
      - {links: each, direction: up, loss: [0.0, 0.5], window_s: [10, 40]}  # MAVLink setpoints
      - {controllers: [2, 3], kill: true, restart_after_s: [0.5, 5], window_s: [10, 30]}

An entry names what fails, one how and optionally a window. What: ``edges`` (``all``: every edge
under one parameter, written as a sweep's ``link.HOW`` writes it, an ``into: i`` plan entry per
follower, so a search and a campaign fly the same plans; ``each``: one plan entry per graph edge,
each with its own; or a list of edges of the graph), ``links`` (``each`` or a list of followers:
their MAVLink links, ``direction`` ``up``, ``down`` or ``both``) or ``controllers`` (``each`` or a
list). How: ``loss: [lo, hi]``, ``delay_s: [lo, hi]`` (edges), ``drop: true`` (edges, links;
lockstep's MAVLink hows are loss and drop), ``kill: true`` with ``restart_after_s: [lo, hi]``
(controllers: killed at a searched instant, started again that much later). A window
(``window_s: [a, b]``): the fault acts from ``from_s`` to ``until_s`` within it, both searched, at
most ``max_duration_s`` long (a kill: happens within it); without one it acts over the whole run.
With more than one item (an entry times its edges, links or controllers) each item is also on or
off. Without a file the space is loss, cuts and delays on every edge (``default_space``).

A plan's cost (``--cost``): ``severity`` (the default) is the sum over its entries of severity
times duration [s] (loss: p; a cut: 1; a delay: ``delay_s / estimator.staleness_s``, at most 1: an
estimate past staleness is as good as lost; a controller down: 1, for its downtime); ``edges`` is
the number of graph edges, MAVLink links and controllers it touches.
"""

import math
from typing import Annotated, Any, Literal, Protocol

from pydantic import BaseModel, ConfigDict, Field, model_validator

from swarm_sitl.config.schema import SwarmConfig
from swarm_sitl.faults.plan import FaultSpec

COSTS = ("severity", "edges")
Edge = tuple[Annotated[int, Field(ge=0)], Annotated[int, Field(ge=1)]]


class Trial(Protocol):
    """What a sampler gives values from (Optuna's ``Trial``)."""

    def suggest_float(self, name: str, low: float, high: float) -> float: ...
    def suggest_categorical(self, name: str, choices: Any) -> Any: ...


Ids = Literal["all", "each"] | list[Annotated[int, Field(ge=1)]]


class SpaceEntry(BaseModel):
    """One entry of a space: what (edges, links or controllers) x one how x a window."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    edges: Literal["all", "each"] | list[Edge] | None = None  #: graph edges
    links: Literal["each"] | list[Annotated[int, Field(ge=1)]] | None = None  #: followers' MAVLink links
    direction: Literal["up", "down", "both"] = "both"  #: which way of a link
    controllers: Literal["each"] | list[Annotated[int, Field(ge=1)]] | None = None  #: killed
    loss: tuple[float, float] | None = None  #: p's range, within [0, 1]
    delay_s: tuple[float, float] | None = None  #: the delay's range [s] (edges)
    drop: Literal[True] | None = None  #: a cut
    kill: Literal[True] | None = None  #: a controller killed (``controllers``)
    restart_after_s: tuple[float, float] | None = None  #: and started again this much later [s]
    window_s: tuple[float, float] | None = None  #: the fault acts within [a, b] [s] (default: the run)
    max_duration_s: Annotated[float, Field(gt=0)] | None = None  #: and at most this long [s]

    @model_validator(mode="after")
    def _one_how(self) -> "SpaceEntry":
        whats = [w for w in ("edges", "links", "controllers") if getattr(self, w) is not None]
        if len(whats) != 1:
            raise ValueError(
                f"needs exactly one of edges, links, controllers (got {', '.join(whats) or 'none'})"
            )
        hows = [h for h in ("loss", "delay_s", "drop", "kill") if getattr(self, h) is not None]
        if len(hows) != 1:
            raise ValueError(
                f"needs exactly one of loss, delay_s, drop, kill (got {', '.join(hows) or 'none'})"
            )
        allowed = {"edges": ("loss", "delay_s", "drop"), "links": ("loss", "drop"), "controllers": ("kill",)}
        if hows[0] not in allowed[whats[0]]:
            raise ValueError(f"{whats[0]} fail by {' or '.join(allowed[whats[0]])}, not {hows[0]}")
        if self.kill is not None and self.restart_after_s is None:
            raise ValueError("kill: give restart_after_s: [low, high] (how long it stays down)")
        for name in ("loss", "delay_s", "window_s", "restart_after_s"):
            r = getattr(self, name)
            if r is not None and not r[0] < r[1]:
                raise ValueError(f"{name}: an empty range [{r[0]:g}, {r[1]:g}] (needs low < high)")
        if self.loss is not None and not 0 <= self.loss[0] < self.loss[1] <= 1:
            raise ValueError(f"loss: [{self.loss[0]:g}, {self.loss[1]:g}] is not within [0, 1]")
        if self.delay_s is not None and self.delay_s[0] < 0:
            raise ValueError("delay_s: a delay is at least 0 s")
        if self.restart_after_s is not None and self.restart_after_s[0] <= 0:
            raise ValueError("restart_after_s: more than 0 s")
        if self.window_s is not None and self.window_s[0] < 0:
            raise ValueError("window_s: starts at 0 s or later")
        return self

    @property
    def what(self) -> str:
        return "edges" if self.edges is not None else ("links" if self.links is not None else "controllers")

    @property
    def how(self) -> str:
        for h in ("loss", "delay_s", "drop", "kill"):
            if getattr(self, h) is not None:
                return h
        raise AssertionError("validated: one how")

    @property
    def severity_range(self) -> tuple[float, float] | None:
        """The range shrinking lowers the severity in (None: a cut, all or nothing)."""
        return self.loss or self.delay_s or self.restart_after_s


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
        ids = [f.id for f in cfg.followers]
        for j, e in enumerate(self.entries):
            named = (
                e.links
                if isinstance(e.links, list)
                else (e.controllers if isinstance(e.controllers, list) else [])
            )
            for i in named:
                if i not in ids:
                    raise ValueError(f"entries.{j}: no follower {i} (followers {ids[0]}..{ids[-1]})")
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
    """One plan entry a space may hold: space entry ``j`` on ``edge``, or on follower ``node``'s
    link or controller, or (neither) on every edge."""

    model_config = ConfigDict(frozen=True)

    j: int
    edge: tuple[int, int] | None = None
    node: int | None = None
    entry: SpaceEntry

    @property
    def name(self) -> str:
        if self.node is not None:
            where = f"{self.entry.what[:-1]}{self.node}"
        else:
            where = "all" if self.edge is None else f"{self.edge[0]}-{self.edge[1]}"
        return f"{self.j}.{self.entry.how}.{where}"


def items(space: Space, cfg: SwarmConfig) -> list[Item]:
    out = []
    ids = [f.id for f in cfg.followers]
    for j, e in enumerate(space.entries):
        if e.edges == "all":
            out.append(Item(j=j, edge=None, entry=e))
        elif e.edges is not None:
            edges = cfg.graph_edges() if e.edges == "each" else [tuple(x) for x in e.edges]
            out += [Item(j=j, edge=(int(s), int(d)), entry=e) for s, d in edges]
        else:
            nodes = e.links if e.links is not None else e.controllers
            out += [Item(j=j, node=i, entry=e) for i in (ids if nodes == "each" else nodes or [])]
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
        elif e.restart_after_s is not None:
            f["kill"] = True
            f["restart_after_s"] = trial.suggest_float(f"{it.name}.down", *e.restart_after_s)
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
        if f.get("kill"):  # a kill happens at from_s: its window gives the instant
            f.pop("until_s", None)
            f.setdefault("from_s", trial.suggest_float(f"{it.name}.at", 0.0, cfg.duration_s / 2))
        if it.node is not None:
            key = "mavlink" if e.links is not None else "controller"
            extra = {"direction": e.direction} if e.links is not None else {}
            entries.append({key: it.node, **extra, **f})
        else:
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


def flown_plan(plan: dict[str, Any], cfg: SwarmConfig) -> dict[str, Any]:
    """What a plan of items (``plan_of``) flies: the config's own ``faults:`` entries first (its
    base plan, flown under every searched plan), then the searched ones (``expand``), all under
    the searched seed. What a counterexample file holds: ``run --faults`` replays it whole."""
    searched = expand(plan, cfg)
    fields = FaultSpec.model_fields
    base = [
        {k: v for k, v in f.items() if v is not None and not (k in fields and v == fields[k].default)}
        for f in cfg.data()["faults"]["plan"]
    ]
    return {"seed": searched["seed"], "plan": base + searched["plan"]}


def edges_of(entry: dict[str, Any], cfg: SwarmConfig) -> list[tuple[int, int]]:
    """The graph edges a fault plan's entry acts on (``FaultSpec.edges``; none for a MAVLink
    link or a process)."""
    return FaultSpec.model_validate(entry).edges(cfg.graph_edges())


def cost(plan: dict[str, Any], cfg: SwarmConfig, how: str = "severity") -> float:
    """A fault plan's cost (module docstring)."""
    if how == "edges":
        touched: set[tuple[int, int]] = set()
        others: set[tuple[str, int]] = set()
        for f in plan["plan"]:
            if "mavlink" in f or "controller" in f:
                others.add(("mavlink", f["mavlink"]) if "mavlink" in f else ("controller", f["controller"]))
            else:
                touched |= set(edges_of(f, cfg))
        return float(len(touched) + len(others))
    total = 0.0
    for f in plan["plan"]:
        dur = min(f.get("until_s", cfg.duration_s), cfg.duration_s) - f.get("from_s", 0.0)
        if f.get("kill"):  # down from from_s for restart_after_s (at most to the end)
            dur = min(f["restart_after_s"], cfg.duration_s - f["from_s"])
        if "loss" in f:
            severity = f["loss"]
        elif "delay_s" in f:
            severity = min(1.0, f["delay_s"] / cfg.estimator.staleness_s)
        else:  # a cut, or a controller down
            severity = 1.0
        total += severity * dur
    return total
