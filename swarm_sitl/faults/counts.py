"""What a fault stage counts per in-edge or per way of a MAVLink link (``EdgeStats``), and the
names of those counts in a file that outlives a killed process (``NamedCounts``), read back by the
run's summary. No zenoh here: the summary's readers import it.
"""

import math
from typing import Any

import numpy as np


class _Count:
    """One of ``BoundEdgeStats``'s counts, an element of its array: ``st.lost += 1`` stores there."""

    def __init__(self, k: int):
        self.k = k

    def __get__(self, st: "BoundEdgeStats", owner: object = None) -> int:
        return int(st.bound[self.k])

    def __set__(self, st: "BoundEdgeStats", v: int) -> None:
        st.bound[self.k] = v


class EdgeStats:
    """What one in-edge (or one way of a MAVLink link) carried, counted at its receiver. The
    counts are plain attributes (a count is a Python int: ``sim`` counts every message, and a
    numpy element, or a descriptor, cost it a read or write each), until ``bind`` moves them
    into an int64 array in a file that outlives the process (``NamedCounts``): a killed
    incarnation's counts still add up in the run's summary."""

    FIELDS = (
        "received",
        "delivered",
        "lost",
        "corrupt",
        "delayed",
        "duplicated",
        "loss_runs",
        "out_of_range",
        "retried",
        "queue_full",
        "held",
    )

    def __init__(self) -> None:
        self.received = 0  #: arrived (over zenoh, or as datagrams)
        self.delivered = 0  #: handed on (a duplicate counts twice)
        self.lost = 0  #: hidden by the plan (drop, loss)
        self.corrupt = 0  #: corrupted by the plan (and dropped by a checksum)
        self.delayed = 0  #: delivered later than on time (delay, stall, reorder)
        self.duplicated = 0  #: delivered a second time (a second copy not yet due is not counted)
        self.loss_runs = 0  #: runs of lost messages in a row (``lost / loss_runs``: the mean burst)
        self.out_of_range = 0  #: lost by a range entry (of ``lost``)
        self.retried = 0  #: through a range entry at a second attempt or later
        self.queue_full = 0  #: dropped at the sender's full queue (a bandwidth budget; of ``lost``)
        #: received and still held by the plan (delayed, or waiting to be judged) when the receiver
        #: ended or was killed. Every message received is accounted for:
        #: ``received == delivered - duplicated + lost + corrupt + held``
        self.held = 0
        self.delays_s: list[float] = []  #: how much later each delayed one came [s]
        self.last_lost = False  #: whether the message before was lost (a run goes on)
        #: the distances range entries saw, sender to receiver [m]: least, sum, most, how many
        self.distance_m = [math.inf, 0.0, -math.inf, 0]

    @property
    def counts(self) -> list[int] | np.ndarray:
        """The counts in ``FIELDS``' order."""
        return [getattr(self, f) for f in self.FIELDS]

    def count_fate(self, lost: bool) -> None:
        """A lost message (``lost``) or not: ``lost`` and ``loss_runs`` as they go."""
        if lost:
            self.lost += 1
            self.loss_runs += not self.last_lost
        self.last_lost = lost

    def count_distance(self, d_m: float) -> None:
        dist = self.distance_m
        dist[0] = min(dist[0], d_m)
        dist[1] += d_m
        dist[2] = max(dist[2], d_m)
        dist[3] += 1

    def bind(self, view: np.ndarray) -> None:
        """Count in ``view`` from now on (what was counted so far is carried over)."""
        view[:] = self.counts
        for f in self.FIELDS:
            del self.__dict__[f]
        self.__class__ = BoundEdgeStats
        self.bound = view

    def as_dict(self) -> dict[str, Any]:
        d = sorted(self.delays_s)
        out: dict[str, Any] = {k: int(v) for k, v in zip(self.FIELDS, self.counts, strict=True)}
        if d:
            out["delay_s"] = {
                "median": d[len(d) // 2],
                "p99": d[math.ceil(0.99 * len(d)) - 1],  # the least at or above 99 % of them
                "max": d[-1],
            }
        n = self.distance_m[3]
        if n:
            out["distance_m"] = {
                "min": self.distance_m[0],
                "mean": self.distance_m[1] / n,
                "max": self.distance_m[2],
            }
        return out


class BoundEdgeStats(EdgeStats):
    """An ``EdgeStats`` whose counts live in its ``bound`` array (``EdgeStats.bind``)."""

    bound: np.ndarray  #: the counts, in ``FIELDS``' order (a view of the file's array)

    @property
    def counts(self) -> list[int] | np.ndarray:
        return self.bound

    received = _Count(0)
    delivered = _Count(1)
    lost = _Count(2)
    corrupt = _Count(3)
    delayed = _Count(4)
    duplicated = _Count(5)
    loss_runs = _Count(6)
    out_of_range = _Count(7)
    retried = _Count(8)
    queue_full = _Count(9)
    held = _Count(10)


def counts_names(prefix: str) -> list[str]:
    """The names of one ``EdgeStats``'s counts in a ``NamedCounts`` file: ``PREFIX received``, ..."""
    return [f"{prefix} {f}" for f in EdgeStats.FIELDS]


def stats_from_counts(counts: dict[str, int], prefix: str) -> dict[str, int] | None:
    """``EdgeStats.as_dict`` of a killed process, from its counts file (its delays died with it)."""
    names = counts_names(prefix)
    if not all(n in counts for n in names):
        return None
    return {f: counts[n] for f, n in zip(EdgeStats.FIELDS, names, strict=True)}
