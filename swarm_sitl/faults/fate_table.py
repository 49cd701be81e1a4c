"""The fates of one link's messages in lockstep, drawn a block of ticks at a time: ``FateTable``.

``plan.fate`` gives one message its fate by asking each of the link's entries in plan order. In
lockstep a message's fate depends on its tick alone, so when every entry's link model can give
the fates of many messages at once (``fates``, the optional part of the link-model contract,
``link_model``), the fate of a tick's message is read here: the entries' effects for ``BLOCK``
ticks are drawn with numpy and combined as ``plan.fate`` combines them (plan order, each within
its window, a loss ends it, delays add in order: the same numbers, bit for bit;
``tests/test_fate_table.py``). An edge's stage (``in_edges``) and ``sim``'s MAVLink links
(``running.sim_plan``) read theirs here; it is what keeps ``sim`` under a plan on every message
close to ``sim`` without one (``docs/performance.md``).

A tick's message is keyed, timed and placed in its stream as ``plan.fate`` is asked for it:

- on an edge, by its step ``k``, at ``k * period_s``;
- on a MAVLink link (``stamp_ms``), by its ``time_boot_ms`` ``round(k * period_s * 1000)``, at
  that many ms, and placed at that over the period in ms (``faults.mavlink``'s lockstep keys).
"""

import numpy as np

from swarm_sitl.faults.link_model import StepsOnLink
from swarm_sitl.faults.plan import ON_TIME, Fate, FaultEntry

BLOCK = 512  #: ticks drawn at once
_LOST = Fate(True)


def batched(rules: list[tuple[int, FaultEntry]]) -> bool:
    """Whether every entry of ``rules`` can give many fates at once (none needs the distance)."""
    return all(callable(getattr(f.link_how[0], "fates", None)) and not f.needs_distance for _, f in rules)


class FateTable:
    """``plan.fate`` of each tick's message of one link (``rules``: all ``batched``) on
    ``channel``; ``stamp_ms``: keyed by ``time_boot_ms`` (a MAVLink link), else by step."""

    def __init__(
        self,
        seed: int,
        rules: list[tuple[int, FaultEntry]],
        channel: int,
        end_s: float,
        period_s: float,
        stamp_ms: bool = False,
    ):
        self.seed, self.rules, self.channel = seed, rules, channel
        self.end_s, self.period_s, self.stamp_ms = end_s, period_s, stamp_ms
        self._blocks: dict[int, list[Fate]] = {}
        #: the block last read and its first tick (none yet: no tick k >= 0 is within it)
        self._first: int = -2 * BLOCK
        self._block: list[Fate] = []

    def at(self, k: int) -> Fate:
        """The fate of tick ``k``'s message."""
        j = k - self._first
        if 0 <= j < BLOCK:
            return self._block[j]
        self._block = self._fates_of(k // BLOCK)
        self._first = k // BLOCK * BLOCK
        return self._block[k - self._first]

    def _fates_of(self, b: int) -> list[Fate]:
        """Block ``b``'s fates, drawn when first asked for."""
        block = self._blocks.get(b)
        if block is None:
            block = self._blocks[b] = self._draw(b)
            self._blocks.pop(b - 2, None)  # (ticks come in order, give or take a delay)
        return block

    def _messages(self, ticks: np.ndarray, j: int) -> StepsOnLink:
        """Entry ``j``'s view of the messages of ``ticks``."""
        if not self.stamp_ms:
            return StepsOnLink(self.seed, j, self.channel, ticks, ticks * self.period_s, self.period_s)
        ms = np.round(ticks * self.period_s * 1000).astype(np.int64)
        chain = ms // round(self.period_s * 1000)
        return StepsOnLink(self.seed, j, self.channel, ms, ms / 1000, self.period_s, chain)

    def _draw(self, b: int) -> list[Fate]:
        ticks = np.arange(b * BLOCK, (b + 1) * BLOCK, dtype=np.int64)
        n = len(ticks)
        lost = np.zeros(n, dtype=bool)
        corrupt = np.zeros(n, dtype=bool)
        duplicate = np.zeros(n, dtype=bool)
        delay = np.zeros(n)
        for j, f in self.rules:
            ms = self._messages(ticks, j)
            until = self.end_s if f.until_s is None else f.until_s
            on = (f.from_s <= ms.t_s) & (ms.t_s < until)
            if not on.any():
                continue
            model, params = f.link_how
            e = model.fates(params, ms)
            lost |= on & e.lost
            corrupt |= on & e.corrupt
            duplicate |= on & e.duplicate
            delay = delay + np.where(on, e.delay_s, 0.0)  # (in plan order, as ``fate`` adds them)
        fates: list[Fate] = [ON_TIME] * n
        for s in np.flatnonzero(lost).tolist():
            fates[s] = _LOST
        c, d, u = corrupt.tolist(), delay.tolist(), duplicate.tolist()  # (Python's bools and floats)
        for s in np.flatnonzero(~lost & (corrupt | duplicate | (delay != 0.0))).tolist():
            fates[s] = Fate(False, c[s], d[s], u[s])
        return fates
