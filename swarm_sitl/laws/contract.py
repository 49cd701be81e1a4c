"""The law contract: what a distributed control law gets from the bench and gives back.

A law is a class. The bench builds one per follower, once, from a ``LawContext``, and calls its
``step`` once per control tick::

    class MyLaw:
        message_length = 6                      # float64 values it sends its out-neighbours
        record_fields = {"p_hat": 3}            # what it wants recorded, name -> width
        Params = MyParams                       # optional: a pydantic model or a dataclass

        def __init__(self, ctx: LawContext): ...
        def step(self, t_s: float, sample: VehicleSample,
                 inbox: Mapping[int, Received]) -> LawOutput: ...

``swarm_sitl/laws/template.py`` is a runnable one that does nothing clever; ``docs/laws.md``
walks through writing one. A config names it: ``law: {entry: "package.module:Name", params:
{...}}`` (or ``"path/to/file.py:Name"``, relative to the config file).

**What a tick is** (the same in ``sim`` and across processes). Tick ``k`` is at ``t_s = k * dt``
(plus the follower's tick phase in a staggered real-time run). The law gets its own vehicle's
sample (position, velocity, attitude as the controller reads them over MAVLink: the sample of
``t_s`` in ``sim`` and lockstep, the latest one in real time, ``sample.t_s`` saying when it holds)
and its inbox: per in-neighbour that has spoken, the newest message, with the instant its values
hold at (``Received.t_s``: the sender's tick) and its age at this tick (``age_s``: one period in
``sim`` and lockstep, what the link made it in real time or under a fault plan). An in-neighbour
whose newest message is older than ``estimator.staleness_s`` is left out of the inbox until it
speaks again; one that never spoke is not in it (at ``k = 0``, nobody has). Node 0 is the leader;
its message is the reference: ``REFERENCE`` says its layout. ``step`` returns the attitude
command for the vehicle (held until the next tick), the message for the out-neighbours (they get
it at tick ``k + 1``) and what to record.

**Rules.** A law is a pure function of its inputs and its own state: no I/O, no clock, no global
state, no randomness but ``ctx.rng`` (seeded per follower from ``law.seed``), so ``sim`` and a
lockstep run of processes give the same numbers bit for bit. Everything is SI, world ENU and body
FLU, quaternions Hamilton ``[w, x, y, z]`` rotating body to world (``docs/paper.md``). A law that
raises, or returns a non-finite command or message, or a message of another length, stops its
follower with one line naming the law and the follower (the run keeps what it recorded).
"""

from collections.abc import Mapping
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any, ClassVar, NamedTuple, Protocol, runtime_checkable

import numpy as np

from sim_vehicles.common.command import AttitudeCommand

__all__ = [
    "MAX_MESSAGE_LENGTH",
    "REFERENCE",
    "REFERENCE_LENGTH",
    "AttitudeCommand",
    "Law",
    "LawContext",
    "LawOutput",
    "Received",
    "VehicleSample",
    "reference_values",
]

#: the leader's message (node 0): the reference position p_r [m], velocity v_r [m/s],
#: acceleration a_r [m/s^2] and jerk j_r [m/s^3] at the message's instant, world ENU
REFERENCE = {"p_r": slice(0, 3), "v_r": slice(3, 6), "a_r": slice(6, 9), "j_r": slice(9, 12)}
REFERENCE_LENGTH = 12
#: the most values a law's message may have (its payload on the bus stays under 33 kB)
MAX_MESSAGE_LENGTH = 4096


def reference_values(derivatives: np.ndarray) -> np.ndarray:
    """The leader's message from its trajectory's ``derivatives(t)`` (``(5, 3)``: p, v, a, jerk,
    snap): p_r, v_r, a_r, j_r in ``REFERENCE``'s order."""
    return derivatives[0:4].reshape(REFERENCE_LENGTH)


class VehicleSample(NamedTuple):
    """What the controller knows of its own vehicle at one instant (from LOCAL_POSITION_NED and
    ATTITUDE_QUATERNION, float32 on the wire)."""

    t_s: float  #: the instant it holds at [s; the run's time]
    p_W: np.ndarray  #: position [m; world ENU]
    v_W: np.ndarray  #: velocity [m/s; world ENU]
    q_WB: np.ndarray  #: attitude [w, x, y, z; body FLU -> world ENU]


class Received(NamedTuple):
    """An in-neighbour's newest message, as the tick gets it."""

    values: np.ndarray  #: float64: ``REFERENCE`` from node 0, the law's ``message_length`` from a follower
    t_s: float  #: the instant its values hold at: the sender's tick [s]
    age_s: float  #: how old it is at this tick: ``t - t_s`` [s]


class LawOutput(NamedTuple):
    """What a tick gives back."""

    command: AttitudeCommand  #: for the vehicle's attitude loop, held until the next tick
    message: np.ndarray  #: ``message_length`` float64 values for the out-neighbours
    #: what to record at this tick: by name (each ``record_fields[name]`` values), or one float64
    #: array of them all in ``record_fields``' order (no dict to build each tick)
    record: Mapping[str, Any] | np.ndarray = MappingProxyType({})


@dataclass(frozen=True)
class LawContext:
    """What a law is built from, once per follower."""

    follower_id: int  #: this follower's id, 1..n (its graph node and its vehicle's MAVLink system id)
    in_edges: tuple[tuple[int, float], ...]  #: ``(source, weight)`` of each in-edge; source 0 is the leader
    out_neighbours: tuple[int, ...]  #: who gets its message
    control_dt_s: float  #: the control period [s]
    mass_kg: float  #: the vehicle's mass, as it reported it (MAVLink parameter MASS_KG, float32)
    max_thrust_N: float  #: its collective thrust at full throttle, as it reported it (MAX_THRUST_N)
    gravity_mps2: float  #: g [m/s^2]
    offset_m: np.ndarray  #: its place in the formation relative to the leader, delta_i [m; ENU]
    rng: np.random.Generator  #: its only source of randomness, seeded from ``law.seed`` and its id
    #: its ``params:`` from the config, validated by its ``Params`` if it declares one (an instance
    #: of it), else the mapping as written
    params: Any = field(default_factory=dict)

    @property
    def in_neighbours(self) -> tuple[int, ...]:
        return tuple(s for s, _ in self.in_edges)


@runtime_checkable
class Law(Protocol):
    """The contract (the module's docstring says what each part means)."""

    message_length: ClassVar[int]
    record_fields: ClassVar[Mapping[str, int]]

    def __init__(self, ctx: LawContext) -> None: ...

    def step(self, t_s: float, sample: VehicleSample, inbox: Mapping[int, Received]) -> LawOutput: ...
