"""The plan's random draws: each a pure function of the seed and integer keys (splitmix64), so
the same plan and seed give every message the same fate on any machine, in any order.

``uniform_at`` is ``uniform`` of (seed, entry, link, step, salt), a message's draw: it reads a
table of ``BLOCK`` consecutive steps hashed at once with numpy (the same 64-bit arithmetic, so
the same numbers, bit for bit: ``tests/test_link_models.py``), which costs a message 0.2 us where
hashing it alone cost 2.4 us.
"""

import numpy as np

_MASK = (1 << 64) - 1
BLOCK = 256  #: steps per table
MAX_TABLES = 8192  #: tables kept (2 kB each); past it they are all made again as they are needed
_TABLES: dict[tuple[int, int, int, int, int], np.ndarray] = {}


def _mix(x: int) -> int:
    """splitmix64's finaliser: a 64-bit integer hash with every input bit reaching every output bit."""
    x = (x + 0x9E3779B97F4A7C15) & _MASK
    x = ((x ^ (x >> 30)) * 0xBF58476D1CE4E5B9) & _MASK
    x = ((x ^ (x >> 27)) * 0x94D049BB133111EB) & _MASK
    return x ^ (x >> 31)


def uniform(seed: int, *keys: int) -> float:
    """A draw in [0, 1) that depends only on ``seed`` and ``keys`` (non-negative integers)."""
    h = _mix(seed)
    for k in keys:
        h = _mix(h ^ k)
    return (h >> 11) / float(1 << 53)


def _mix_all(x: np.ndarray) -> np.ndarray:
    """``_mix`` of each element of a uint64 array (numpy's uint64 arithmetic wraps, as the mask)."""
    x = x + np.uint64(0x9E3779B97F4A7C15)
    x = (x ^ (x >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
    x = (x ^ (x >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
    return x ^ (x >> np.uint64(31))


def _table(seed: int, entry: int, channel: int, salt: int, block: int) -> np.ndarray:
    return uniforms(seed, entry, channel, np.arange(block * BLOCK, (block + 1) * BLOCK), salt)


def uniforms(seed: int, entry: int, channel: int, steps: np.ndarray, salt: int) -> np.ndarray:
    """``uniform(seed, entry, channel, s, salt)`` of each step ``s`` of ``steps`` (non-negative
    integers), hashed at once."""
    h = _mix(_mix(_mix(seed) ^ entry) ^ channel)
    with np.errstate(over="ignore"):
        x = _mix_all(_mix_all(np.uint64(h) ^ steps.astype(np.uint64)) ^ np.uint64(salt))
    return (x >> np.uint64(11)).astype(np.float64) / float(1 << 53)


def uniform_at(seed: int, entry: int, channel: int, step: int, salt: int) -> float:
    """``uniform(seed, entry, channel, step, salt)``, from a table of ``BLOCK`` steps."""
    key = (seed, entry, channel, salt, step // BLOCK)
    t = _TABLES.get(key)
    if t is None:
        if len(_TABLES) >= MAX_TABLES:
            _TABLES.clear()
        t = _TABLES[key] = _table(seed, entry, channel, salt, step // BLOCK)
    return float(t[step % BLOCK])


__all__ = ["_mix", "uniform", "uniform_at", "uniforms"]
