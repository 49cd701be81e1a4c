"""``swarm-sitl``: one command line for checking, running, recording and plotting a swarm.

Every user mistake ends with one line on stderr (``swarm-sitl: error: ...``) and a non-zero exit.
"""

import argparse
import json
import sys
import time
from collections.abc import Sequence
from datetime import datetime
from pathlib import Path

from swarm_sitl.command_attitude import SingularCommandError
from swarm_sitl.config import ConfigError, SwarmConfig, load_config
from swarm_sitl.graph import GraphError
from swarm_sitl.recording import Recording, RunDirError

EXIT_USAGE = 2


class CliError(Exception):
    """A user-facing error: printed as one line, exit code 2."""


def _load(path: str) -> SwarmConfig:
    return load_config(path)


def _default_run_dir(cfg: SwarmConfig, kind: str) -> Path:
    return Path("runs") / f"{cfg.name}-{kind}-{datetime.now().strftime('%Y%m%d-%H%M%S')}"


def _with_duration(cfg: SwarmConfig, duration_s: float | None) -> SwarmConfig:
    if duration_s is None:
        return cfg
    if not duration_s > 0:
        raise CliError(f"--duration must be > 0, got {duration_s}")
    return cfg.model_copy(update={"duration_s": float(duration_s)})


def cmd_check(args: argparse.Namespace) -> int:
    from swarm_sitl.gain_conditions import check_gains
    from swarm_sitl.gain_report import render

    cfg = _load(args.config)
    report = check_gains(
        cfg.build_graph(), cfg.gain_dict(), cfg.trajectory(), cfg.gravity_mps2, max(cfg.duration_s, 200.0)
    )
    print(render(report, args.config))
    return 0


def _summary_lines(summary: dict) -> list[str]:
    s = summary["swarm"]

    def fmt(x: float | None, unit: str) -> str:
        return "never" if x is None else f"{x:.4g} {unit}"

    lines = [
        f"  formation error |p - p_r - delta|: final {s['final_pos_err_m']:.3g} m, "
        f"peak after {s['settle_from_s']:.0f} s {s['peak_pos_err_after_settle_m']:.3g} m; "
        f"velocity error peak after {s['settle_from_s']:.0f} s {s['peak_vel_err_after_settle_mps']:.3g} m/s",
        f"  converged below 0.1 m at {fmt(s['time_to_0.1m_s'], 's')}, below 0.01 m at "
        f"{fmt(s['time_to_0.01m_s'], 's')}",
        f"  min u_z {s['min_u_z_mps2']:.3f} m/s^2 (floor g - k_gamma - 2 k_eta = {s['u_z_floor_mps2']:.3f}); "
        f"max thrust / bound {s['max_thrust_over_bound']:.3f}",
    ]
    return lines


def write_outputs(cfg: SwarmConfig, rec: Recording, run_dir: Path) -> dict:
    from swarm_sitl.metrics import summarize
    from swarm_sitl.recording import write_run

    masses = {f.id: cfg.vehicle.mass_kg for f in cfg.followers}
    summary = summarize(rec, cfg.gain_dict(), masses, cfg.gravity_mps2)
    write_run(run_dir, cfg.to_yaml(), rec, summary)
    return summary


def cmd_sim(args: argparse.Namespace) -> int:
    cfg = _with_duration(_load(args.config), args.duration)
    from swarm_sitl.sim import run_sim

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
    summary = write_outputs(cfg, rec, run_dir)
    print(
        f"sim {cfg.name}: {cfg.duration_s:g} s simulated in {wall:.2f} s wall "
        f"({cfg.duration_s / wall:.1f}x real time) -> {run_dir}"
    )
    print("\n".join(_summary_lines(summary)))
    return 0


def cmd_plot(args: argparse.Namespace) -> int:
    from swarm_sitl.plots import plot_run
    from swarm_sitl.recording import load_run

    run_dir = Path(args.run_dir)
    rec = load_run(run_dir)
    bounds = None
    summary_path = run_dir / "summary.json"
    if summary_path.is_file():
        s = json.loads(summary_path.read_text())
        bounds = {int(i): f["thrust_bound_N"] for i, f in s["followers"].items()}
    out = Path(args.out) if args.out else run_dir / "plots"
    for p in plot_run(rec, out, bounds):
        print(p)
    return 0


def cmd_bench(args: argparse.Namespace) -> int:
    from swarm_sitl.bench import run_bench

    return run_bench(args.config, repeats=args.repeats)


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="swarm-sitl", description="Software-in-the-loop bench for VTOL UAV swarms."
    )
    sub = p.add_subparsers(dest="command", required=True, metavar="COMMAND")

    c = sub.add_parser("check", help="report Theorem 1's gain conditions for a config")
    c.add_argument("config")
    c.set_defaults(func=cmd_check)

    s = sub.add_parser("sim", help="run the whole swarm in one process and write a run directory")
    s.add_argument("config")
    s.add_argument("--out", help="run directory (default runs/<name>-sim-<time>)")
    s.add_argument("--duration", type=float, help="override duration_s [s]")
    s.add_argument("--quiet", action="store_true", help="no progress bar")
    s.set_defaults(func=cmd_sim)

    pl = sub.add_parser("plot", help="draw the figures of a run directory as PNG")
    pl.add_argument("run_dir")
    pl.add_argument("--out", help="output folder (default RUN_DIR/plots)")
    pl.set_defaults(func=cmd_plot)

    b = sub.add_parser("bench", help="measure speed figures and print them")
    b.add_argument("--config", default=str(Path("configs") / "paper.yaml"))
    b.add_argument("--repeats", type=int, default=3)
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
