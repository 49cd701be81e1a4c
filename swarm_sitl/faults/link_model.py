"""The link-model plug-in point: what happens to one message on one link, from what it needs.

A fault plan names how a link fails. The built-in hows are its keys (``drop``, ``loss``,
``bursty``, ``range``, ``bandwidth``, ``delay_s``, ``stall``, ``duplicate``, ``reorder``,
``corrupt``), each a model of this contract in its own module (``link_models.LINK_MODELS``); a
user's own is an entry::

    - {all_edges: true, model: {entry: "my_link.py:DistanceDelay", params: {speed_mps: 200}}}

(``"package.module:Name"`` or ``"path/file.py:Name"``, a relative path relative to the config or
the plan file that holds it). **The contract** of such a class, checked when the plan loads (one
line naming the entry otherwise):

- ``Params``: a pydantic model of its parameters, each with its range (``Field(gt=0, le=1)``);
  the entry's ``params`` are validated by it at load, and a name it does not declare is refused
  (one line) whether or not the model forbids extra keys;
- ``fate(params, m) -> Effect | None``: a pure function of ``m`` (``MessageOnLink``: the plan's
  seed, the entry's index, the link's channel, the message's step and time, the control period,
  and the distance between its sender and receiver when it was sent) and the parameters: the
  message is lost, corrupted, late by ``delay_s`` or duplicated (``Effect``), or untouched
  (None). Random draws come from ``m.uniform(salt)``, a hash of (seed, entry, link, step, salt):
  the same plan and seed give every message the same fate in lockstep, in real time and twice;
- ``needs_distance`` (optional, default False): whether ``m.distance_m`` is needed (the receiver
  then waits for its own position of the message's step, as for ``range``);
- ``fates(params, ms) -> Effects`` (optional): the fates of many steps of one link at once
  (``StepsOnLink``: arrays of steps and times; ``ms.uniform(salt)`` draws for each), equal to
  ``fate`` step for step. A lockstep stage then reads each message's fate from a table drawn a
  block of steps at a time (``fate_table``) rather than calling ``fate`` per message; every
  built-in model but ``range`` (which needs each message's distance) has it, held to ``fate``
  by ``tests/test_link_models.py``.

- of a parameter that hurts more as it gets smaller (a radio's range), ``HARSHER_WHEN_SMALLER``
  in its annotation (``range_m: Annotated[float, Field(gt=0), HARSHER_WHEN_SMALLER]``): a campaign
  reads its breaking point from the largest value down, ``falsify`` shrinks it upward;
- what it declares of itself (class attributes, each optional; ``declared`` reads them with
  ``DECLARED``'s defaults): ``on_mavlink`` (it may act on a vehicle's MAVLink link: no distance,
  no shared radio; default False), ``mavlink_in_lockstep`` (and on one in lockstep, where a
  datagram may be lost or corrupted but never held; default False), ``node_radio`` (it is a
  sending node's radio, one per node; default False) and ``severity(params, period_s,
  staleness_s)`` (how much of a link it takes, in [0, 1]: ``falsify``'s cost; default: drawn from
  ``fate``, ``severity_of``). A plan, ``check``, ``sweep`` and ``falsify`` read these, never a
  model's name.

A model acts in plan order with the others on the link (``plan.fate``: a loss ends a message's
fate, delays add). A user's acts on the bus's edges (not on a vehicle's MAVLink link).
"""

import math
from dataclasses import dataclass
from typing import Any, NamedTuple, Protocol

import numpy as np
from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    PrivateAttr,
    ValidationError,
    ValidationInfo,
    model_validator,
)

from sim_vehicles.common.contract import missing_members
from sim_vehicles.common.entry import EntryError, declared_params, load_entry, one_line, undeclared_line
from swarm_sitl.faults.draws import uniform_at, uniforms


class Effect(NamedTuple):
    """What a link model does to one message."""

    lost: bool = False
    corrupt: bool = False  #: one byte flipped (the receiver's checksum drops it)
    delay_s: float = 0.0  #: how much later than on time [s]
    duplicate: bool = False  #: delivered a second time, one period after the first
    out_of_range: bool = False  #: lost because every attempt failed (``range``; counted apart)
    retried: bool = False  #: got through at a second attempt or later (``range``)


@dataclass(frozen=True)
class MessageOnLink:
    """One message on one link, as a model sees it."""

    seed: int  #: the plan's
    entry: int  #: the plan entry's index
    channel: int  #: the link's (``plan.edge_channel``)
    step: int  #: the tick the message was sent for
    t_s: float  #: its time: simulated (lockstep, the time it was sent for) or run seconds (real time)
    period_s: float  #: the control period [s]
    distance_m: float = math.nan  #: sender to receiver when it was sent (``needs_distance``) [m]
    #: its place in its stream, for a model with a chain of states (``bursty``: per tick in
    #: lockstep, where a MAVLink datagram's ``step`` is its stamp in ms); default ``step``
    chain_step: int = -1

    @property
    def chain(self) -> int:
        return self.step if self.chain_step < 0 else self.chain_step

    def uniform(self, salt: int) -> float:
        """A uniform draw in [0, 1) of (seed, entry, link, step, ``salt``)."""
        return uniform_at(self.seed, self.entry, self.channel, self.step, salt)


class Effects(NamedTuple):
    """What a link model does to each of many messages (``fates``): arrays, one element per step."""

    lost: np.ndarray  #: bool
    corrupt: np.ndarray  #: bool
    delay_s: np.ndarray  #: float [s]
    duplicate: np.ndarray  #: bool


@dataclass(frozen=True)
class StepsOnLink:
    """Many messages of one link, one per step of ``steps``, as a model's ``fates`` sees them
    (``MessageOnLink``'s fields, the step and time as arrays; no distance)."""

    seed: int
    entry: int
    channel: int
    steps: np.ndarray  #: int64, ascending, >= 0
    t_s: np.ndarray  #: each message's time [s]
    period_s: float
    #: each message's place in its stream (``MessageOnLink.chain``); None: its step
    chain_steps: np.ndarray | None = None

    @property
    def chains(self) -> np.ndarray:
        return self.steps if self.chain_steps is None else self.chain_steps

    def uniform(self, salt: int) -> np.ndarray:
        """``MessageOnLink.uniform(salt)`` of each step."""
        return uniforms(self.seed, self.entry, self.channel, self.steps, salt)

    def where(self, mask: np.ndarray, effect: Effect) -> Effects:
        """``effect`` on the messages of ``mask``, none on the others."""
        return Effects(
            mask & effect.lost,
            mask & effect.corrupt,
            np.where(mask, effect.delay_s, 0.0),
            mask & effect.duplicate,
        )


#: the validation context of a config read from a run directory (``config.load.load_recorded``):
#: its plug-ins are named, not imported
RECORDED = {"recorded": True}


def recorded(info: ValidationInfo) -> bool:
    """Whether a config is being read as a run's record (``RECORDED``)."""
    return isinstance(info.context, dict) and bool(info.context.get("recorded"))


class LinkModel(Protocol):
    """The contract of a link model (module docstring): a plug-in is held to what this declares
    (``sim_vehicles.common.contract``); what it may declare besides is ``DECLARED``."""

    Params: type[BaseModel]

    def fate(self, params: Any, m: MessageOnLink) -> Effect | None: ...


class LinkModelError(ValueError):
    """A link-model entry that cannot be flown; one line naming it."""


class ModelEntry(BaseModel):
    """``model:`` of a plan entry: a user's link model and its parameters, resolved at load."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    entry: str  #: ``"my_link.py:Name"`` or ``"package.module:Name"``
    params: dict[str, Any] = {}  #: validated by the model's ``Params``

    _model: Any = PrivateAttr(default=None)
    _params: Any = PrivateAttr(default=None)

    @model_validator(mode="after")
    def _resolve(self, info: ValidationInfo) -> "ModelEntry":
        if recorded(info):  # a run's record: read, never imported
            return self
        cls = resolve_link_model(self.entry)
        unknown = undeclared_line(self.params, declared_params(cls.Params), "it")
        if unknown is not None:  # (whatever the model's own Params would let through)
            raise ValueError(f"params: {unknown} (link model {self.entry})")
        try:
            self._params = cls.Params.model_validate(dict(self.params))
        except ValidationError as e:
            err = e.errors()[0]
            where = ".".join(str(p) for p in err["loc"])
            msg = err["msg"].removeprefix("Value error, ")
            raise ValueError(f"params.{where}: {msg} (link model {self.entry})") from None
        self._model = cls()
        return self

    @property
    def model(self) -> Any:
        """The model (an instance of the entry's class)."""
        return self._model

    @property
    def parsed_params(self) -> Any:
        """Its parameters, validated by its ``Params``."""
        return self._params

    def describe(self) -> str:
        shown = ", ".join(f"{k} {v}" for k, v in self.params.items())
        return f"{self.entry.rpartition(':')[2]}" + (f" ({shown})" if shown else "")


#: how a missing member of the contract is named in the one line that says so
SAID = {"Params": "Params (a pydantic model of its parameters)", "fate": "fate(params, message) method"}


def resolve_link_model(entry: str) -> Any:
    """The class ``entry`` names, imported and held to the contract (module docstring)."""
    try:
        cls = load_entry(entry, "swarm_sitl_link")
    except EntryError as e:
        raise LinkModelError(str(e)) from None
    if not isinstance(cls, type):
        raise LinkModelError(f"link model {entry!r} is a {type(cls).__name__}, not a class")
    missing = missing_members(cls, LinkModel) or ([] if callable(getattr(cls, "fate", None)) else ["fate"])
    if missing:
        said = ", ".join(SAID.get(name, name) for name in missing)
        raise LinkModelError(f"link model {entry!r} does not meet the link-model contract: no {said}")
    params = cls.Params  # type: ignore[attr-defined]  # (checked present just above)
    if not (isinstance(params, type) and issubclass(params, BaseModel)):
        raise LinkModelError(f"link model {entry!r}: Params must be a pydantic model of its parameters")
    try:
        cls()
    except Exception as e:
        raise LinkModelError(f"link model {entry!r}: building it raised {one_line(e)}") from None
    return cls


#: a parameter's declaration that it hurts more as it gets smaller (module docstring)
HARSHER_WHEN_SMALLER = Field(json_schema_extra={"harsher": "when smaller"})


def harsher_when_smaller(params: type[BaseModel], name: str) -> bool:
    """Whether parameter ``name`` of ``params`` declares ``HARSHER_WHEN_SMALLER``."""
    extra = params.model_fields[name].json_schema_extra
    return isinstance(extra, dict) and extra.get("harsher") == "when smaller"


#: what a model may declare of itself (module docstring), and what it is when it does not
DECLARED: dict[str, bool] = {
    "needs_distance": False,
    "on_mavlink": False,
    "mavlink_in_lockstep": False,
    "node_radio": False,
}


def declared(model: Any, name: str) -> bool:
    """What ``model`` (a class or an instance) declares of ``name`` (``DECLARED``)."""
    return bool(getattr(model, name, DECLARED[name]))


#: ``severity_of``'s draws: messages of one link, from one plan seed
SEVERITY_STEPS, SEVERITY_SEED = 2048, 0


def severity_of(model: Any, params: Any, period_s: float, staleness_s: float) -> float:
    """How much of a link ``model`` takes under ``params``, in [0, 1]: its own ``severity`` if it
    declares one, else the one drawn from its ``fate`` (``drawn_severity``)."""
    own = getattr(model, "severity", None)
    if callable(own):
        return min(1.0, max(0.0, float(own(params, period_s, staleness_s))))
    return drawn_severity(model, params, period_s, staleness_s)


def drawn_severity(model: Any, params: Any, period_s: float, staleness_s: float) -> float:
    """The mean over ``SEVERITY_STEPS`` consecutive messages of one link, drawn from ``model``'s
    ``fate``, of what each loses: lost or corrupted, 1; late, its delay over ``staleness_s``, at
    most 1 (an estimate past staleness is as good as lost); duplicated or on time, 0."""
    total = 0.0
    for step in range(SEVERITY_STEPS):
        m = MessageOnLink(SEVERITY_SEED, 0, 0, step, step * period_s, period_s)
        e = model.fate(params, m) or Effect()
        total += 1.0 if (e.lost or e.corrupt) else min(1.0, max(0.0, e.delay_s) / staleness_s)
    return total / SEVERITY_STEPS


#: ``fates_disagreement``: blocks of consecutive steps drawn, and each block's length
CHECK_BLOCKS, CHECK_BLOCK_STEPS = 4, 512


def _shown(lost: bool, corrupt: bool, delay_s: float, duplicate: bool) -> str:
    if lost:
        return "lost"
    parts = [w for w, on in (("corrupt", corrupt), ("duplicated", duplicate)) if on]
    return ", ".join(parts + ([f"{delay_s:g} s late"] if delay_s else [])) or "on time"


def fates_disagreement(model: Any, params: Any, period_s: float, seed: int = 0) -> str | None:
    """Where a model's ``fates`` gives a message another fate than its ``fate`` (the contract
    wants them equal), on ``CHECK_BLOCKS`` blocks of consecutive steps drawn from ``seed`` (random
    links, starts and plan seeds): one line naming the first such message, or what raised; None
    where they agree or the model has no ``fates``."""
    if not callable(getattr(model, "fates", None)):
        return None
    rng = np.random.default_rng(seed)
    for _ in range(CHECK_BLOCKS):
        plan_seed, channel = int(rng.integers(0, 2**63 - 1)), int(rng.integers(0, 2**31))
        start = int(rng.integers(0, 100_000))
        steps = np.arange(start, start + CHECK_BLOCK_STEPS, dtype=np.int64)
        try:
            many = model.fates(params, StepsOnLink(plan_seed, 0, channel, steps, steps * period_s, period_s))
            lost, corrupt = np.asarray(many.lost, bool), np.asarray(many.corrupt, bool)
            delay, dup = np.asarray(many.delay_s, float), np.asarray(many.duplicate, bool)
        except Exception as e:
            return f"fates() raised {one_line(e)}"
        if not all(a.shape == steps.shape for a in (lost, corrupt, delay, dup)):
            return f"fates() gave arrays of another length than the {len(steps)} steps asked for"
        for k, step in enumerate(steps.tolist()):
            m = MessageOnLink(plan_seed, 0, channel, step, step * period_s, period_s)
            try:
                one = model.fate(params, m) or Effect()
            except Exception as e:
                return f"fate() raised {one_line(e)} at step {step}"
            a = (bool(one.lost), bool(one.corrupt), float(one.delay_s), bool(one.duplicate))
            b = (bool(lost[k]), bool(corrupt[k]), float(delay[k]), bool(dup[k]))
            if a[0] != b[0] or (not a[0] and a != b):
                return (
                    f"fates() and fate() disagree at step {step} (plan seed {plan_seed}, link {channel}): "
                    f"fate() says {_shown(*a)}, fates() {_shown(*b)}"
                )
    return None
