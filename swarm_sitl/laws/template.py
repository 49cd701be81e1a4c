"""A law that does nothing clever, to copy: every part of the contract (``contract``), filled in.

It holds its vehicle where it is (level, thrust = weight), sends its own position and velocity
to its out-neighbours, and records how many in-neighbours it heard and the oldest message's age.
It flies: ``law: {entry: "swarm_sitl.laws.template:HoverLaw"}`` keeps every vehicle hovering at
its start. ``docs/laws.md`` turns a copy of it into a formation law, step by step.
"""

from collections.abc import Mapping
from typing import ClassVar

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from swarm_sitl.laws.contract import AttitudeCommand, LawContext, LawOutput, Received, VehicleSample


class HoverParams(BaseModel):
    """The law's ``params:`` (optional: a law without ``Params`` gets the mapping as written)."""

    model_config = ConfigDict(extra="forbid")
    thrust_scale: float = Field(1.0, gt=0.0, le=2.0, description="thrust as a fraction of the weight")


class HoverLaw:
    #: float64 values per message to the out-neighbours (here: p, v)
    message_length: ClassVar[int] = 6
    #: what it records per tick, name -> number of values (lands in follower_<id>.npz as arrays)
    record_fields: ClassVar[dict[str, int]] = {"heard": 1, "oldest_age_s": 1}
    Params = HoverParams

    def __init__(self, ctx: LawContext):
        p: HoverParams = ctx.params
        self.thrust_N = p.thrust_scale * ctx.mass_kg * ctx.gravity_mps2
        self.level = np.array([1.0, 0.0, 0.0, 0.0])
        self.zero = np.zeros(3)

    def step(self, t_s: float, sample: VehicleSample, inbox: Mapping[int, Received]) -> LawOutput:
        command = AttitudeCommand(self.level, self.thrust_N, self.zero, self.zero)
        message = np.concatenate((sample.p_W, sample.v_W))
        oldest = max((m.age_s for m in inbox.values()), default=0.0)
        return LawOutput(command, message, {"heard": len(inbox), "oldest_age_s": oldest})
