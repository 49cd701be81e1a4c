"""The link models that change a message rather than lose or hold it: ``duplicate`` (delivered
again a period later) and ``corrupt`` (one byte flipped: the receiver's checksum drops it), each
with a probability (``loss.Chance``). The contract: ``link_model``."""

from swarm_sitl.faults.link_model import Effect
from swarm_sitl.faults.loss import Chance


class Duplicate(Chance):
    """Each message, with probability ``p``, delivered a second time a period after the first."""

    EFFECT = Effect(duplicate=True)

    def severity(self, p: Chance.Params, period_s: float, staleness_s: float) -> float:
        return 0.0  # every message still comes


class Corrupt(Chance):
    """Each message, with probability ``p``, has one byte flipped."""

    EFFECT = Effect(corrupt=True)
    mavlink_in_lockstep = True  #: a corrupted datagram is dropped by the checksum: a lost one

    def severity(self, p: Chance.Params, period_s: float, staleness_s: float) -> float:
        return p.p
