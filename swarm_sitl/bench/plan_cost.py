"""``bench --sim-plan FILE``: what flying a fault plan costs ``sim``, measured in one run.

``sim`` of the config without a plan and with the plan of ``FILE`` are timed in this process,
alternated ``repeats`` times (each after its kernels are loaded), and the ratio of the medians is
printed: the issue's target is at most 1.10 (``running.sim_plan``: the plan's stage per message,
the vehicle's own modes per tick).
"""

import statistics
import time

from swarm_sitl.config.load import load_config, with_faults
from swarm_sitl.running.sim import run_sim


def run_plan_cost(cfg_path: str, plan_path: str, repeats: int) -> int:
    cfg = load_config(cfg_path)
    plain = cfg.model_copy(update={"faults": cfg.faults.model_copy(update={"plan": []})})
    planned = with_faults(plain, plan_path)
    run_sim(plain, n_steps=2)
    run_sim(planned, n_steps=2)
    without: list[float] = []
    with_plan: list[float] = []
    for _ in range(repeats):
        for cfg, into in ((plain, without), (planned, with_plan)):
            t0 = time.process_time()
            run_sim(cfg)
            into.append(time.process_time() - t0)
    a, b = statistics.median(without), statistics.median(with_plan)
    n = len(planned.faults.plan)
    print(f"sim {plain.name}, {plain.duration_s:g} s, CPU s (median of {repeats}):")
    print(f"  without a plan  {a:.3f}  ({', '.join(f'{x:.3f}' for x in without)})")
    print(f"  with {plan_path} ({n} entries)  {b:.3f}  ({', '.join(f'{x:.3f}' for x in with_plan)})")
    print(f"  ratio {b / a:.3f} (target <= 1.10)")
    return 0
