"""The plan's random draws: each a pure function of the seed and integer keys (splitmix64), so
the same plan and seed give every message the same fate on any machine, in any order."""

_MASK = (1 << 64) - 1


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


__all__ = ["_mix", "uniform"]
