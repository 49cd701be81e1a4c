"""``swarm-sitl bench``: speed figures, measured and printed (``swarm_sitl.bench``).

Imports are at the top but for three parts, each imported by the commands that run it: measured
after the config schema every command needs (0.6 s), matplotlib costs 0.44 s (``plot``, and
``bench``: 0.54 s with its runs), the run machinery (``running``) 0.12 s (``sim``, ``run``,
``vehicles``, ``controllers``) and a node's own modules 0.17 s (``controller``, ``leader``).
"""

import argparse
import math
import sys
import time
from pathlib import Path
from typing import Any

from swarm_sitl.commands.common import CliError


def cmd_bench(args: argparse.Namespace) -> int:
    # the benchmarks and the run machinery, matplotlib among them: 0.54 s (module doc)
    from swarm_sitl.bench.speed import run_bench
    from swarm_sitl.running.supervisor import RunFailedError

    if args.repeats < 1 or not args.realtime_s > 0 or not 0 < args.scale_duration < math.inf:
        raise CliError("--repeats must be >= 1, --realtime-s and --scale-duration > 0")
    if not 0 <= args.scale_realtime < math.inf:
        raise CliError(f"--scale-realtime must be >= 0 s, got {args.scale_realtime}")
    if args.split is not None and not args.scale:
        raise CliError("--split N goes with --scale (it profiles one of the scale runs)")
    if args.empty and not args.scale:
        raise CliError("--empty goes with --scale (it runs each N's swarm with no work in it)")
    if args.against and not (Path(args.against) / "swarm_sitl" / "__init__.py").is_file():
        raise CliError(f"--against {args.against}: not a swarm-sitl source tree (no swarm_sitl/__init__.py)")
    if args.soak is not None and not 0 < args.soak < math.inf:
        raise CliError(f"--soak takes minutes > 0, got {args.soak}")
    try:
        if args.soak is not None:
            from swarm_sitl.bench.soak import run_soak

            configs = [c for c in args.soak_configs.split(",") if c]
            for c in configs:
                if not Path(c).is_file():
                    raise CliError(f"--soak-configs: {c}: no such file")
            stamp = time.strftime("%Y%m%d-%H%M%S")
            soak_out = Path(args.out) if args.out else Path("runs") / f"bench-soak-{stamp}"
            return run_soak(args.soak, configs, soak_out)
        if args.scale:
            from swarm_sitl.bench.scale import run_scale

            try:
                ns = [int(x) for x in args.scale.split(",")]
            except ValueError:
                raise CliError(f"--scale takes follower counts like 4,8,16, got {args.scale!r}") from None
            if not ns or min(ns) < 1 or max(ns) > 254:
                raise CliError(f"--scale: follower counts must be 1..254, got {args.scale!r}")
            out = Path(args.out) if args.out else None
            try:
                splits = [int(x) for x in args.split.split(",")] if args.split is not None else []
            except ValueError:
                raise CliError(f"--split takes follower counts like 16,64, got {args.split!r}") from None
            if any(n not in ns for n in splits):
                raise CliError(f"--split {args.split}: not among the --scale counts {args.scale}")
            return run_scale(
                ns,
                args.scale_duration,
                out,
                args.scale_start,
                args.scale_realtime,
                splits,
                args.empty,
            )
        if args.sim_plan:
            from swarm_sitl.bench.plan_cost import run_plan_cost

            if not Path(args.sim_plan).is_file():
                raise CliError(f"--sim-plan {args.sim_plan}: no such file")
            return run_plan_cost(args.config, args.sim_plan, args.repeats)
        if args.sim_memory:
            from swarm_sitl.bench.sim_memory import sim_memory

            try:
                durations = [float(x) for x in args.sim_memory.split(",")]
            except ValueError:
                raise CliError(
                    f"--sim-memory takes durations in s like 60,3600, got {args.sim_memory!r}"
                ) from None
            if not durations or not all(0 < d < math.inf for d in durations):
                raise CliError(f"--sim-memory: durations must be > 0 s, got {args.sim_memory!r}")
            return sim_memory(args.config, durations)
        if args.view:
            from swarm_sitl.bench.view_cost import view_cost

            return view_cost(args.config, args.repeats)
        if args.ros2:
            from swarm_sitl.bench.ros2_cost import ros2_cost

            return ros2_cost(args.config, args.repeats)
        if args.against:
            from swarm_sitl.bench.speed import compare_trees

            return compare_trees(args.config, Path(args.against), args.repeats)
        return run_bench(args.config, args.scale_config, args.repeats, args.realtime_s)
    except RunFailedError as e:
        print(f"swarm-sitl: error: bench: {e}", file=sys.stderr)
        return 1


def add_bench(sub: Any) -> None:
    """``swarm-sitl bench``: speed figures."""
    b = sub.add_parser("bench", help="measure speed figures and print them")
    b.add_argument(
        "--config",
        default=str(Path("configs") / "paper.yaml"),
        help="the swarm benchmarked (default: the paper's)",
    )
    b.add_argument(
        "--repeats",
        type=int,
        default=3,
        help="how many times each is run, alternated where two are compared (default 3)",
    )
    b.add_argument(
        "--scale-config", default=str(Path("configs") / "swarm16.yaml"), help="real-time scale run"
    )
    b.add_argument("--realtime-s", type=float, default=20.0, help="duration of the real-time scale run [s]")
    b.add_argument(
        "--against",
        metavar="DIR",
        help="only compare the lockstep run with another source tree's, alternated --repeats times",
    )
    b.add_argument(
        "--view",
        action="store_true",
        help="instead: the lockstep run without and with a page open on it (run --view), alternated "
        "--repeats times",
    )
    b.add_argument(
        "--ros2",
        action="store_true",
        help="instead: the lockstep run without and with its ROS 2 face (run --ros2) and a ROS 2 reader on "
        "every topic, alternated --repeats times",
    )
    b.add_argument(
        "--sim-plan",
        metavar="FILE",
        help="instead: sim of --config without and with this fault plan, alternated --repeats times",
    )
    b.add_argument(
        "--sim-memory",
        metavar="S,S,...",
        help="instead: sim of --config for each of these durations [s], its peak resident memory",
    )
    b.add_argument(
        "--scale",
        metavar="N,N,...",
        help="instead: lockstep cost against sim for generated layered swarms of these sizes (4,8,16,32,64)",
    )
    b.add_argument("--scale-duration", type=float, default=20.0, help="simulated seconds per --scale run")
    b.add_argument(
        "--scale-realtime",
        type=float,
        default=0.0,
        metavar="S",
        help="--scale: also run each N for S s in real time (late ticks, setpoint latency)",
    )
    b.add_argument(
        "--split",
        metavar="N,N,...",
        help="--scale: also profile these runs and print where each process kind's CPU goes "
        "(with --empty: beyond the empty swarm's and sim's)",
    )
    b.add_argument(
        "--empty",
        action="store_true",
        help="--scale: also run each N as a swarm of the same processes and messages with no work "
        "in them (what the process structure alone costs on this machine)",
    )
    b.add_argument(
        "--scale-start", choices=("fork", "spawn"), default="fork", help="--scale: run.start of the runs"
    )
    b.add_argument(
        "--soak",
        type=float,
        metavar="MINUTES",
        help="instead: fly each --soak-configs swarm this long in real time and report per process "
        "resident memory, open files, late ticks and the run directory's growth (a leak hunt)",
    )
    b.add_argument(
        "--soak-configs",
        default=f"{Path('configs') / 'paper.yaml'},{Path('configs') / 'swarm16.yaml'}",
        metavar="CFG,CFG,...",
        help="--soak: the configs to fly, one after the other (default: paper.yaml,swarm16.yaml)",
    )
    b.add_argument(
        "--out",
        help="--scale, --soak: directory for the figures (default runs/bench-scale-<time>, "
        "runs/bench-soak-<time>)",
    )
    b.set_defaults(func=cmd_bench)
