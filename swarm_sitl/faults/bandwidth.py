"""A bandwidth budget per node: its radio sends one message at a time, at ``rate_bps``, from a
queue that holds ``queue`` messages behind the one on the air, and drops what comes to a full one.

At each tick ``k`` (time ``t_k = k dt``) a node puts one message per out-edge in its queue, in
the order of the receivers' ids. A message of ``B`` bytes (``bus.codec.message_size``: what the
bus carries) takes ``tau = 8 B / rate_bps`` on the air; message ``m`` of the tick leaves at

    D_m = max(t_k, D_{m-1}) + tau      (D_{m-1}: when the one before it left, this tick or earlier)

unless, when it comes, ``queue`` messages already wait behind the one on the air: then it is
dropped. Below saturation (``n_out tau <= dt``) nothing waits across ticks and the message to the
``m``-th receiver (0-based) leaves ``(m + 1) tau`` after its tick; above it the queue fills and, in
the long run, a fraction ``1 - dt / (n_out tau)`` of the messages is dropped (with a queue that
holds a period's work, ``queue tau >= dt``; a shorter one leaves the radio idle and drops more).

A message that has left by the next tick is on time, as any message is (lockstep: usable at tick
``k + 1``); one that leaves at ``t_k + w`` with ``w > dt`` is usable at tick ``k + ceil(w / dt)``
(real time: at ``t_k + w``). While the node is down (a process fault) it sends nothing and its
queue is lost with it. Outside the entry's ``from_s``..``until_s`` the node has no budget.

Every receiver replays its sender's queue from the plan alone (the ticks, the graph, the sizes),
so the run is the same in every process and every time (``RadioQueue``).
"""

from collections.abc import Callable
from typing import Annotated

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from swarm_sitl.faults.link_model import HARSHER_WHEN_SMALLER, Effect, Effects, MessageOnLink, StepsOnLink

KEEP_STEPS = 1024  #: how many of the newest steps' departures a queue keeps (messages come in order)


class Bandwidth(BaseModel):
    """``bandwidth:`` of a plan entry: the node's radio (the module's formulas)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    rate_bps: Annotated[float, Field(gt=0), HARSHER_WHEN_SMALLER]  #: what the radio sends [bit/s]
    #: messages that may wait behind the one on the air
    queue: Annotated[int, Field(ge=0, le=100_000), HARSHER_WHEN_SMALLER] = 16

    def air_time_s(self, size_bytes: int) -> float:
        """``tau``: how long a message of ``size_bytes`` takes on the air [s]."""
        return 8.0 * size_bytes / self.rate_bps

    def describe(self) -> str:
        return f"bandwidth {self.rate_bps:g} bit/s, queue {self.queue}"


class RadioQueue:
    """One sender's queue, replayed from the plan: ``leaves(step)`` says when the message of
    ``step`` to receiver ``index`` (of ``n_out``, in id order) left, after its tick [s], or None
    (dropped at a full queue, or not sent: the sender was down). ``down(k)``: whether the sender
    is down at tick ``k``; ``active(t_s)``: whether the budget holds at ``t_s``."""

    def __init__(
        self,
        budget: Bandwidth,
        n_out: int,
        index: int,
        size_bytes: int,
        period_s: float,
        down: Callable[[int], bool],
        active: Callable[[float], bool],
    ):
        self.budget = budget
        self.n_out = n_out
        self.index = index
        self.tau = budget.air_time_s(size_bytes)
        self.period_s = period_s
        self.down = down
        self.active = active
        #: per step from ``_first`` on: when ours left after its tick [s], or None
        self._left: list[float | None] = []
        self._first = 0
        self._in_air: list[float] = []  #: when each message still queued or on the air leaves [s]

    def leaves(self, step: int) -> float | None:
        if step < self._first:  # older than what is kept: replayed from the start
            self._left, self._first, self._in_air = [], 0, []
        while self._first + len(self._left) <= step:
            self._tick(self._first + len(self._left))
        out = self._left[step - self._first]
        if len(self._left) > 2 * KEEP_STEPS:  # (a long run keeps only its recent steps)
            cut = len(self._left) - KEEP_STEPS
            del self._left[:cut]
            self._first += cut
        return out

    def _tick(self, k: int) -> None:
        t = k * self.period_s
        if self.down(k):
            self._in_air = []
            self._left.append(None)
            return
        if not self.active(t):
            self._left.append(0.0)
            return
        in_air = [d for d in self._in_air if d > t]
        ours: float | None = None
        for m in range(self.n_out):
            if in_air and len(in_air) - 1 >= self.budget.queue:
                continue  # dropped: the queue is full
            d = max(t, in_air[-1] if in_air else t) + self.tau
            in_air.append(d)
            if m == self.index:
                ours = d - t
        self._in_air = in_air
        self._left.append(ours)


class Budget:
    """The link model of ``bandwidth:``: it acts at the sender's queue (``RadioQueue``, replayed by
    each receiver: ``edges``), not on a message's fate here."""

    Params = Bandwidth
    plan_form = "params"  #: ``bandwidth: {rate_bps, queue}`` (``link_models``)
    node_radio = True  #: a sending node's radio: one per node

    def fate(self, p: Bandwidth, m: MessageOnLink) -> Effect | None:
        return None

    def fates(self, p: Bandwidth, ms: StepsOnLink) -> Effects:
        return ms.where(np.zeros(len(ms.steps), dtype=bool), Effect())
