"""When a recorded error settles: the first time after which it stays within a tolerance, for
the summary's convergence times (``metrics``) and the verdicts after a restart (``rejoins``)."""

import numpy as np


def time_to_converge(t: np.ndarray, err: np.ndarray, tol: float) -> float | None:
    """First time after which ``err`` stays at or below ``tol`` to the end (None if never, or if
    there are no samples)."""
    if not t.size:
        return None
    above = np.nonzero(~(err <= tol))[0]
    if above.size == 0:
        return float(t[0])
    last = above[-1]
    return None if last + 1 >= t.size else float(t[last + 1])
