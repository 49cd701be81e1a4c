"""One plan flown in ``sim``: the requirement's robustness (negative: the plan breaks it).

The requirement is one of the config's ``spec:`` entries (``specs``) or, without one, the run's
bound as a requirement: ``always[settle_s, end] (pos_err_m <= bound)`` over the followers, which
is what ``run.max_formation_error_m`` judges. A run that recorded nothing where the requirement
looks (a follower lost) has no robustness: it counts as ``-inf``, a violation.

``sim`` flies a plan as a lockstep run of processes does, bit for bit (``running.sim_plan``), so
the robustness found here is the one a lockstep run under the same plan gives.
"""

import math
from collections.abc import Callable
from typing import Any

from swarm_sitl.config.schema import SwarmConfig
from swarm_sitl.faults.plan import FaultPlan
from swarm_sitl.rundir.recording import Recording
from swarm_sitl.rundir.requirements import judge
from swarm_sitl.running.sim import SimFailedError, run_sim
from swarm_sitl.specs.requirement import Requirement

BOUND = "bound"  #: the name of the requirement made of the run's bound


def requirement_config(cfg: SwarmConfig, name: str | None, bound_m: float | None) -> tuple[SwarmConfig, str]:
    """``cfg`` holding exactly the requirement ``falsify`` judges, and its name; ``ValueError``
    (one line) if there is none to judge or ``name`` is not one of the config's."""
    if bound_m is not None or not cfg.spec:
        bound = bound_m if bound_m is not None else cfg.run.max_formation_error_m
        if bound is None:
            raise ValueError(
                "nothing to falsify: the config has no spec: and no run.max_formation_error_m "
                "(give --spec or --bound)"
            )
        if not cfg.run.settle_s < cfg.duration_s:
            raise ValueError(
                f"the bound is judged from run.settle_s = {cfg.run.settle_s:g} s, not before the run's end "
                f"({cfg.duration_s:g} s): a longer --duration, or a spec"
            )
        if name not in (None, BOUND):
            raise ValueError(f"--requirement {name}: with a bound the requirement is {BOUND!r}")
        req = Requirement(name=BOUND, formula=f"always[{cfg.run.settle_s:g}, end] (pos_err_m <= {bound!r})")
        return cfg.model_copy(update={"spec": [req]}), BOUND
    names = [r.name for r in cfg.spec]
    if name is None:
        if len(names) > 1:
            raise ValueError(
                f"the spec has {len(names)} requirements ({', '.join(names)}): name one (--requirement)"
            )
        name = names[0]
    if name not in names:
        raise ValueError(f"--requirement {name}: not in the spec (it has {', '.join(names)})")
    return cfg.model_copy(update={"spec": [r for r in cfg.spec if r.name == name]}), name


def robustness_of(cfg: SwarmConfig, rec: Recording, name: str) -> float:
    """The requirement's robustness for the run ``rec`` (-inf where it has none)."""
    r = judge(cfg, rec, rec.events)[name]["robustness"]
    return -math.inf if r is None else float(r)


def evaluate(
    cfg: SwarmConfig,
    name: str,
    plan: dict[str, Any],
    on_hard_stop: Callable[[str, Recording], None] | None = None,
) -> float:
    """Fly ``plan`` (a ``faults:`` mapping) in ``sim``; the robustness of requirement ``name``.
    ``on_hard_stop``: told before a law held in compiled code ends the process (``run_sim``)."""
    flown = cfg.model_copy(update={"faults": FaultPlan.model_validate(plan)})
    try:
        rec = run_sim(flown, on_hard_stop=on_hard_stop)
    except SimFailedError as e:  # the law failed: judged on what it recorded (NaN after: violated)
        assert isinstance(e.recording, Recording)  # (run_sim's: in memory)
        rec = e.recording
    return robustness_of(flown, rec, name)
