"""``swarm-sitl falsify``: the cheapest fault plan that breaks a requirement (``falsify``)."""

import argparse
import sys
from typing import Any

from swarm_sitl.commands.common import CliError, interrupted_exit


def cmd_falsify(args: argparse.Namespace) -> int:
    from swarm_sitl.campaigns.runner import SchedulerError
    from swarm_sitl.falsify.search import FalsifyError, falsify, load_inputs
    from swarm_sitl.falsify.workers import WorkerError

    for flag, n in (("--jobs", args.jobs), ("--batch", args.batch)):
        if n is not None and n < 1:
            raise CliError(f"{flag} {n}: at least 1")
    try:  # every input checked before anything is flown
        load_inputs(
            args.config,
            args.space,
            args.spec,
            args.requirement,
            args.bound,
            args.duration,
            args.budget,
            args.cost,
        )
    except FalsifyError as e:
        raise CliError(str(e)) from None
    say = (lambda line: None) if args.quiet else (lambda line: print(line, flush=True))
    try:
        f = falsify(
            args.config,
            args.out,
            space=args.space,
            spec=args.spec,
            requirement=args.requirement,
            bound_m=args.bound,
            duration_s=args.duration,
            budget=args.budget,
            cost_how=args.cost,
            seed=args.seed,
            jobs=args.jobs,
            batch=args.batch,
            confirm=not args.no_confirm,
            scheduler=args.scheduler,
            say=say,
        )
    except SchedulerError as e:
        raise CliError(str(e)) from None
    except WorkerError as e:  # no verdict (report.md says so): exit 1, as a failed run
        print(f"swarm-sitl: error: falsify stopped: {e}", file=sys.stderr)
        return 1
    except KeyboardInterrupt as stop:  # (before the search had begun)
        return interrupted_exit(stop)[0]
    rate = f"{f.per_minute:.1f} per minute"
    print(f"falsify {f.requirement}: {f.evaluations} evaluations, {rate} -> {args.out}")
    if f.interrupted:
        print("  interrupted: what was found is written")
    if f.baseline < 0:
        without = "with the config's own plan alone" if f.base_entries else "without any fault"
        print(f"  {f.requirement} fails {without} (robustness {f.baseline:.4g}): nothing to search for")
        return 3
    if f.plan is None:
        if f.interrupted:
            return 128 + f.signum
        print(f"  no plan in the space breaks {f.requirement} within {args.budget} evaluations")
        return 0
    print(
        f"  minimal counterexample {f.counterexample}: {len(f.plan['plan'])} entries, cost {f.cost:.4g}, "
        f"robustness {f.robustness:.4g}"
        + ("" if f.confirmed is None else f"; lockstep run {'the same' if f.confirmed else 'DIFFERS'}")
    )
    for entry in f.plan["plan"]:
        print(f"    {entry}")
    return 128 + f.signum if f.interrupted else 3


def add_falsify(sub: Any) -> None:
    p = sub.add_parser("falsify", help="search fault plans for the cheapest that breaks a requirement")
    p.add_argument("config")
    p.add_argument(
        "--space", metavar="FILE", help="what may fail (YAML; default: loss, cuts, delays on every edge)"
    )
    p.add_argument("--spec", metavar="FILE", help="requirements in place of the config's spec:")
    p.add_argument("--requirement", metavar="NAME", help="which requirement (default: the only one)")
    p.add_argument(
        "--bound", type=float, metavar="M", help="the requirement: formation error after run.settle_s"
    )
    p.add_argument("--budget", type=int, default=60, help="search evaluations (default 60)")
    p.add_argument("--cost", default="severity", help="severity (severity x duration, summed) or edges")
    p.add_argument("--seed", type=int, default=0, help="the sampler's seed (default 0)")
    p.add_argument("--duration", type=float, metavar="S", help="simulated seconds per run")
    p.add_argument("--jobs", type=int, help="worker processes (default: the cores, at most --batch)")
    p.add_argument("--batch", type=int, default=4, help="plans asked for at once (default 4)")
    p.add_argument(
        "--scheduler", metavar="ADDR", help="fly the plans on a Dask cluster (tcp://host:8786) instead"
    )
    p.add_argument("--no-confirm", action="store_true", help="do not fly the counterexample as processes")
    p.add_argument("--quiet", action="store_true", help="no progress lines, only the verdict")
    p.add_argument(
        "--out", required=True, metavar="DIR", help="the search's directory (the same command resumes it)"
    )
    p.set_defaults(func=cmd_falsify)
