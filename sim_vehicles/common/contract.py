"""A plug-in point's contract, stated one way for all three (a law, a vehicle model, a link
model): a ``typing.Protocol`` class, and a plug-in held to it by the names the protocol itself
declares (``protocol_members``), never by a list of names typed again beside it.
"""

from typing import Any, Protocol


def protocol_members(protocol: type) -> tuple[str, ...]:
    """The names ``protocol`` (a ``Protocol`` class, and the protocols it extends) declares, in
    order: its annotated attributes, then its methods and properties; not ``__init__`` or any
    other dunder (how it is built is the plug-in point's to say)."""
    names: list[str] = []
    for klass in reversed(protocol.__mro__):
        if klass is Protocol or not getattr(klass, "_is_protocol", False):
            continue
        names += [n for n in getattr(klass, "__annotations__", {}) if not n.startswith("_")]
        names += [
            n
            for n, v in vars(klass).items()
            if not n.startswith("_") and (callable(v) or isinstance(v, property | classmethod | staticmethod))
        ]
    return tuple(dict.fromkeys(names))


def missing_members(obj: Any, protocol: type) -> list[str]:
    """The names of ``protocol`` that ``obj`` (a class or an instance) does not have."""
    return [name for name in protocol_members(protocol) if not hasattr(obj, name)]
