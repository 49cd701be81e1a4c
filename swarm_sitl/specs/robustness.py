"""A formula's quantitative robustness over sampled signals: how much it holds (> 0) or fails (< 0),
in its signals' unit, at every sample (``robustness``), and its verdict at the run's start.

Discrete-time, finite-trace semantics (as rtamt's offline discrete-time monitor, which the tests
hold these values to):

- ``x < c``, ``x <= c``: ``c - x``; ``x > c``, ``x >= c``: ``x - c`` (a tie is 0: it holds, at the
  edge);
- ``not f``: ``-f``; ``f and g``: ``min``; ``f or g``: ``max``; ``f implies g``: ``max(-f, g)``;
- ``always[a, b] f`` at sample k: the ``min`` of ``f`` over samples ``k + ceil(a/dt)`` to
  ``k + floor(b/dt)``, clipped at the last sample (``+inf`` where nothing is left);
  ``eventually[a, b] f``: the ``max`` (``-inf`` where nothing is left).

The window extremes are O(n) whatever the window (van Herk / Gil-Werman), so a requirement over a
whole run costs a few passes over its samples.
"""

import math
from collections.abc import Mapping

import numpy as np

from swarm_sitl.specs.formula import Always, And, Atom, Eventually, Formula, Implies, Not, Or

_EPS = 1e-9


def _steps(start_s: float, end_s: float, dt_s: float, n: int) -> tuple[int, int]:
    lo = math.ceil(start_s / dt_s - _EPS)
    hi = n - 1 if math.isinf(end_s) else math.floor(end_s / dt_s + _EPS)
    return lo, min(hi, n - 1)


def window_extreme(r: np.ndarray, lo: int, hi: int, minimum: bool) -> np.ndarray:
    """Per sample k: the min (``minimum``) or max of ``r[k + lo : k + hi + 1]`` clipped to the
    samples there are; ``+inf`` (min) or ``-inf`` (max) where the window holds none."""
    n = len(r)
    empty = math.inf if minimum else -math.inf
    w = hi - lo + 1
    if w <= 0 or n == 0:
        return np.full(n, empty)
    op = np.minimum if minimum else np.maximum
    # r shifted by lo, padded with the neutral value so that every window is whole
    shifted = np.full(n + w, empty)
    if lo < n:
        shifted[: n - lo] = r[lo:]
    blocks = math.ceil(len(shifted) / w)
    padded = np.full(blocks * w, empty)
    padded[: len(shifted)] = shifted
    grid = padded.reshape(blocks, w)
    prefix = op.accumulate(grid, axis=1).ravel()
    suffix = op.accumulate(grid[:, ::-1], axis=1)[:, ::-1].ravel()
    k = np.arange(n)
    return op(suffix[k], prefix[k + w - 1])


def robustness(node: Formula, signals: Mapping[str, np.ndarray], dt_s: float) -> np.ndarray:
    """The robustness of ``node`` at every sample of ``signals`` (each an array of one length,
    sampled every ``dt_s``)."""
    if isinstance(node, Atom):
        x = np.asarray(signals[node.signal], dtype=float)
        return node.value - x if node.op in ("<", "<=") else x - node.value
    if isinstance(node, Not):
        return -robustness(node.arg, signals, dt_s)
    if isinstance(node, And | Or | Implies):
        left = robustness(node.left, signals, dt_s)
        right = robustness(node.right, signals, dt_s)
        if isinstance(node, And):
            return np.minimum(left, right)
        if isinstance(node, Or):
            return np.maximum(left, right)
        return np.maximum(-left, right)
    assert isinstance(node, Always | Eventually)
    inner = robustness(node.arg, signals, dt_s)
    lo, hi = _steps(node.start_s, node.end_s, dt_s, len(inner))
    return window_extreme(inner, lo, hi, minimum=isinstance(node, Always))


def verdict(node: Formula, signals: Mapping[str, np.ndarray], dt_s: float) -> float:
    """The robustness at the run's start: what the requirement says of the whole run."""
    return float(robustness(node, signals, dt_s)[0])
