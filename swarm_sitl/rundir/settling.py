"""When a recorded error settles: the first time after which it stays within a tolerance, for
the summary's convergence times (``metrics``) and the verdicts after a restart (``rejoins``).
``Settling`` takes the rows in blocks, in order (a run streamed to disk, ``sim``'s); the whole
series at once is one block (``time_to_converge``)."""

import numpy as np


class Settling:
    """``time_to_converge`` of rows given block by block, in order."""

    def __init__(self, tol: float):
        self.tol = tol
        self.first: float | None = None  #: the first row's time
        self.after: float | None = None  #: the time of the row after the last one above ``tol``
        self.above = False  #: a row was above ``tol``
        self.pending = False  #: the last row seen was above: its successor is not seen yet

    def add(self, t: np.ndarray, err: np.ndarray) -> "Settling":
        if not t.size:
            return self
        if self.first is None:
            self.first = float(t[0])
        above = np.nonzero(~(err <= self.tol))[0]
        if above.size:
            last = int(above[-1])
            self.above = True
            self.pending = last + 1 >= t.size
            self.after = None if self.pending else float(t[last + 1])
        elif self.pending:
            self.after, self.pending = float(t[0]), False
        return self

    def result(self) -> float | None:
        if self.first is None or self.pending:
            return None
        return self.after if self.above else self.first


def time_to_converge(t: np.ndarray, err: np.ndarray, tol: float) -> float | None:
    """First time after which ``err`` stays at or below ``tol`` to the end (None if never, or if
    there are no samples)."""
    return Settling(tol).add(t, err).result()
