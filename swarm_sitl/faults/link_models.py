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


def how_of(entry: Any) -> tuple[Any, Any]:
    """``(model, params)`` of a link entry of a plan (``plan.FaultSpec``), by its one how."""
    if entry.model is not None:
        return entry.model.model, entry.model.parsed_params
    for key, cls in LINK_MODELS.items():
        value = getattr(entry, key)
        if value is None:
            continue
        if key in ("drop", "stall"):
            params = cls.Params() if key == "drop" else cls.Params(until_s=entry.until_s)
        elif key == "delay_s":
            params = cls.Params(delay_s=value, jitter_s=entry.jitter_s)
        elif isinstance(value, cls.Params):
            params = value
        else:
            params = cls.Params(p=value)
        return cls(), params
    raise ValueError(f"{entry.what}: no link model")  # (a process entry)
