"""What the commands share: the exit codes, the one-line user error, the config and run directory
of a command, the summary lines, and the options several commands take.

Imports are at the top but for three parts, each imported by the commands that run it: measured
after the config schema every command needs (0.6 s), matplotlib costs 0.44 s (``plot``, and
``bench``: 0.54 s with its runs), the run machinery (``running``) 0.12 s (``sim``, ``run``,
``vehicles``, ``controllers``) and a node's own modules 0.17 s (``controller``, ``leader``).
"""

import argparse
import math
import signal
import sys
from datetime import datetime
from pathlib import Path

from swarm_sitl.config.load import load_config
from swarm_sitl.config.schema import SwarmConfig
from swarm_sitl.rundir.metrics import describe_inputs

EXIT_FAILED = 1  #: a process of the run failed
EXIT_USAGE = 2
EXIT_DEGRADED = 3  #: the run completed, and a follower broke run.max_formation_error_m


class CliError(Exception):
    """A user-facing error: printed as one line, exit code 2."""


def load(path: str) -> SwarmConfig:
    """The config at ``path``; what it says the old way is one notice line each on stderr."""
    cfg = load_config(path)
    for line in cfg.notices:
        print(f"swarm-sitl: notice: {path}: {line}", file=sys.stderr)
    return cfg


def default_run_dir(cfg: SwarmConfig, kind: str) -> Path:
    return Path("runs") / f"{cfg.name}-{kind}-{datetime.now().strftime('%Y%m%d-%H%M%S')}"


def run_dir_of(out: str | None, cfg: SwarmConfig, kind: str) -> Path:
    """``--out`` (default ``default_run_dir``), refused in one line before anything starts if it
    is not a directory that can be created or written."""
    path = Path(out) if out else default_run_dir(cfg, kind)
    if path.exists() and not path.is_dir():
        raise CliError(f"--out {path}: exists and is not a directory")
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise CliError(f"--out {path}: cannot create it ({e.strerror})") from None
    probe = path / ".swarm-sitl-write-test"
    try:
        probe.write_bytes(b"")
        probe.unlink()
    except OSError as e:
        raise CliError(f"--out {path}: cannot write in it ({e.strerror})") from None
    return path


#: the signals that end a command as Ctrl-C does (what timeout, systemd, CI runners and container
#: stops send, and a closed terminal)
ENDING_SIGNALS = (signal.SIGTERM, signal.SIGHUP)


class Terminated(KeyboardInterrupt):
    """SIGTERM or SIGHUP, raised where the main thread is, handled as Ctrl-C is."""

    def __init__(self, signum: int):
        super().__init__(signal.Signals(signum).name)
        self.signum = signum


def end_on_signals() -> None:
    """SIGTERM and SIGHUP raise ``Terminated`` in the main thread (default: die on the spot,
    writing nothing)."""

    def raise_terminated(signum: int, frame: object) -> None:
        raise Terminated(signum)

    for s in ENDING_SIGNALS:
        signal.signal(s, raise_terminated)


def interrupted_exit(e: BaseException | None) -> tuple[int, str]:
    """Exit code (128 + the signal) and its name for an interruption (``Terminated`` or Ctrl-C)."""
    signum = e.signum if isinstance(e, Terminated) else signal.SIGINT
    return 128 + signum, signal.Signals(signum).name


def summary_lines(summary: dict) -> list[str]:
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
        f"max thrust / bound {s['max_thrust_over_bound']:.3f}"
        if "min_u_z_mps2" in s
        else f"  max thrust / the vehicle's maximum {s['max_thrust_over_bound']:.3f}",
    ]
    for name, r in summary.get("spec", {}).items():  # the config's requirements
        rob = r["robustness"]
        least = min(r["members"].items(), key=lambda kv: -math.inf if kv[1] is None else kv[1], default=None)
        lines.append(
            f"  requirement {name}: {'holds' if r['holds'] else 'FAILS'}, robustness "
            + ("not recorded" if rob is None else f"{rob:.4g}")
            + (f" (least: {least[0]})" if least is not None else "")
        )
    return lines


def degraded_lines(summary: dict) -> list[str]:
    """What the controllers reported of late, old or missing inputs, one line per follower."""
    out = []

    for i, rep in sorted(summary.get("inputs", {}).items(), key=lambda kv: int(kv[0])):
        why = describe_inputs(rep)
        if why:
            out.append(f"  follower {i} degraded inputs: {why}")
    for i in summary.get("lost", []):
        out.append(f"  vehicle {i} lost (a fault plan's): its follower is recorded up to the loss")
    for i, refused in sorted(summary.get("vehicles", {}).items(), key=lambda kv: int(kv[0])):
        for port, n in sorted(refused.get("rx_unsigned", {}).items()):
            if n:
                out.append(
                    f"  vehicle {i}: {n} unsigned messages refused on its {port.replace('_', '-')} port "
                    "(a signed run: sign with RUN_DIR/mavlink_signing.key, docs/tools.md)"
                )
    for edge, st in sorted(summary.get("links", {}).items()):
        if st.get("lost") or st.get("corrupt") or st.get("delayed") or st.get("duplicated"):
            out.append(
                f"  {edge if edge.startswith('mavlink') else 'edge ' + edge}: "
                f"{st['delivered']} of {st['received']} delivered, {st['lost']} lost, "
                f"{st['corrupt']} corrupt, {st['delayed']} delayed, {st['duplicated']} duplicated"
                + (f", {st['held']} held at the end" if st.get("held") else "")
                + _radio(st)
            )
    return out


def _radio(st: dict) -> str:
    """What the radio models did on an edge (``faults.radio_range``, ``faults.bandwidth``), if any."""
    parts = [f"{st[k]} {k.replace('_', ' ')}" for k in ("out_of_range", "queue_full", "retried") if st.get(k)]
    d = st.get("distance_m")
    if d:
        parts.append(f"{d['min']:.1f}..{d['max']:.1f} m apart")
    return f" ({', '.join(parts)})" if parts else ""


def held_to_bound(failures: list[str]) -> int:
    """``EXIT_DEGRADED`` with one line per follower past ``run.max_formation_error_m``, else 0."""
    for line in failures:
        print(f"swarm-sitl: error: {line}", file=sys.stderr)
    return EXIT_DEGRADED if failures else 0


def check_base_port(cfg: SwarmConfig, base_port: int) -> None:
    from swarm_sitl.running.vehicles import GCS_PORT_OFFSET  # the run machinery: 0.12 s (module doc)

    if not (base_port == 0 or 1024 <= base_port <= 65535 - GCS_PORT_OFFSET - cfg.n_followers):
        raise CliError(
            f"--base-port must be 0 (free ports) or a port from 1024 with room for "
            f"{cfg.n_followers} vehicles and their ground-station ports {GCS_PORT_OFFSET} above, "
            f"got {base_port}"
        )


def add_base_port(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--base-port",
        type=int,
        default=0,
        help="vehicle i takes its controller on BASE_PORT + i and a ground station on BASE_PORT + 3990 + i, "
        "which sends to 127.0.0.1:14550 until one speaks (14580: PX4 SITL's ports; default: free ports)",
    )


def add_run_outputs(p: argparse.ArgumentParser, kind: str) -> None:
    p.add_argument("--out", help=f"run directory (default runs/<name>-{kind}-<time>)")
    p.add_argument("--duration", type=float, help="override duration_s [s]")
    p.add_argument("--seed", type=int, help="the run's seed, of every random stream its section does not pin")
    p.add_argument(
        "--spec",
        metavar="FILE",
        help="requirements (YAML list: name, over, formula) in place of the config's",
    )
    p.add_argument("--quiet", action="store_true", help="no progress bar")
