"""The registry of link models: every how a fault plan knows, by its key in a plan entry, each a
class in its own module with its parameter schema and each parameter's range (the contract:
``link_model``), and ``how_of``: the model and parameters of one plan entry.

=============  ==================================  ==============================
key            model                               module
=============  ==================================  ==============================
``drop``       every message lost                  ``loss``
``loss``       lost with probability ``p``         ``loss``
``bursty``     Gilbert-Elliott bursts              ``bursts``
``range``      path loss with distance, retries    ``radio_range``
``bandwidth``  the sender's radio and its queue    ``bandwidth``
``delay_s``    late by a delay and a jitter        ``delays``
``stall``      held until the entry's end          ``delays``
``reorder``    held one period, with ``p``         ``delays``
``duplicate``  delivered twice, with ``p``         ``copies``
``corrupt``    a byte flipped, with ``p``          ``copies``
``model``      a user's own, by entry              ``link_model.ModelEntry``
=============  ==================================  ==============================

Every consumer reads this registry and what each model declares (``link_model.declared``): the
plan (its hows, which may act on a vehicle's MAVLink link and in lockstep, which is a node's
radio), ``sweep`` (``link.KEY`` for a probability, ``link.KEY.PARAM`` for a model written as a
mapping, ``link.ENTRY.PARAM`` for a user's) and ``falsify`` (a space's hows and their severity).
A built-in also says how a plan entry writes its parameters (``plan_form``):

- ``flag``: ``drop: true`` (no parameter; ``stall: true`` takes the entry's ``until_s``);
- ``p``: a probability, ``loss: 0.3`` (its ``Params`` is ``{p}``);
- ``delay``: ``delay_s: d`` and the entry's ``jitter_s``;
- ``params``: the mapping of its ``Params``, ``bursty: {p: 0.05, r: 0.5}``.

Adding a model: its module and its line in ``LINK_MODELS``. A plan then names it by its key
(``plan.FaultEntry`` reads a registered key it has no field for as that model's entry), ``sweep``
varies it and ``falsify`` searches it (``tests/test_link_registry.py`` registers one at run time
and does all three). A field in ``plan.FaultEntry`` for the key is optional: the built-ins have
one, so the config reference (``docs/config.md``) lists them with their types.
"""

from typing import Any

from swarm_sitl.faults.bandwidth import Budget
from swarm_sitl.faults.bursts import Bursty
from swarm_sitl.faults.copies import Corrupt, Duplicate
from swarm_sitl.faults.delays import Delay, Reorder, Stall
from swarm_sitl.faults.loss import Drop, Loss
from swarm_sitl.faults.radio_range import Range

#: the built-in link models by their key in a plan entry (a user's: ``model: {entry, params}``)
LINK_MODELS: dict[str, Any] = {
    "drop": Drop,
    "loss": Loss,
    "bursty": Bursty,
    "range": Range,
    "bandwidth": Budget,
    "delay_s": Delay,
    "stall": Stall,
    "duplicate": Duplicate,
    "reorder": Reorder,
    "corrupt": Corrupt,
}


#: how a plan entry writes a built-in's parameters (module docstring)
PLAN_FORMS = ("flag", "p", "delay", "params")


def keys_of_form(form: str) -> list[str]:
    """The built-in models' keys that a plan writes in ``form``."""
    return [k for k, cls in LINK_MODELS.items() if cls.plan_form == form]


def model_of(entry: Any) -> Any:
    """The class of a link entry's model (``plan.FaultEntry``; None: a user's model not imported,
    as in a run's record)."""
    if entry.model is not None:
        return None if entry.model.model is None else type(entry.model.model)
    for key, cls in LINK_MODELS.items():
        if getattr(entry, key) is not None:
            return cls
    raise ValueError(f"{entry.what}: no link model")  # (a process entry)


def how_of(entry: Any) -> tuple[Any, Any]:
    """``(model, params)`` of a link entry of a plan (``plan.FaultEntry``), by its one how."""
    if entry.model is not None:
        return entry.model.model, entry.model.parsed_params
    for key, cls in LINK_MODELS.items():
        value = getattr(entry, key)
        if value is None:
            continue
        form = cls.plan_form
        if form == "flag":
            params = (
                cls.Params(until_s=entry.until_s) if "until_s" in cls.Params.model_fields else cls.Params()
            )
        elif form == "delay":
            params = cls.Params(delay_s=value, jitter_s=entry.jitter_s)
        elif form == "p":
            params = cls.Params(p=value)
        else:
            params = value
        return cls(), params
    raise ValueError(f"{entry.what}: no link model")  # (a process entry)
