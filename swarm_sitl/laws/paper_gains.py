"""The paper's law's gains, one type: ``PaperGains`` is the config's ``gains:`` section (validated
at load), the law's parameters carry it (``zou_meng.ZouMengParams.gains``), ``swarm-sitl check``
holds it to Theorem 1, and the kernels' ``follower_law.ControlGains`` is made from it by name.
"""

from typing import Annotated

from pydantic import BaseModel, ConfigDict, Field

#: a gain: positive and finite (an infinite gain is refused at load, not at the first tick)
Positive = Annotated[float, Field(gt=0, allow_inf_nan=False)]


class PaperGains(BaseModel):
    """The gains of the estimator and the position loop (the paper's symbols)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    k_gamma: Positive  #: estimator: bound of the acceleration estimate, a_hat = k_gamma tanh(gamma) [m/s^2]
    k_p: Positive  #: estimator: consensus gain on the neighbours' position estimates [1/s]
    k_v: Positive  #: estimator: consensus gain on the neighbours' velocity estimates [1/s]
    l_a: Positive  #: estimator: damping of gamma's second-order dynamics [1/s]
    k_a: Positive  #: estimator: gain of the sliding variable's sign term
    l_p: Positive  #: auxiliary system: position-error gain
    l_v: Positive  #: auxiliary system: velocity-error gain
    k_eta: Positive  #: auxiliary system: bound of its saturated (tanh) terms [m/s^2]
