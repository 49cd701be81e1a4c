"""The commands around a run: ``check`` (Theorem 1's conditions for a config), ``new`` (a generated
swarm's config), ``router`` (a zenoh router for several hosts), ``plot`` and ``export`` (a run
directory as figures, as MCAP), ``merge`` (a run directory rebuilt from its raw records).

Imports are at the top but for three parts, each imported by the commands that run it: measured
after the config schema every command needs (0.6 s), matplotlib costs 0.44 s (``plot``, and
``bench``: 0.54 s with its runs), the run machinery (``running``) 0.12 s (``sim``, ``run``,
``vehicles``, ``controllers``) and a node's own modules 0.17 s (``controller``, ``leader``).
"""

import argparse
import json
import math
import os
import signal
import sys
import time
from pathlib import Path
from typing import Any

from swarm_sitl.bus.session import error_line, open_plain_router, router_runtime
from swarm_sitl.commands.common import CliError, load, summary_lines
from swarm_sitl.commands.law_check import render_law_check
from swarm_sitl.config.generator import FORMATIONS, GRAPHS, TRAJECTORIES, GeneratorError, generate
from swarm_sitl.config.law_entry import LawEntryError, absolute_entry, is_file_entry, split_entry
from swarm_sitl.config.load import ConfigError, load_recorded
from swarm_sitl.config.seeds import seed_lines
from swarm_sitl.laws.gain_conditions import check_gains
from swarm_sitl.laws.gain_report import render
from swarm_sitl.rundir.events import read_events
from swarm_sitl.rundir.layout import procs_dir
from swarm_sitl.rundir.load import RunDirError, load_run
from swarm_sitl.rundir.mcap_export import write_mcap
from swarm_sitl.rundir.merge import merge_run
from swarm_sitl.rundir.outputs import write_outputs
from swarm_sitl.rundir.whole_files import WriteError


def cmd_check(args: argparse.Namespace) -> int:

    cfg = load(args.config)
    print("\n".join(seed_lines(cfg)))
    disagree = link_model_lines(cfg)
    for line in disagree:
        print(line)
    if disagree:
        return 1
    if not cfg.law.is_paper:
        text, ok = render_law_check(cfg, args.config)
        print(text)
        return 0 if ok else 1
    report = check_gains(
        cfg.build_graph(), cfg.gain_dict(), cfg.trajectory(), cfg.gravity_mps2, max(cfg.duration_s, 200.0)
    )
    print(render(report, args.config, cfg.estimator.bracket))
    return 0


def _name_values(items: list[str], flag: str) -> dict[str, float]:
    """``NAME=VALUE`` arguments as a mapping of numbers; ``CliError`` (one line) for a bad one."""
    out: dict[str, float] = {}
    for item in items:
        name, sep, value = item.partition("=")
        try:
            number = float(value)
        except ValueError:
            number = math.nan
        if not sep or not name.strip() or not math.isfinite(number):
            raise CliError(f"{flag} {item!r}: give NAME=NUMBER")
        out[name.strip()] = number
    return out


def link_model_lines(cfg: Any) -> list[str]:
    """A line for each link model of the user's in the plan whose ``fates`` and ``fate`` disagree
    (``faults.link_model.fates_disagreement``: the contract wants them equal, and lockstep reads
    ``fates`` where real time asks ``fate``)."""
    from swarm_sitl.faults.link_model import fates_disagreement

    out = []
    for j, f in enumerate(cfg.faults.plan):
        if f.model is not None:
            why = fates_disagreement(f.model.model, f.model.parsed_params, cfg.control_dt_s)
            if why is not None:
                out.append(f"faults.plan.{j}: link model {f.model.entry}: {why}")
    return out


def written_entry(entry: str, config_dir: Path) -> str:
    """A law entry as a config in ``config_dir`` must hold it: a file entry given relative to the
    working directory, made relative to the config's directory."""
    if not is_file_entry(entry):
        return entry
    path, name = split_entry(absolute_entry(entry, Path.cwd()))
    return f"{os.path.relpath(path, config_dir.resolve())}:{name}"


def cmd_new(args: argparse.Namespace) -> int:

    out = Path(args.o)
    try:
        law = args.law if args.law is None else written_entry(args.law, out.parent)
        vehicle = args.vehicle if args.vehicle is None else written_entry(args.vehicle, out.parent)
        vehicle_params = _name_values(args.vehicle_param, "--vehicle-param")
        if vehicle_params and vehicle is None:
            raise CliError("--vehicle-param: name the model it is for (--vehicle MODEL)")
        text = generate(
            args.followers,
            args.graph,
            args.formation,
            args.trajectory,
            args.seed,
            args.duration,
            law,
            out.parent,
            vehicle,
            vehicle_params,
        )
    except (GeneratorError, LawEntryError) as e:
        hint = " (give the model's parameters with --vehicle-param NAME=VALUE)" if "params" in str(e) else ""
        raise CliError(f"{e}{hint}") from None
    if out.exists() and not args.force:
        raise CliError(f"{out} exists (--force to overwrite)")
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(text)
    except OSError as e:
        raise CliError(f"cannot write {out}: {e.strerror}") from None
    gains = [line.strip()[2:] for line in text.splitlines() if line.startswith("  # ") and "gains" in line]
    print(f"wrote {out}: {args.followers} followers, {args.graph} graph, {args.formation}, {args.trajectory}")
    for line in gains[: 1 if args.law is None else 0]:  # Theorem 1's: the paper's law's
        print(f"  gains: {line}")
    return 0


def cmd_router(args: argparse.Namespace) -> int:

    if args.users_file and not Path(args.users_file).is_file():
        raise CliError(f"--users-file {args.users_file}: no such file")
    try:
        with router_runtime():
            router = open_plain_router(args.listen, args.users_file)
    except Exception as e:  # zenoh raises its own error type for a bad or busy endpoint
        raise CliError(f"cannot open a zenoh router on {' '.join(args.listen)}: {error_line(e)}") from None
    auth = f"sessions authenticate against {args.users_file}" if args.users_file else "no authentication"
    print(f"zenoh router listening on {' '.join(args.listen)} ({auth}); Ctrl-C stops it", flush=True)
    signal.signal(signal.SIGTERM, lambda signum, frame: sys.exit(0))
    try:
        while True:
            time.sleep(0.5)
    except KeyboardInterrupt:
        pass
    finally:
        router.close()
    return 0


def cmd_plot(args: argparse.Namespace) -> int:
    from swarm_sitl.rundir.plots import plot_run  # matplotlib: 0.44 s (module doc)

    run_dir = Path(args.run_dir)
    rec = load_run(run_dir)
    bounds = summary = edges = None
    summary_path = run_dir / "summary.json"
    if summary_path.is_file():
        summary = json.loads(summary_path.read_text())
        bounds = {
            int(i): f["thrust_bound_N"] for i, f in summary["followers"].items() if "thrust_bound_N" in f
        }
    events = []
    if (run_dir / "events.jsonl").is_file():
        events = read_events(run_dir / "events.jsonl")
    if "links" in (summary or {}):
        try:
            edges = load_recorded(run_dir).graph_edges()
        except ConfigError:
            edges = None
    out = Path(args.out) if args.out else run_dir / "plots"
    for p in plot_run(rec, out, bounds, events, summary, edges):
        print(p)
    return 0


def cmd_merge(args: argparse.Namespace) -> int:
    """The run directory written again from its processes' raw records (``procs/``): after a
    run whose outputs could not be written, or to redo them."""
    run_dir = Path(args.run_dir)
    if not (run_dir / "config.yaml").is_file() or not procs_dir(run_dir).is_dir():
        raise RunDirError(f"{run_dir}: not a multi-process run directory (no config.yaml and procs/)")
    cfg = load_recorded(run_dir)
    try:
        summary = write_outputs(cfg, merge_run(cfg, run_dir), run_dir, processes=True)
    except WriteError as e:
        raise CliError(str(e)) from None
    print(f"{run_dir}: written from {procs_dir(run_dir)}")
    print("\n".join(summary_lines(summary)))
    return 0


def cmd_export(args: argparse.Namespace) -> int:

    run_dir = Path(args.run_dir)
    if not (run_dir / "config.yaml").is_file():
        raise RunDirError(f"{run_dir}: not a run directory (no config.yaml)")
    if args.ros2:
        return _export_ros2(run_dir, args)
    out = Path(args.out) if args.out else run_dir / "run.mcap"
    counts = write_mcap(run_dir, out)
    print(f"{out}: {sum(counts.values())} messages on {len(counts)} channels")
    return 0


def _export_ros2(run_dir: Path, args: argparse.Namespace) -> int:
    """``export --ros2``: the run as a rosbag2 directory (``rundir.ros2_bag``)."""
    from swarm_sitl.ros2.names import RosNameError
    from swarm_sitl.ros2.types import Ros2TypesError
    from swarm_sitl.rundir.ros2_bag import BagError, write_bag

    out = Path(args.out) if args.out else run_dir / "rosbag2"
    try:
        counts = write_bag(run_dir, out, args.namespace, args.distro)
    except (BagError, RosNameError, Ros2TypesError) as e:
        raise CliError(str(e)) from None
    print(f"{out}: a rosbag2 (MCAP) of {sum(counts.values())} messages on {len(counts)} topics")
    return 0


def add_check(sub: Any) -> None:
    """``swarm-sitl check``: Theorem 1's gain conditions for a config."""
    c = sub.add_parser("check", help="report Theorem 1's gain conditions for a config")
    c.add_argument("config")
    c.set_defaults(func=cmd_check)


def add_new(sub: Any) -> None:
    """``swarm-sitl new``: a config for a generated swarm."""
    n = sub.add_parser("new", help="write a config for a generated swarm (graph, formation, trajectory)")
    n.add_argument("--followers", type=int, required=True, metavar="N", help="how many followers (1..254)")
    n.add_argument("--graph", choices=GRAPHS, default="layered", help="communication graph (default layered)")
    n.add_argument("--formation", choices=FORMATIONS, default="grid", help="formation shape (default grid)")
    n.add_argument(
        "--trajectory", choices=TRAJECTORIES, default="helix", help="leader's path (default helix)"
    )
    n.add_argument("--seed", type=int, default=0, help="random graph and initial positions (default 0)")
    n.add_argument("--duration", type=float, default=60.0, help="duration_s of the config [s] (default 60)")
    n.add_argument(
        "--law",
        metavar="ENTRY",
        help="the followers' law: 'package.module:Class' or 'path/file.py:Class' (default: the paper's)",
    )
    n.add_argument(
        "--vehicle",
        metavar="MODEL",
        help="the vehicle model: paper_vtol (default), px4_quad_x or 'file.py:Class' (docs/vehicles.md)",
    )
    n.add_argument(
        "--vehicle-param",
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="one of the model's parameters, written under vehicle.params (repeat for more)",
    )
    n.add_argument("-o", required=True, metavar="FILE", help="the config file to write")
    n.add_argument("--force", action="store_true", help="overwrite FILE if it exists")
    n.set_defaults(func=cmd_new)


def add_router(sub: Any) -> None:
    """``swarm-sitl router``: a zenoh router for a swarm over several hosts."""
    ro = sub.add_parser("router", help="a zenoh router for a swarm spread over several hosts")
    ro.add_argument(
        "--listen",
        nargs="+",
        required=True,
        metavar="ENDPOINT",
        help="zenoh endpoints to listen on, e.g. tcp/192.168.1.10:7447",
    )
    ro.add_argument(
        "--users-file",
        metavar="FILE",
        help="user:password lines; sessions must authenticate as one (zenoh usrpwd). Without it the "
        "router takes any session: use it only on a network you trust",
    )
    ro.set_defaults(func=cmd_router)


def add_plot(sub: Any) -> None:
    """``swarm-sitl plot``: a run directory's figures."""
    pl = sub.add_parser("plot", help="draw the figures of a run directory as PNG")
    pl.add_argument("run_dir")
    pl.add_argument("--out", help="output folder (default RUN_DIR/plots)")
    pl.set_defaults(func=cmd_plot)


def add_merge(sub: Any) -> None:
    """``swarm-sitl merge``: a run directory rebuilt from its raw records."""
    m = sub.add_parser("merge", help="write a run directory again from its processes' raw records")
    m.add_argument("run_dir")
    m.set_defaults(func=cmd_merge)


def add_export(sub: Any) -> None:
    """``swarm-sitl export``: a run directory as one MCAP file."""
    ex = sub.add_parser("export", help="write a run directory as one MCAP file (Foxglove opens it)")
    ex.add_argument("run_dir")
    ex.add_argument("--out", help="the MCAP file (default RUN_DIR/run.mcap; with --ros2: RUN_DIR/rosbag2)")
    ex.add_argument(
        "--ros2",
        action="store_true",
        help="instead: a rosbag2 directory (MCAP storage, CDR, type hashes) of the run's ROS 2 topics",
    )
    ex.add_argument("--namespace", default="/swarm", help="with --ros2: the topics' namespace (/swarm)")
    ex.add_argument(
        "--distro", choices=("jazzy", "humble"), default="jazzy", help="with --ros2: whose type definitions"
    )
    ex.set_defaults(func=cmd_export)
