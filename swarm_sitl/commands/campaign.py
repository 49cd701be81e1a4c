"""``swarm-sitl sweep``: a robustness campaign (``campaigns.sweep``) from the command line."""

import argparse
import sys
from typing import Any

from swarm_sitl.commands.common import CliError, interrupted_exit


def cmd_sweep(args: argparse.Namespace) -> int:
    from swarm_sitl.campaigns.point import PointError
    from swarm_sitl.campaigns.runner import SchedulerError
    from swarm_sitl.campaigns.sweep import SweepSpecError, summary_lines, sweep

    seeds: Any = args.seeds
    if "," in seeds:
        try:
            seeds = [int(s) for s in seeds.split(",") if s.strip()]
        except ValueError:
            raise CliError(f"--seeds {args.seeds}: a count or a comma list of integers") from None
    else:
        try:
            seeds = int(seeds)
        except ValueError:
            raise CliError(f"--seeds {args.seeds}: a count or a comma list of integers") from None
    try:
        c = sweep(
            args.config,
            args.vary,
            out=args.out,
            seeds=seeds,
            faults=args.faults,
            duration_s=args.duration,
            bound_m=args.bound,
            jobs=args.jobs,
            scheduler=args.scheduler,
            scheduler_timeout_s=args.scheduler_timeout,
            refine=args.refine,
            progress=not args.quiet,
            keep_runs=args.keep_runs,
            point_timeout_s=args.point_timeout,
            spec=args.spec,
        )
    except (SweepSpecError, SchedulerError, PointError) as e:
        raise CliError(str(e)) from None
    for line in summary_lines(c):
        print(line)
    if c.interrupted:
        code, name = interrupted_exit(c.interrupted)
        print(
            f"swarm-sitl: interrupted ({name}): the {len(c.rows)} finished runs are in {c.table}; "
            "the same command runs the rest",
            file=sys.stderr,
        )
        return code
    return 0


def add_sweep(sub: Any) -> None:
    s = sub.add_parser(
        "sweep",
        help="a robustness campaign: lockstep runs over a grid of config or fault-plan values and seeds",
        description="Run every point of a grid of values (KEY=VALUES, several --vary for a grid) times "
        "several seeds, each a lockstep run; one row per run in OUT/table.csv, charts of the error "
        "against each value, and the breaking point (the largest value at which every seed holds the "
        "bound). Resumable: rows already in the table are not run again.",
    )
    s.add_argument("config")
    s.add_argument(
        "--vary",
        action="append",
        required=True,
        metavar="KEY=VALUES",
        help="a config path (gains.k_p, vehicle.mass_kg, wind.gust_mps) or link.loss, link.delay_s, "
        "link.jitter_s, link.duplicate, link.corrupt, link.reorder, link.MODEL.PARAM (link.bursty.p, "
        "link.range.range_m, link.bandwidth.rate_bps, a model of yours: link.my_link.py:Name.param; "
        "every graph edge), mavlink.loss, "
        "mavlink.corrupt (every vehicle link); VALUES: START:STOP:STEP or a,b,c",
    )
    s.add_argument("--seeds", default="3", help="a count (seeds 0..N-1) or a list 1,5,9 (default 3)")
    s.add_argument("--out", required=True, help="the campaign's directory (run again to resume)")
    s.add_argument("--faults", help="a base fault plan (YAML) under the swept entries")
    s.add_argument("--duration", type=float, help="override duration_s [s]")
    s.add_argument("--bound", type=float, help="the pass/fail bound [m] (default: run.max_formation_error_m)")
    s.add_argument("--jobs", type=int, help="runs at once on this machine (default: one per core)")
    s.add_argument("--scheduler", help="a Dask scheduler's address (tcp://HOST:8786): run there instead")
    s.add_argument(
        "--scheduler-timeout", type=float, default=10.0, help="seconds to reach the scheduler (default 10)"
    )
    s.add_argument("--refine", type=int, default=0, help="bisection steps at the breaking point (one key)")
    s.add_argument("--keep-runs", action="store_true", help="keep each run's directory in OUT/runs")
    s.add_argument("--spec", metavar="FILE", help="requirements in place of the config's (docs/specs.md)")
    s.add_argument(
        "--point-timeout",
        type=float,
        metavar="S",
        help="each run's wall budget; a run past it is a failed row, 'timed out' (default: "
        "run.start_timeout_s + 10 x its duration + 60 s)",
    )
    s.add_argument("--quiet", action="store_true", help="no progress bar")
    s.set_defaults(func=cmd_sweep)
