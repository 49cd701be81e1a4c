"""The fault plan of a run: what fails x how x when, validated at load.

A plan is the ``faults:`` section of a config, or a file given with ``swarm-sitl run --faults FILE``
(the same mapping, which replaces the config's)::

    faults:
      seed: 7                 # every random choice of the plan derives from it
      plan:
        - {edge: [1, 4], loss: 0.5}                             # half the estimates 1 -> 4 are lost
        - {edge: [0, 1], drop: true, from_s: 20, until_s: 30}   # the edge is cut for 10 s
        - {into: 4, delay_s: 0.05, jitter_s: 0.02}              # every edge into follower 4
        - {out_of: 2, duplicate: 0.1}                           # every edge out of follower 2
        - {leader_edges: true, stall: true, from_s: 5, until_s: 6}
        - {controller: 2, kill: true, from_s: 20, restart_after_s: 2}   # SIGKILL, then started again
        - {controller: 3, freeze_s: 2, from_s: 10}              # SIGSTOP for 2 s
        - {vehicle: 1, kill: true, from_s: 20}                  # a lost aircraft (its controller too)
        - {all_edges: true, range: {range_m: 40, fading_db: 4}}  # loss with distance
        - {out_of: 3, bandwidth: {rate_bps: 64000, queue: 8}}   # follower 3's radio

One entry names one *what*, one *how* and optionally *when*:

- what (links): ``edge: [src, dst]`` (an edge of the graph), ``into: i`` / ``out_of: i`` (every edge
  into or out of follower i), ``leader_edges: true`` (every edge out of node 0), ``all_edges: true``
  (every edge of the graph), ``partition:
  [[0, 1, 2], [3, 4]]`` (groups of nodes that cannot hear each other: every edge from one group to
  another; its how is ``drop`` unless it names another; a node in no group hears everyone);
- how (links): ``drop: true`` (every message), ``loss: p``, ``delay_s: d`` (plus ``jitter_s: j``,
  uniform in [0, j]), ``stall: true`` (held from ``from_s`` and released in one burst at
  ``until_s``), ``duplicate: p`` (delivered again a period later), ``reorder: p`` (held one period,
  so it comes after the next one), ``corrupt: p`` (one byte flipped: the receiver's checksum drops
  and counts it), ``bursty: {p, r, loss_bad, loss_good}`` (lost in bursts: the Gilbert-Elliott
  model with netem's parameters, ``bursts``), ``range: {range_m, exponent, fading_db, retries,
  retry_s}`` (loss and delay with the distance between the two nodes: log-distance path loss,
  ``radio_range``), ``bandwidth: {rate_bps, queue}`` (the sending node's radio: messages wait for
  their air time, a full queue drops; named by ``out_of``, ``leader_edges`` or ``all_edges``, one
  per node, ``bandwidth``), ``model: {entry, params}`` (a link model of the user's,
  ``link_model``: the fate of each message from its step, time and distance);
- what (a vehicle link): ``mavlink: i`` (follower i's link to its vehicle) with ``direction: up``
  (setpoints), ``down`` (telemetry) or ``both`` (the default); it fails by the same hows, applied to
  datagrams where the controller sends and receives them. In lockstep it fails by ``drop``,
  ``loss`` and ``corrupt`` only: a lost setpoint is a period the vehicle flies on what it holds (a
  clock-only setpoint goes in its place), a lost sample a tick that carries the one before;
- what (processes): ``controller: i``, ``vehicle: i``, ``leader: true``;
- how (processes): ``kill: true`` (SIGKILL; ``restart_after_s: d`` starts it again d seconds
  later; a vehicle is a lost aircraft and never restarts, and its controller, the companion
  computer it carries, is lost with it unless ``with_controller: false``), ``freeze_s: d``
  (SIGSTOP, SIGCONT d seconds later);
- when: ``from_s`` (default 0) and ``until_s`` (default: the end of the run): simulated seconds
  in lockstep (the time the message was sent for), run seconds in real time (its arrival).
  A process fault happens at ``from_s``.

In lockstep a process fault happens at a tick: a node planned to die at tick k kills itself with
SIGKILL when it gets there, before it publishes tick k (``edges``), so the swarm sees the
same run every time; the supervisor restarts it, and it takes up its vehicle at the restart tick
(the vehicle flies its failsafe through the gap, in simulated time). A freeze in lockstep only
costs wall time (no simulated time passes while a process is stopped).

Probabilities are drawn per message from a hash of (seed, entry, edge, step): the same plan and
seed give the same fate to every message, whatever the machine does (``fate``). Faults act where
messages are received (``edges``), so a lockstep receiver always knows a message's fate
without waiting for something that will not come.
"""

import functools
import math
from collections.abc import Iterable
from typing import Annotated, Any, Literal, NamedTuple

from pydantic import BaseModel, ConfigDict, Field, model_validator

from swarm_sitl.faults.bandwidth import Bandwidth
from swarm_sitl.faults.bursts import GilbertElliott
from swarm_sitl.faults.link_model import MessageOnLink, ModelEntry, declared
from swarm_sitl.faults.link_models import LINK_MODELS, how_of, model_of
from swarm_sitl.faults.radio_range import PathLoss

Probability = Annotated[float, Field(gt=0, le=1)]
NonNegative = Annotated[float, Field(ge=0)]

LINK_WHAT = ("edge", "into", "out_of", "leader_edges", "all_edges", "partition", "mavlink")
#: the hows of a link: the registry's models by key, and a user's own (``model``)
LINK_HOW = (*LINK_MODELS, "model")
#: the whats that name a node's radio (a model that declares ``node_radio``: a bandwidth budget)
NODE_WHAT = ("out_of", "leader_edges", "all_edges")
PROCESS_WHAT = ("controller", "vehicle", "leader")
PROCESS_HOW = ("kill", "freeze_s")


class FaultEntry(BaseModel):
    """One entry of a fault plan: one what, one how, and when."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    edge: tuple[int, int] | None = None  #: [src, dst], an edge of the graph
    into: Annotated[int, Field(ge=1)] | None = None  #: every edge into this follower
    out_of: Annotated[int, Field(ge=1)] | None = None  #: every edge out of this follower
    leader_edges: Literal[True] | None = None  #: every edge out of the leader
    all_edges: Literal[True] | None = None  #: every edge of the graph
    #: groups of nodes (0: the leader) that cannot hear each other: every edge between two groups
    partition: list[list[Annotated[int, Field(ge=0)]]] | None = None
    mavlink: Annotated[int, Field(ge=1)] | None = None  #: this follower's MAVLink link to its vehicle
    #: which way, with ``mavlink``: ``up`` (setpoints, to the vehicle), ``down`` (telemetry), ``both``
    direction: Literal["up", "down", "both"] | None = None

    drop: Literal[True] | None = None  #: every message is lost
    loss: Probability | None = None  #: each message is lost with this probability
    bursty: GilbertElliott | None = None  #: lost in bursts (``bursts.GilbertElliott``)
    range: PathLoss | None = None  #: lost and late with distance (``radio_range.PathLoss``)
    bandwidth: Bandwidth | None = None  #: the sender's radio (``bandwidth.Bandwidth``)
    delay_s: NonNegative | None = None  #: each message comes this much later [s]
    jitter_s: NonNegative = 0.0  #: plus a uniform draw in [0, jitter_s] [s] (with delay_s)
    stall: Literal[True] | None = None  #: held until ``until_s``, then released at once
    duplicate: Probability | None = None  #: delivered again one period later, with this probability
    reorder: Probability | None = None  #: held back one period (after the next), with this probability
    corrupt: Probability | None = None  #: one byte flipped, with this probability
    #: a link model of the user's and its parameters (``link_model``: ``{entry, params}``)
    model: ModelEntry | None = None

    controller: Annotated[int, Field(ge=1)] | None = None  #: this follower's controller process
    vehicle: Annotated[int, Field(ge=1)] | None = None  #: this follower's vehicle process
    leader: Literal[True] | None = None  #: the leader's process
    kill: Literal[True] | None = None  #: SIGKILL
    restart_after_s: Annotated[float, Field(gt=0)] | None = None  #: started again this much later [s]
    with_controller: bool = True  #: a lost vehicle takes its controller with it
    freeze_s: Annotated[float, Field(gt=0)] | None = None  #: SIGSTOP, then SIGCONT this much later [s]

    from_s: NonNegative = 0.0  #: the fault starts [s]
    until_s: Annotated[float, Field(gt=0)] | None = None  #: and ends [s] (default: the end of the run)

    @model_validator(mode="before")
    @classmethod
    def _partition_drops(cls, data: object) -> object:
        """A partition with no how cuts its edges (``drop``)."""
        named = isinstance(data, dict) and any(data.get(k) is not None for k in LINK_HOW + PROCESS_HOW)
        if isinstance(data, dict) and data.get("partition") is not None and not named:
            return {**data, "drop": True}
        return data

    @model_validator(mode="before")
    @classmethod
    def _registered_by_its_key(cls, data: object) -> object:
        """A model of the registry that this schema has no field for, named by its key, is the
        same as naming it by its entry (``model: {entry, params}``): a built-in added to
        ``link_models.LINK_MODELS`` is a how of every plan with no other file edited."""
        if not isinstance(data, dict):
            return data
        for key in [k for k in data if k in LINK_MODELS and k not in cls.model_fields]:
            model, value = LINK_MODELS[key], data[key]
            params = {} if model.plan_form == "flag" else ({"p": value} if model.plan_form == "p" else value)
            rest = {k: v for k, v in data.items() if k != key}
            data = {**rest, "model": {"entry": f"{model.__module__}:{model.__qualname__}", "params": params}}
        return data

    @model_validator(mode="after")
    def _one_of_each(self) -> "FaultEntry":
        all_what, all_how = LINK_WHAT + PROCESS_WHAT, LINK_HOW + PROCESS_HOW
        what = [k for k in all_what if getattr(self, k) is not None]
        how = [k for k in all_how if getattr(self, k) is not None]
        if len(what) != 1:
            raise ValueError(f"name exactly one of {', '.join(all_what)} (what fails); got {what or 'none'}")
        if len(how) != 1:
            raise ValueError(f"name exactly one of {', '.join(all_how)} (how it fails); got {how or 'none'}")
        if (what[0] in PROCESS_WHAT) != (how[0] in PROCESS_HOW):
            kind = "a process" if what[0] in PROCESS_WHAT else "a link"
            allowed = PROCESS_HOW if what[0] in PROCESS_WHAT else LINK_HOW
            raise ValueError(f"{what[0]} is {kind}: it fails by {', '.join(allowed)}, not {how[0]}")
        if how[0] in LINK_HOW:
            self._fits_its_model(what[0], how[0])
        if self.restart_after_s is not None and not self.kill:
            raise ValueError("restart_after_s goes with kill")
        if self.restart_after_s is not None and self.vehicle is not None:
            raise ValueError("a killed vehicle is a lost aircraft: it does not restart")
        if self.direction is not None and self.mavlink is None:
            raise ValueError("direction goes with mavlink")
        if not self.with_controller and self.vehicle is None:
            raise ValueError("with_controller goes with vehicle")
        if self.is_process and self.until_s is not None:
            raise ValueError(
                "a process fault happens at from_s (use restart_after_s or freeze_s for how long)"
            )
        if self.jitter_s and self.delay_s is None:
            raise ValueError("jitter_s goes with delay_s")
        if self.stall and self.until_s is None:
            raise ValueError("a stall needs until_s (when the held messages are released)")
        if self.partition is not None:
            nodes = [n for g in self.partition for n in g]
            if len(self.partition) < 2 or any(not g for g in self.partition):
                raise ValueError("a partition is two or more groups of nodes, none empty")
            if len(set(nodes)) != len(nodes):
                raise ValueError("a node is in two groups of the partition")
        if self.until_s is not None and self.until_s <= self.from_s:
            raise ValueError(f"until_s ({self.until_s:g}) must be after from_s ({self.from_s:g})")
        return self

    def _fits_its_model(self, what: str, how: str) -> None:
        """What the entry's model declares of itself (``link_model.declared``) against its what."""
        model = model_of(self)
        if model is None:  # a user's model in a run's record: read, not imported
            return
        if self.mavlink is not None and not declared(model, "on_mavlink"):
            raise ValueError(
                f"{how} acts on bus edges: a vehicle's MAVLink link is on board (no distance, "
                "no shared radio)"
            )
        if declared(model, "node_radio") and what not in NODE_WHAT:
            raise ValueError(
                f"a {how} budget is a sending node's radio: name it with {', '.join(NODE_WHAT)}, not {what}"
            )

    @property
    def is_process(self) -> bool:
        return self.kill is not None or self.freeze_s is not None

    @functools.cached_property
    def link_how(self) -> tuple[Any, Any]:
        """``(model, params)`` of a link entry (``link_models.how_of``), made once (kept in the
        instance's ``__dict__``: read per message, a plain attribute lookup)."""
        return how_of(self)

    @property
    def needs_distance(self) -> bool:
        """Whether a link entry's model reads the distance between sender and receiver
        (``range``, or a model of the user's that says so): its receiver gives it."""
        return declared(self.link_how[0], "needs_distance")

    @property
    def process(self) -> str:
        """The process this entry acts on, as the supervisor names it (``controller_2``, ``leader``)."""
        if self.controller is not None:
            return f"controller_{self.controller}"
        if self.vehicle is not None:
            return f"vehicle_{self.vehicle}"
        return "leader" if self.leader else ""

    @property
    def what(self) -> str:
        if self.is_process:
            return self.process
        if self.edge is not None:
            return f"edge {self.edge[0]}->{self.edge[1]}"
        if self.partition is not None:
            return "partition " + " | ".join(",".join(map(str, g)) for g in self.partition)
        if self.mavlink is not None:
            way = {"up": "uplink", "down": "downlink"}.get(self.direction or "both", "both ways")
            return f"MAVLink of vehicle {self.mavlink}, {way}"
        if self.into is not None:
            return f"edges into {self.into}"
        if self.out_of is not None:
            return f"edges out of {self.out_of}"
        if self.all_edges:
            return "every edge"
        return "leader's edges"

    @property
    def how(self) -> str:
        if self.kill:
            if self.vehicle is not None:
                return "lost" + (" with its controller" if self.with_controller else "")
            return "kill" + (f", restart after {self.restart_after_s:g} s" if self.restart_after_s else "")
        if self.freeze_s is not None:
            return f"freeze {self.freeze_s:g} s"
        if self.drop:
            return "drop"
        if self.stall:
            return "stall"
        if self.bursty is not None:
            return self.bursty.describe()
        if self.range is not None:
            return self.range.describe()
        if self.bandwidth is not None:
            return self.bandwidth.describe()
        if self.model is not None:
            return self.model.describe()
        if self.delay_s is not None:
            return f"delay {self.delay_s:g} s" + (f" + U(0, {self.jitter_s:g}) s" if self.jitter_s else "")
        for k in ("loss", "duplicate", "reorder", "corrupt"):
            p = getattr(self, k)
            if p is not None:
                return f"{k} {p:g}"
        raise AssertionError("validated: one how")

    def edges(self, graph_edges: Iterable[tuple[int, int]]) -> list[tuple[int, int]]:
        """The graph's edges this entry names (none for a process fault)."""
        es = list(graph_edges)
        if self.is_process or self.mavlink is not None:
            return []
        if self.edge is not None:
            return [e for e in es if e == tuple(self.edge)]
        if self.partition is not None:
            group = {n: g for g, nodes in enumerate(self.partition) for n in nodes}
            return [e for e in es if e[0] in group and e[1] in group and group[e[0]] != group[e[1]]]
        if self.into is not None:
            return [e for e in es if e[1] == self.into]
        if self.out_of is not None:
            return [e for e in es if e[0] == self.out_of]
        if self.all_edges:
            return es
        return [e for e in es if e[0] == 0]

    def victims(self) -> list[str]:
        """The processes this entry stops (a lost vehicle: its controller too, unless not)."""
        if self.vehicle is not None and self.kill and self.with_controller:
            return [self.process, f"controller_{self.vehicle}"]
        return [self.process] if self.is_process else []

    def active(self, t_s: float, end_s: float) -> bool:
        return self.from_s <= t_s < (end_s if self.until_s is None else self.until_s)


class FaultPlan(BaseModel):
    """``faults:`` of a config: the plan's entries and the seed of its random draws."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    seed: Annotated[int, Field(ge=0, lt=2**63)] = 0  #: of every random draw: the same seed, the same faults
    plan: list[FaultEntry] = []  #: the entries, each one what, one how and when

    def check_against(self, graph_edges: list[tuple[int, int]], n_followers: int, duration_s: float) -> None:
        """Cross-checks with the rest of the config; raises ``ValueError`` naming the entry."""
        for j, f in enumerate(self.plan):
            where = f"faults.plan.{j}"
            for key in ("into", "out_of", "controller", "vehicle", "mavlink"):
                node = getattr(f, key)
                if node is not None and not 1 <= node <= n_followers:
                    raise ValueError(f"{where}.{key}: follower {node} is not 1..{n_followers}")
            for node in [n for g in f.partition or [] for n in g]:
                if node > n_followers:
                    raise ValueError(f"{where}.partition: node {node} is not 0..{n_followers}")
            if not f.is_process and f.mavlink is None and not f.edges(graph_edges):
                raise ValueError(f"{where}: {f.what} is not in the graph")
            end = f.from_s + (f.restart_after_s or f.freeze_s or 0.0)
            if f.is_process and end >= duration_s:
                raise ValueError(
                    f"{where}: {f.what} is back at {end:g} s, not within the run (0..{duration_s:g} s)"
                )
            if f.from_s >= duration_s:
                raise ValueError(
                    f"{where}.from_s: {f.from_s:g} s is not within the run (0..{duration_s:g} s)"
                )
            if f.until_s is not None and f.until_s > duration_s:
                raise ValueError(
                    f"{where}.until_s: {f.until_s:g} s is past the end of the run ({duration_s:g} s)"
                )

        budgeted: dict[int, int] = {}  # sender -> the entry that gives its radio a budget
        for j, f in enumerate(self.plan):
            for s in sorted({s for s, _ in f.edges(graph_edges)}) if f.bandwidth is not None else []:
                if s in budgeted:
                    raise ValueError(
                        f"faults.plan.{j}: node {s}'s radio already has a bandwidth budget "
                        f"(faults.plan.{budgeted[s]}); a node has one"
                    )
                budgeted[s] = j

        killed: dict[str, float] = {}
        for j, f in sorted(enumerate(self.plan), key=lambda jf: jf[1].from_s):
            if f.kill:
                for name in f.victims():
                    if name in killed and not f.from_s > killed[name]:
                        raise ValueError(f"faults.plan.{j}: {name} is killed again before it is back")
                    killed[name] = math.inf if f.restart_after_s is None else f.from_s + f.restart_after_s

    def check_lockstep(self) -> None:
        """What a lockstep run cannot do, as a ``ValueError`` naming the entry (one line)."""
        for j, f in enumerate(self.plan):
            if f.mavlink is not None and not declared(model_of(f), "mavlink_in_lockstep"):
                hows = ", ".join(k for k, m in LINK_MODELS.items() if declared(m, "mavlink_in_lockstep"))
                raise ValueError(
                    f"faults.plan.{j}: in lockstep a MAVLink link fails by {hows} "
                    "(a lost setpoint or sample is a period on what was there); "
                    f"fly {f.how} on it in a real-time run"
                )
            if f.vehicle is not None and f.kill and not f.with_controller:
                raise ValueError(
                    f"faults.plan.{j}: in lockstep a lost vehicle takes its controller with it "
                    "(its controller would wait for samples that never come); "
                    "lose a vehicle alone in a real-time run"
                )

    def outages(self, period_s: float) -> dict[int, list[tuple[int, int | None]]]:
        """Lockstep: per node (0 the leader, i a follower's controller) the ticks it is down,
        ``(first, back)`` with ``back`` the tick it resumes at (None: never)."""
        out: dict[int, list[tuple[int, int | None]]] = {}
        for f in self.plan:
            if not f.kill:
                continue
            node = 0 if f.leader else (f.controller if f.controller is not None else f.vehicle)
            if f.vehicle is not None and not f.with_controller:
                continue  # its controller lives on
            assert node is not None
            k = tick_of(f.from_s, period_s)
            back = None if f.restart_after_s is None else k + round(f.restart_after_s / period_s)
            out.setdefault(node, []).append((k, back))
        return out

    def on_mavlink(self, vehicle: int, uplink: bool) -> list[tuple[int, FaultEntry]]:
        """``(entry index, entry)`` of every entry acting on ``vehicle``'s MAVLink link, one way."""
        way = "up" if uplink else "down"
        return [
            (j, f)
            for j, f in enumerate(self.plan)
            if f.mavlink == vehicle and (f.direction or "both") in (way, "both")
        ]

    def process_faults(self) -> list[tuple[int, FaultEntry]]:
        return [(j, f) for j, f in enumerate(self.plan) if f.is_process]

    def on_edge(self, src: int, dst: int, graph_edges: list[tuple[int, int]]) -> list[tuple[int, FaultEntry]]:
        """``(entry index, entry)`` of every entry acting on the edge ``src -> dst``, in plan order."""
        return [(j, f) for j, f in enumerate(self.plan) if (src, dst) in f.edges(graph_edges)]


# -- the fate of one message ---------------------------------------------------------------------
class Fate(NamedTuple):
    """What the plan does to one message."""

    lost: bool = False
    corrupt: bool = False
    delay_s: float = 0.0  #: how much later than on time it is delivered [s]
    duplicate: bool = False  #: delivered a second time, one period after the first
    faults: tuple[int, ...] = ()  #: the plan entries that acted on it
    out_of_range: bool = False  #: lost by a range entry (every attempt failed)
    retried: bool = False  #: got through a range entry at a second attempt or later


ON_TIME = Fate()


def fate(
    seed: int,
    rules: list[tuple[int, FaultEntry]],
    channel: int,
    key: int,
    t_s: float,
    end_s: float,
    period_s: float,
    step: int | None = None,
    distance_m: float = math.nan,
) -> Fate:
    """The fate of message ``key`` (its step) on ``channel`` at time ``t_s``, under ``rules``
    (``FaultPlan.on_edge``): entries act in plan order, a loss ends it. ``step``: the message's
    place in its stream, for a bursty entry's chain (default ``key``); ``distance_m``: between its
    sender and receiver when it was sent, for a range entry. A bandwidth entry acts at the
    sender's queue, not here (``edges``)."""
    corrupt = duplicate = retried = False
    delay = 0.0
    acted: list[int] = []
    chain = -1 if step is None else step
    for j, f in rules:
        if not f.active(t_s, end_s):
            continue
        model, params = f.link_how
        effect = model.fate(params, MessageOnLink(seed, j, channel, key, t_s, period_s, distance_m, chain))
        if effect is None:
            continue
        if effect.lost:
            return Fate(True, faults=(*acted, j), out_of_range=effect.out_of_range)
        corrupt = corrupt or effect.corrupt
        delay += effect.delay_s
        duplicate = duplicate or effect.duplicate
        retried = retried or effect.retried
        acted.append(j)
    if not acted:
        return ON_TIME
    return Fate(False, corrupt, delay, duplicate, tuple(acted), retried=retried)


def tick_of(t_s: float, period_s: float) -> int:
    """The first control tick at or after ``t_s``."""
    return math.ceil(t_s / period_s - 1e-9)


def down_at(outages: list[tuple[int, int | None]], step: int) -> bool:
    """Whether ``step`` falls in one of a node's ``outages``."""
    return any(k <= step and (back is None or step < back) for k, back in outages)


def mavlink_channel(vehicle: int, uplink: bool) -> int:
    """The channel number of one way of a vehicle's MAVLink link in ``fate``'s draws."""
    return ((1 if uplink else 2) << 32) | vehicle


def edge_channel(src: int, dst: int) -> int:
    """The channel number of an edge in ``fate``'s draws."""
    return (src << 16) | dst
