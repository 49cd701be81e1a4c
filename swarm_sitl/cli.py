"""``swarm-sitl``: one command line for checking, running, recording and plotting a swarm.

Every user mistake ends with one line on stderr (``swarm-sitl: error: ...``) and a non-zero exit.
"""

import argparse
import json
import math
import signal
import sys
import time
from collections.abc import Sequence
from datetime import datetime
from pathlib import Path
from typing import Any

from swarm_sitl.config.load import ConfigError, load_config, with_duration
from swarm_sitl.config.schema import SwarmConfig
from swarm_sitl.laws.command_attitude import SingularCommandError
from swarm_sitl.laws.graph import GraphError
from swarm_sitl.nodes.entry import add_node_parsers
from swarm_sitl.rundir.load import RunDirError

EXIT_FAILED = 1  #: a process of the run failed
EXIT_USAGE = 2
EXIT_DEGRADED = 3  #: the run completed, and a follower broke run.max_formation_error_m


class CliError(Exception):
    """A user-facing error: printed as one line, exit code 2."""


def _load(path: str) -> SwarmConfig:
    return load_config(path)


def _default_run_dir(cfg: SwarmConfig, kind: str) -> Path:
    return Path("runs") / f"{cfg.name}-{kind}-{datetime.now().strftime('%Y%m%d-%H%M%S')}"


def cmd_check(args: argparse.Namespace) -> int:
    from swarm_sitl.laws.gain_conditions import check_gains
    from swarm_sitl.laws.gain_report import render

    cfg = _load(args.config)
    report = check_gains(
        cfg.build_graph(), cfg.gain_dict(), cfg.trajectory(), cfg.gravity_mps2, max(cfg.duration_s, 200.0)
    )
    print(render(report, args.config, cfg.estimator.bracket))
    return 0


def cmd_router(args: argparse.Namespace) -> int:
    from swarm_sitl.bus.session import error_line, open_plain_router, router_runtime

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


def cmd_new(args: argparse.Namespace) -> int:
    from swarm_sitl.config.generator import GeneratorError, generate

    try:
        text = generate(args.followers, args.graph, args.formation, args.trajectory, args.seed, args.duration)
    except GeneratorError as e:
        raise CliError(str(e)) from None
    out = Path(args.o)
    if out.exists() and not args.force:
        raise CliError(f"{out} exists (--force to overwrite)")
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(text)
    except OSError as e:
        raise CliError(f"cannot write {out}: {e.strerror}") from None
    gains = [line.strip()[2:] for line in text.splitlines() if line.startswith("  # ") and "gains" in line]
    print(f"wrote {out}: {args.followers} followers, {args.graph} graph, {args.formation}, {args.trajectory}")
    for line in gains[:1]:
        print(f"  gains: {line}")
    return 0


def _summary_lines(summary: dict) -> list[str]:
    s = summary["swarm"]

    def fmt(x: float | None, unit: str) -> str:
        return "never" if x is None else f"{x:.4g} {unit}"

    after = f"after {s['settle_from_s']:.0f} s"
    if s["peak_pos_err_after_settle_m"] is None:  # the run ended before
        peaks = f"no peak {after} (the run is shorter)"
    else:
        peaks = (
            f"peak {after} {s['peak_pos_err_after_settle_m']:.3g} m; "
            f"velocity error peak {after} {s['peak_vel_err_after_settle_mps']:.3g} m/s"
        )
    lines = [
        f"  formation error |p - p_r - delta|: final {s['final_pos_err_m']:.3g} m, {peaks}",
        f"  converged below 0.1 m at {fmt(s['time_to_0.1m_s'], 's')}, below 0.01 m at "
        f"{fmt(s['time_to_0.01m_s'], 's')}",
        f"  min u_z {s['min_u_z_mps2']:.3f} m/s^2 (floor g - k_gamma - 2 k_eta = {s['u_z_floor_mps2']:.3f}); "
        f"max thrust / bound {s['max_thrust_over_bound']:.3f}",
    ]
    return lines


def _held_to_bound(failures: list[str]) -> int:
    """``EXIT_DEGRADED`` with one line per follower past ``run.max_formation_error_m``, else 0."""
    for line in failures:
        print(f"swarm-sitl: error: {line}", file=sys.stderr)
    return EXIT_DEGRADED if failures else 0


def cmd_sim(args: argparse.Namespace) -> int:
    cfg = with_duration(_load(args.config), args.duration)
    from swarm_sitl.running.sim import run_sim

    run_dir = Path(args.out) if args.out else _default_run_dir(cfg, "sim")
    n = cfg.n_control_steps
    t0 = time.monotonic()
    if args.quiet:
        rec = run_sim(cfg)
    else:
        from tqdm import tqdm

        with tqdm(total=n + 1, unit="tick", desc=f"sim {cfg.name}", mininterval=0.25, leave=False) as bar:
            stride = max(1, (n + 1) // 100)

            def progress(k: int) -> None:
                if k % stride == 0 or k == n:
                    bar.update(k + 1 - bar.n)

            rec = run_sim(cfg, progress=progress)
    wall = time.monotonic() - t0
    from swarm_sitl.rundir.metrics import bound_failures
    from swarm_sitl.rundir.outputs import write_outputs

    summary = write_outputs(cfg, rec, run_dir)
    print(
        f"sim {cfg.name}: {cfg.duration_s:g} s simulated in {wall:.2f} s wall "
        f"({cfg.duration_s / wall:.1f}x real time) -> {run_dir}"
    )
    print("\n".join(_summary_lines(summary)))
    return _held_to_bound(bound_failures(summary, cfg.run.max_formation_error_m))


class _RunProgress:
    """A progress bar over ticks with each follower's formation error from its status messages."""

    def __init__(self, cfg: SwarmConfig, label: str, quiet: bool):
        self.cfg = cfg
        self.bar: Any = None
        if not quiet:
            from tqdm import tqdm

            self.bar = tqdm(
                total=cfg.n_control_steps + 1, unit="tick", desc=label, mininterval=0.25, leave=False
            )

    def __call__(self, step: int, errors_m: dict[int, float]) -> None:
        if self.bar is None:
            return
        if step + 1 > self.bar.n:
            self.bar.update(step + 1 - self.bar.n)
        if errors_m:
            worst = max(errors_m, key=lambda i: errors_m[i])
            shown = (
                " ".join(f"{i}:{e:.3f}" for i, e in sorted(errors_m.items()))
                if len(errors_m) <= 6
                else f"max {errors_m[worst]:.3f} (#{worst})"
            )
            self.bar.set_postfix_str(f"|p-p_r-d| m {shown}", refresh=False)

    def note(self, lines: list[str]) -> None:
        """Lines printed above the bar (the vehicles' ports, as they come up)."""
        if self.bar is not None:
            for line in lines:
                self.bar.write(line)
            sys.stdout.flush()  # a pipe's reader (a script waiting for the ports) gets them now

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()


def _run_and_record(
    cfg: SwarmConfig,
    run_dir: Path,
    lockstep: bool,
    quiet: bool,
    mavlink: dict[int, str] | None,
    kind: str,
    base_port: int = 0,
) -> int:
    from swarm_sitl.running.run import record_run

    clock = "lockstep" if lockstep else "real time"
    progress = _RunProgress(cfg, f"{kind} {cfg.name} ({clock})", quiet)
    try:
        out = record_run(cfg, run_dir, lockstep, mavlink, progress, base_port, progress.note)
    finally:
        progress.close()
    if out.failure is not None:
        print(
            f"swarm-sitl: error: {out.failure} (partial run in {run_dir}, logs in {run_dir / 'logs'})",
            file=sys.stderr,
        )
        return EXIT_FAILED
    if out.interrupted:
        print(f"swarm-sitl: interrupted; partial run in {run_dir}", file=sys.stderr)
        return 130
    print(
        f"{kind} {cfg.name} ({clock}): {cfg.duration_s:g} s simulated in {out.run_wall_s:.2f} s wall "
        f"({cfg.duration_s / out.run_wall_s:.1f}x real time; start-up {out.startup_wall_s:.1f} s) "
        f"-> {run_dir}"
    )
    print("\n".join(_summary_lines(out.summary)))
    for line in _degraded_lines(out.summary):
        print(line)
    return _held_to_bound(out.bound_failures)


def _degraded_lines(summary: dict) -> list[str]:
    """What the controllers reported of late, old or missing inputs, one line per follower."""
    out = []
    from swarm_sitl.rundir.metrics import describe_inputs

    for i, rep in sorted(summary.get("inputs", {}).items(), key=lambda kv: int(kv[0])):
        why = describe_inputs(rep)
        if why:
            out.append(f"  follower {i} degraded inputs: {why}")
    for i in summary.get("lost", []):
        out.append(f"  vehicle {i} lost (a fault plan's): its follower is recorded up to the loss")
    for edge, st in sorted(summary.get("links", {}).items()):
        if st.get("lost") or st.get("corrupt") or st.get("delayed") or st.get("duplicated"):
            out.append(
                f"  {edge if edge.startswith('mavlink') else 'edge ' + edge}: "
                f"{st['delivered']} of {st['received']} delivered, {st['lost']} lost, "
                f"{st['corrupt']} corrupt, {st['delayed']} delayed, {st['duplicated']} duplicated"
            )
    return out


def _with_fault_file(cfg: SwarmConfig, path: str | None) -> SwarmConfig:
    from swarm_sitl.config.load import with_faults

    return cfg if path is None else with_faults(cfg, path)


def cmd_run(args: argparse.Namespace) -> int:
    cfg = _with_fault_file(with_duration(_load(args.config), args.duration), args.faults)
    _check_base_port(cfg, args.base_port)
    run_dir = Path(args.out) if args.out else _default_run_dir(cfg, "run")
    return _run_and_record(cfg, run_dir, not args.realtime, args.quiet, None, "run", args.base_port)


def _check_base_port(cfg: SwarmConfig, base_port: int) -> None:
    from swarm_sitl.running.vehicles import GCS_PORT_OFFSET

    if not (base_port == 0 or 1024 <= base_port <= 65535 - GCS_PORT_OFFSET - cfg.n_followers):
        raise CliError(
            f"--base-port must be 0 (free ports) or a port from 1024 with room for "
            f"{cfg.n_followers} vehicles and their ground-station ports {GCS_PORT_OFFSET} above, "
            f"got {base_port}"
        )


def cmd_controllers(args: argparse.Namespace) -> int:
    cfg = _with_fault_file(with_duration(_load(args.config), args.duration), args.faults)
    if len(args.mavlink) != cfg.n_followers:
        raise CliError(
            f"--mavlink needs one connection string per follower ({cfg.n_followers}, in id order), "
            f"got {len(args.mavlink)}"
        )
    run_dir = Path(args.out) if args.out else _default_run_dir(cfg, "controllers")
    mavlink = {
        f.id: url for f, url in zip(sorted(cfg.followers, key=lambda f: f.id), args.mavlink, strict=True)
    }
    return _run_and_record(cfg, run_dir, args.lockstep, args.quiet, mavlink, "controllers")


def cmd_vehicles(args: argparse.Namespace) -> int:
    from swarm_sitl.running.run import compile_kernels
    from swarm_sitl.running.supervisor import RunFailedError, Supervisor
    from swarm_sitl.running.vehicles import port_lines, signing_key_file, start_vehicles

    cfg = _load(args.config)
    _check_base_port(cfg, args.base_port)
    run_dir = Path(args.out) if args.out else _default_run_dir(cfg, "vehicles")
    compile_kernels(cfg)
    sup = Supervisor(run_dir)
    try:
        key_file = signing_key_file(cfg, run_dir, own_vehicles=False)
        endpoints, ground = start_vehicles(sup, cfg, args.lockstep, args.base_port, key_file, args.host)
        clock = f"lockstep, {cfg.control_dt_s:g} s per setpoint" if args.lockstep else "real time"
        print(f"{cfg.n_followers} vehicles of {cfg.name} ({clock}); .tlogs in {run_dir / 'tlogs'}")
        print(f"  MAVLink 2 signing with {key_file}" if key_file else "  MAVLink 2 signing off")
        print("\n".join(port_lines(endpoints, ground)))
        print("Ctrl-C stops them", flush=True)
        while True:
            sup.check()
            time.sleep(0.1)
    except RunFailedError as e:
        raise CliError(str(e)) from None
    except KeyboardInterrupt:
        print("swarm-sitl: vehicles stopped", file=sys.stderr)
        return 0
    finally:
        sup.close()


def cmd_export(args: argparse.Namespace) -> int:
    from swarm_sitl.rundir.mcap_export import write_mcap

    run_dir = Path(args.run_dir)
    if not (run_dir / "config.yaml").is_file():
        raise RunDirError(f"{run_dir}: not a run directory (no config.yaml)")
    out = Path(args.out) if args.out else run_dir / "run.mcap"
    counts = write_mcap(run_dir, out)
    print(f"{out}: {sum(counts.values())} messages on {len(counts)} channels")
    return 0


def cmd_plot(args: argparse.Namespace) -> int:
    from swarm_sitl.rundir.load import load_run
    from swarm_sitl.rundir.plots import plot_run

    run_dir = Path(args.run_dir)
    rec = load_run(run_dir)
    bounds = summary = edges = None
    summary_path = run_dir / "summary.json"
    if summary_path.is_file():
        summary = json.loads(summary_path.read_text())
        bounds = {int(i): f["thrust_bound_N"] for i, f in summary["followers"].items()}
    events = []
    if (run_dir / "events.jsonl").is_file():
        from swarm_sitl.rundir.events import read_events

        events = read_events(run_dir / "events.jsonl")
    if "links" in (summary or {}):
        try:
            edges = load_config(run_dir / "config.yaml").graph_edges()
        except ConfigError:
            edges = None
    out = Path(args.out) if args.out else run_dir / "plots"
    for p in plot_run(rec, out, bounds, events, summary, edges):
        print(p)
    return 0


def cmd_bench(args: argparse.Namespace) -> int:
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
    try:
        if args.scale:
            from swarm_sitl.bench.scale import run_scale

            try:
                ns = [int(x) for x in args.scale.split(",")]
            except ValueError:
                raise CliError(f"--scale takes follower counts like 4,8,16, got {args.scale!r}") from None
            if not ns or min(ns) < 1 or max(ns) > 254:
                raise CliError(f"--scale: follower counts must be 1..254, got {args.scale!r}")
            out = Path(args.out) if args.out else None
            if args.split is not None and args.split not in ns:
                raise CliError(f"--split {args.split}: not one of the --scale counts {args.scale}")
            return run_scale(
                ns,
                args.scale_duration,
                out,
                args.scale_start,
                args.scale_realtime,
                args.split or 0,
                args.empty,
            )
        if args.against:
            from swarm_sitl.bench.speed import compare_trees

            return compare_trees(args.config, Path(args.against), args.repeats)
        return run_bench(args.config, args.scale_config, args.repeats, args.realtime_s)
    except RunFailedError as e:
        print(f"swarm-sitl: error: bench: {e}", file=sys.stderr)
        return 1


def _base_port(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--base-port",
        type=int,
        default=0,
        help="vehicle i takes its controller on BASE_PORT + i and a ground station on BASE_PORT + 3990 + i, "
        "which sends to 127.0.0.1:14550 until one speaks (14580: PX4 SITL's ports; default: free ports)",
    )


def _run_outputs(p: argparse.ArgumentParser, kind: str) -> None:
    p.add_argument("--out", help=f"run directory (default runs/<name>-{kind}-<time>)")
    p.add_argument("--duration", type=float, help="override duration_s [s]")
    p.add_argument("--quiet", action="store_true", help="no progress bar")


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="swarm-sitl", description="Software-in-the-loop bench for VTOL UAV swarms."
    )
    sub = p.add_subparsers(dest="command", required=True, metavar="COMMAND")

    c = sub.add_parser("check", help="report Theorem 1's gain conditions for a config")
    c.add_argument("config")
    c.set_defaults(func=cmd_check)

    from swarm_sitl.config.generator import FORMATIONS, GRAPHS, TRAJECTORIES

    n = sub.add_parser("new", help="write a config for a generated swarm (graph, formation, trajectory)")
    n.add_argument("--followers", type=int, required=True, metavar="N", help="how many followers (1..254)")
    n.add_argument("--graph", choices=GRAPHS, default="layered", help="communication graph (default layered)")
    n.add_argument("--formation", choices=FORMATIONS, default="grid", help="formation shape (default grid)")
    n.add_argument(
        "--trajectory", choices=TRAJECTORIES, default="helix", help="leader's path (default helix)"
    )
    n.add_argument("--seed", type=int, default=0, help="random graph and initial positions (default 0)")
    n.add_argument("--duration", type=float, default=60.0, help="duration_s of the config [s] (default 60)")
    n.add_argument("-o", required=True, metavar="FILE", help="the config file to write")
    n.add_argument("--force", action="store_true", help="overwrite FILE if it exists")
    n.set_defaults(func=cmd_new)

    s = sub.add_parser("sim", help="run the whole swarm in one process and write a run directory")
    s.add_argument("config")
    _run_outputs(s, "sim")
    s.set_defaults(func=cmd_sim)

    r = sub.add_parser("run", help="run the swarm as processes: vehicles, controllers, leader, zenoh")
    r.add_argument("config")
    r.add_argument("--realtime", action="store_true", help="wall clock, as in flight (default: lockstep)")
    r.add_argument("--faults", metavar="FILE", help="fault plan (YAML: seed, plan) in place of the config's")
    _base_port(r)
    _run_outputs(r, "run")
    r.set_defaults(func=cmd_run)

    v = sub.add_parser("vehicles", help="start only the simulated vehicles and print their MAVLink endpoints")
    v.add_argument("config")
    v.add_argument("--lockstep", action="store_true", help="step one control period per stamped setpoint")
    _base_port(v)
    v.add_argument(
        "--host",
        default="127.0.0.1",
        help="address the vehicles bind (default 127.0.0.1; another host's controllers need this "
        "machine's address on their network)",
    )
    v.add_argument("--out", help="directory for .tlogs and logs (default runs/<name>-vehicles-<time>)")
    v.set_defaults(func=cmd_vehicles)

    cs = sub.add_parser("controllers", help="run the leader and controllers against given MAVLink endpoints")
    cs.add_argument("config")
    cs.add_argument(
        "--mavlink",
        nargs="+",
        required=True,
        metavar="URL",
        help="one pymavlink connection string per follower",
    )
    cs.add_argument(
        "--lockstep", action="store_true", help="the vehicles step in lockstep (default: real time)"
    )
    cs.add_argument("--faults", metavar="FILE", help="fault plan (YAML: seed, plan) in place of the config's")
    _run_outputs(cs, "controllers")
    cs.set_defaults(func=cmd_controllers)

    add_node_parsers(sub)

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

    pl = sub.add_parser("plot", help="draw the figures of a run directory as PNG")
    pl.add_argument("run_dir")
    pl.add_argument("--out", help="output folder (default RUN_DIR/plots)")
    pl.set_defaults(func=cmd_plot)

    ex = sub.add_parser("export", help="write a run directory as one MCAP file (Foxglove opens it)")
    ex.add_argument("run_dir")
    ex.add_argument("--out", help="the MCAP file (default RUN_DIR/run.mcap)")
    ex.set_defaults(func=cmd_export)

    b = sub.add_parser("bench", help="measure speed figures and print them")
    b.add_argument("--config", default=str(Path("configs") / "paper.yaml"))
    b.add_argument("--repeats", type=int, default=3)
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
        type=int,
        metavar="N",
        help="--scale: also profile the N-follower run and print where each process kind's CPU goes",
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
        "--out", help="--scale: directory for scale.csv and scale.png (default runs/bench-scale-<time>)"
    )
    b.set_defaults(func=cmd_bench)
    return p


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.func(args))
    except (ConfigError, GraphError, RunDirError, SingularCommandError, CliError) as e:
        print(f"swarm-sitl: error: {e}", file=sys.stderr)
        return EXIT_USAGE
    except KeyboardInterrupt:
        print("swarm-sitl: interrupted", file=sys.stderr)
        return 130
