"""One seed for a run: every random stream takes the config's top-level ``seed`` unless its section
sets its own.

The streams (``STREAMS``) and where each one's seed lives:

- ``faults``: ``faults.seed``, the fault plan's draws (each message's fate, a link model's draws);
- ``law``: ``law.seed``, each follower's ``LawContext.rng`` (seeded with it and the follower's id);
- ``wind``: ``wind.seed``, the gusts (with each vehicle's id, or the world's);
- ``sensors``: ``vehicle.sensors.seed``, the reported state's noise and bias walk.

Giving every stream the same number does not correlate them: each stream's draws are keyed by
more than the seed (``faults.draws.uniform(seed, entry, channel, step, salt)``, the gusts'
``default_rng([seed, id, k, 77])``, the noise's ``default_rng([seed, id, time_boot_ms])``, the
law's ``default_rng([seed, id])``), so two streams never draw from one generator state. With the
run's seed at its default 0 and no section seed, every stream's seed is 0: what each was before
the run seed existed, so configs and campaigns written before it fly as they did.

``derive_seeds`` fills the unset section seeds from the run's at validation (``SwarmConfig``) and
says which streams a section pinned; ``without_derived_seeds`` takes the filled ones out again
when the config is written, so a written config keeps following its run seed.
"""

from typing import Any

#: stream -> the keys of its seed in a config's data
STREAMS: dict[str, tuple[str, ...]] = {
    "faults": ("faults", "seed"),
    "law": ("law", "seed"),
    "wind": ("wind", "seed"),
    "sensors": ("vehicle", "sensors", "seed"),
}


def _get(data: Any, path: tuple[str, ...]) -> Any:
    for key in path:
        if not isinstance(data, dict) or key not in data:
            return None
        data = data[key]
    return data


def _with(data: dict[str, Any], path: tuple[str, ...], value: Any) -> dict[str, Any]:
    """``data`` with ``value`` at ``path`` (sections copied on the way, created if absent); a
    section that is not a mapping is left for validation to refuse."""
    head, *rest = path
    if not rest:
        return {**data, head: value}
    inner = data.get(head, {})
    if not isinstance(inner, dict):
        return data
    return {**data, head: _with(inner, tuple(rest), value)}


def derive_seeds(data: Any) -> tuple[Any, frozenset[str]]:
    """``data`` with each unset stream seed set to the run's ``seed`` (0 when unset), and the
    streams whose section set its own."""
    if not isinstance(data, dict):
        return data, frozenset()
    run_seed = data.get("seed", 0)
    pinned = set()
    for name, path in STREAMS.items():
        if _get(data, path) is not None:
            pinned.add(name)
        else:
            data = _with(data, path, run_seed)
    return data, frozenset(pinned)


def _without(data: dict[str, Any], path: tuple[str, ...]) -> dict[str, Any]:
    head, *rest = path
    if not rest:
        return {k: v for k, v in data.items() if k != head}
    if not isinstance(data.get(head), dict):
        return data
    return {**data, head: _without(data[head], tuple(rest))}


def without_derived_seeds(data: dict[str, Any], pinned: frozenset[str]) -> dict[str, Any]:
    """``data`` (a validated config's dump) without the seeds ``derive_seeds`` filled in."""
    for name, path in STREAMS.items():
        if name not in pinned:
            data = _without(data, path)
    return data


def stream_seed(cfg: Any, name: str) -> int:
    """The seed stream ``name`` of a validated config flies with."""
    value: Any = cfg
    for key in STREAMS[name]:
        value = getattr(value, key)
    return int(value)


def seed_lines(cfg: Any) -> list[str]:
    """What ``check`` says of the seeds: the run's, and each stream's (pinned or the run's)."""
    parts = [
        f"{name} {seed}" + (" (pinned by its section)" if pinned else "")
        for name, (seed, pinned) in cfg.seed_streams().items()
    ]
    return [f"seeds: run {cfg.seed}; streams: " + ", ".join(parts)]
