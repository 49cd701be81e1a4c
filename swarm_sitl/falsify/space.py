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
      - {edges: all, bursty: {p: [0.01, 0.5], r: 0.25}}  # any model of the registry, its ranges
      - {edges: each, model: {entry: "my_link.py:DutyCycle", params: {duty: [0, 1]}}}  # or yours

An entry names what fails, one how and optionally a window. What: ``edges`` (``all``: every edge
under one parameter, written as a sweep's ``link.HOW`` writes it, an ``into: i`` plan entry per
follower, so a search and a campaign fly the same plans; ``each``: one plan entry per graph edge,
each with its own; or a list of edges of the graph), ``links`` (``each`` or a list of followers:
their MAVLink links, ``direction`` ``up``, ``down`` or ``both``) or ``controllers`` (``each`` or a
list). How: ``loss: [lo, hi]``, ``delay_s: [lo, hi]`` (edges), ``drop: true`` (edges, links;
lockstep's MAVLink hows are loss and drop), ``kill: true`` with ``restart_after_s: [lo, hi]``
(controllers: killed at a searched instant, started again that much later), or any other link
model of the registry (``faults.link_models``) or of the user's (``model: {entry, params}``, a
file relative to the space file) on edges: a probability's range (``corrupt: [lo, hi]``), or its
parameters, each a range ``[lo, hi]`` searched or a value held (``bursty: {p: [lo, hi], r:
0.25}``). A model whose effect is not a message's own fate (``range``: with the distance;
``bandwidth``: the sender's queue) is swept, not searched. A window
(``window_s: [a, b]``): the fault acts from ``from_s`` to ``until_s`` within it, both searched, at
most ``max_duration_s`` long (a kill: happens within it); without one it acts over the whole run.
With more than one item (an entry times its edges, links or controllers) each item is also on or
off. Without a file the space is loss, cuts and delays on every edge (``default_space``).

A plan's cost (``--cost``): ``severity`` (the default) is the sum over its entries of severity
times duration [s]: a link entry's severity is its model's (``link_model.severity_of``: loss: p;
a cut: 1; a delay: ``delay_s / estimator.staleness_s``, at most 1, an estimate past staleness
being as good as lost; a model that declares none: the share of its messages lost, or late
against staleness, drawn from its ``fate``); a controller down: 1, for its downtime. ``edges`` is
the number of graph edges, MAVLink links and controllers it touches.
"""

import math
from pathlib import Path
from typing import Annotated, Any, Literal, Protocol

from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from sim_vehicles.common.entry import absolute_entry
from swarm_sitl.config.schema import SwarmConfig
from swarm_sitl.faults.link_model import declared, resolve_link_model, severity_of
from swarm_sitl.faults.link_models import LINK_MODELS
from swarm_sitl.faults.plan import FaultEntry

COSTS = ("severity", "edges")
Edge = tuple[Annotated[int, Field(ge=0)], Annotated[int, Field(ge=1)]]


class Trial(Protocol):
    """What a sampler gives values from (Optuna's ``Trial``)."""

    def suggest_float(self, name: str, low: float, high: float) -> float: ...
    def suggest_categorical(self, name: str, choices: Any) -> Any: ...


Ids = Literal["all", "each"] | list[Annotated[int, Field(ge=1)]]
#: the hows a space names by their own field (the rest: ``ModelHow``)
OWN_HOWS = ("loss", "delay_s", "drop", "kill")
#: the least probability searched (a plan's probabilities are positive)
P_LOW = 1e-6
#: the least delay searched [s] (a plan's delays are positive)
D_LOW_S = 1e-9


class ModelHow(BaseModel):
    """A link model searched by a space entry other than ``loss``, ``delay_s`` and ``drop``: a
    model of the registry by its key, or a user's (``key`` ``model`` and its ``entry``), and each
    parameter's range ``[lo, hi]`` (searched) or value (held)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    key: str
    entry: str | None = None
    params: dict[str, tuple[float, float] | float | bool] = {}

    @property
    def model(self) -> Any:
        """The model's class."""
        return resolve_link_model(self.entry) if self.entry is not None else LINK_MODELS[self.key]

    @property
    def name(self) -> str:
        return self.key if self.entry is None else self.entry.rpartition(":")[2]

    @property
    def searched(self) -> dict[str, tuple[float, float]]:
        return {k: v for k, v in self.params.items() if isinstance(v, tuple)}

    @property
    def held(self) -> dict[str, Any]:
        return {k: v for k, v in self.params.items() if not isinstance(v, tuple)}

    @model_validator(mode="after")
    def _searchable(self) -> "ModelHow":
        if self.entry is None and self.key not in LINK_MODELS:
            known = ", ".join(LINK_MODELS)
            raise ValueError(f"{self.key}: not a link model ({known}, or model: {{entry, params}})")
        model = self.model
        if self.entry is None and model.plan_form not in ("p", "params"):
            raise ValueError(
                f"{self.key}: not searched by a space (its own how, or a probability or a mapping)"
            )
        if declared(model, "needs_distance") or declared(model, "node_radio"):
            raise ValueError(
                f"{self.name}: its effect is not a message's own fate (it needs the distance, or it is "
                "a sender's queue): sweep it (swarm-sitl sweep --vary link.MODEL.PARAM) instead"
            )
        fields = model.Params.model_fields
        unknown = [k for k in self.params if k not in fields]
        if unknown:
            has = ", ".join(fields) or "none"
            raise ValueError(f"{self.name}: no parameter {unknown[0]!r} (it has {has})")
        if not self.searched:
            raise ValueError(f"{self.name}: give at least one parameter a range [lo, hi] to search")
        probability = self.entry is None and model.plan_form == "p"
        for k, (lo, hi) in self.searched.items():
            if not lo < hi:
                raise ValueError(f"{self.name}.{k}: an empty range [{lo:g}, {hi:g}] (needs low < high)")
            if probability and hi <= P_LOW:
                raise ValueError(
                    f"{self.name}.{k}: [{lo:g}, {hi:g}] ends at or below {P_LOW:g}, the least p searched"
                )
            for end in (max(lo, P_LOW) if probability else lo, hi):
                try:
                    self.params_at({k: end})
                except ValidationError as e:
                    msg = e.errors()[0]["msg"]
                    raise ValueError(f"{self.name}.{k}: {end:g} is out of its range ({msg})") from None
        return self

    def params_at(self, values: dict[str, float]) -> Any:
        """The model's ``Params`` at ``values`` (the searched ones not given: their ranges' middle)."""
        mids = {k: (lo + hi) / 2 for k, (lo, hi) in self.searched.items()}
        return self.model.Params.model_validate({**self.held, **mids, **values})

    def plan_value(self, values: dict[str, float]) -> tuple[str, Any]:
        """``(key, value)`` of a fault plan's entry with the searched parameters at ``values``."""
        params = {**self.held, **values}
        if self.entry is not None:
            return "model", {"entry": self.entry, "params": params}
        if self.model.plan_form == "p":
            return self.key, params["p"]
        return self.key, params


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
    #: any other link model, written by its key (``bursty: {p: [lo, hi], r: 0.25}``, ``corrupt:
    #: [lo, hi]``) or ``model: {entry, params}`` (``ModelHow``)
    link_model: ModelHow | None = None

    @model_validator(mode="before")
    @classmethod
    def _model_by_its_key(cls, data: Any) -> Any:
        """A registry model's key or ``model`` as ``link_model``."""
        if not isinstance(data, dict):
            return data
        keys = [k for k in data if k not in cls.model_fields and (k in LINK_MODELS or k == "model")]
        if len(keys) != 1:
            return data  # none (or two: refused by the one-how rule below, both named)
        key = keys[0]
        rest = {k: v for k, v in data.items() if k != key}
        value = data[key]
        if key == "model":
            if not isinstance(value, dict):
                raise ValueError("model: {entry: 'my_link.py:Name', params: {PARAM: [lo, hi] or a value}}")
            how = {"key": "model", **value}
        elif isinstance(value, dict):
            how = {"key": key, "params": value}
        else:
            how = {"key": key, "params": {"p": value}}
        return {**rest, "link_model": how}

    @model_validator(mode="after")
    def _one_how(self) -> "SpaceEntry":
        whats = [w for w in ("edges", "links", "controllers") if getattr(self, w) is not None]
        if len(whats) != 1:
            raise ValueError(
                f"needs exactly one of edges, links, controllers (got {', '.join(whats) or 'none'})"
            )
        hows = [h for h in OWN_HOWS if getattr(self, h) is not None]
        hows += [self.link_model.key] if self.link_model is not None else []
        if len(hows) != 1:
            raise ValueError(
                f"needs exactly one of loss, delay_s, drop, kill, or a link model "
                f"(got {', '.join(hows) or 'none'})"
            )
        allowed = {"edges": ("loss", "delay_s", "drop"), "links": ("loss", "drop"), "controllers": ("kill",)}
        if self.link_model is not None and whats[0] != "edges":
            raise ValueError(f"{whats[0]} fail by {' or '.join(allowed[whats[0]])}, not {hows[0]}")
        if self.link_model is None and hows[0] not in allowed[whats[0]]:
            raise ValueError(f"{whats[0]} fail by {' or '.join(allowed[whats[0]])}, not {hows[0]}")
        if self.kill is not None and self.restart_after_s is None:
            raise ValueError("kill: give restart_after_s: [low, high] (how long it stays down)")
        for name in ("loss", "delay_s", "window_s", "restart_after_s"):
            r = getattr(self, name)
            if r is not None and not r[0] < r[1]:
                raise ValueError(f"{name}: an empty range [{r[0]:g}, {r[1]:g}] (needs low < high)")
        if self.loss is not None and not 0 <= self.loss[0] < self.loss[1] <= 1:
            raise ValueError(f"loss: [{self.loss[0]:g}, {self.loss[1]:g}] is not within [0, 1]")
        if self.loss is not None and self.loss[1] <= P_LOW:
            raise ValueError(
                f"loss: [{self.loss[0]:g}, {self.loss[1]:g}] ends at or below {P_LOW:g}, the least p searched"
            )
        if self.delay_s is not None and self.delay_s[0] < 0:
            raise ValueError("delay_s: a delay is at least 0 s")
        if self.delay_s is not None and self.delay_s[1] <= D_LOW_S:
            lo, hi = self.delay_s
            raise ValueError(
                f"delay_s: [{lo:g}, {hi:g}] ends at or below {D_LOW_S:g} s, the least delay searched"
            )
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
        """Its how's key in a fault plan's entry (``model``: a user's link model)."""
        if self.link_model is not None:
            return self.link_model.key
        for h in OWN_HOWS:
            if getattr(self, h) is not None:
                return h
        raise AssertionError("validated: one how")

    def searched(self, f: dict[str, Any]) -> list[tuple[tuple[str, ...], tuple[float, float]]]:
        """Where in ``f`` (a plan entry of this space entry) each searched severity is, and its
        range, the milder end first: what shrinking lowers (none: a cut, all or nothing)."""
        if self.link_model is None:
            rng = self.loss or self.delay_s or self.restart_after_s
            key = {"loss": "loss", "delay_s": "delay_s", "kill": "restart_after_s"}.get(self.how)
            return [] if rng is None or key is None else [((key,), rng)]
        how = self.link_model
        if how.entry is None and how.model.plan_form == "p":
            return [((how.key,), how.searched["p"])]
        at = ("model", "params") if how.entry is not None else (how.key,)
        value = f["model"]["params"] if how.entry is not None else f[how.key]
        out = []
        model = how.model()
        for k, (lo, hi) in how.searched.items():
            low, high = (severity_of(model, how.params_at({**value, k: v}), 1.0, 1.0) for v in (lo, hi))
            out.append(((*at, k), (lo, hi) if low <= high else (hi, lo)))
        return out

    def makes(self, f: dict[str, Any]) -> bool:
        """Whether plan entry ``f`` is one of this space entry's (its how, and its what's kind)."""
        kind = "links" if "mavlink" in f else ("controllers" if "controller" in f else "edges")
        if kind != self.what or self.how not in f:
            return False
        return (
            self.link_model is None
            or self.link_model.entry is None
            or (f["model"].get("entry") == self.link_model.entry)
        )


class Space(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)

    seeds: list[Annotated[int, Field(ge=0)]] = [0]  #: the plan's seed is one of these
    entries: list[SpaceEntry] = Field(min_length=1)

    def user_models(self) -> list[str]:
        """The file entries of the users' link models this space searches (absolute, as loaded:
        ``entries_relative_to``), each once: what a worker elsewhere needs shipped."""
        named = [e.link_model.entry for e in self.entries if e.link_model is not None]
        return list(dict.fromkeys(m for m in named if m is not None))

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


def entries_relative_to(data: Any, base_dir: Path) -> Any:
    """A space file's data with each user's link model's file entry made absolute against
    ``base_dir`` (the space file's directory, as a plan file's entries are against its own)."""
    if not isinstance(data, dict) or not isinstance(data.get("entries"), list):
        return data
    entries = []
    for e in data["entries"]:
        m = e.get("model") if isinstance(e, dict) else None
        if isinstance(m, dict) and isinstance(m.get("entry"), str):
            e = {**e, "model": {**m, "entry": absolute_entry(m["entry"], base_dir)}}
        entries.append(e)
    return {**data, "entries": entries}


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
        if e.link_model is not None:
            how = e.link_model
            low = P_LOW if how.entry is None and how.model.plan_form == "p" else -math.inf
            values = {}
            for k, (lo, hi) in how.searched.items():
                values[k] = trial.suggest_float(f"{it.name}.{k}", max(lo, low), hi)
            key, value = how.plan_value(values)
            f[key] = value
        elif e.loss is not None:
            f["loss"] = trial.suggest_float(f"{it.name}.p", max(e.loss[0], P_LOW), e.loss[1])
        elif e.delay_s is not None:
            f["delay_s"] = trial.suggest_float(f"{it.name}.d", max(e.delay_s[0], D_LOW_S), e.delay_s[1])
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
    fields = FaultEntry.model_fields
    base = [
        {k: v for k, v in f.items() if v is not None and not (k in fields and v == fields[k].default)}
        for f in cfg.data()["faults"]["plan"]
    ]
    return {"seed": searched["seed"], "plan": base + searched["plan"]}


def edges_of(entry: dict[str, Any], cfg: SwarmConfig) -> list[tuple[int, int]]:
    """The graph edges a fault plan's entry acts on (``FaultEntry.edges``; none for a MAVLink
    link or a process)."""
    return FaultEntry.model_validate(entry).edges(cfg.graph_edges())


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
        if f.get("kill"):  # down from from_s for restart_after_s (at most to the end), all of it
            total += min(f["restart_after_s"], cfg.duration_s - f["from_s"])
            continue
        model, params = FaultEntry.model_validate(f).link_how
        total += severity_of(model, params, cfg.control_dt_s, cfg.estimator.staleness_s) * dur
    return total
