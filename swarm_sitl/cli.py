"""``swarm-sitl``: one command line for checking, running, recording and plotting a swarm.

The subcommands are ``commands``' (and, for ``controller`` and ``leader``, the node processes'
own arguments, ``nodes.arguments``). Every user mistake ends with one line on stderr
(``swarm-sitl: error: ...``) and exit 2; a failed run exits 1, a run past its bound 3, Ctrl-C 130,
SIGTERM 143 and SIGHUP 129 (each ends a run as Ctrl-C does: the run directory written).
"""

import argparse
import sys
from collections.abc import Sequence

from swarm_sitl.commands import bench, campaign, falsify, runs, tools, view
from swarm_sitl.commands.common import EXIT_USAGE, CliError, end_on_signals, interrupted_exit
from swarm_sitl.config.load import ConfigError
from swarm_sitl.laws.graph import GraphError
from swarm_sitl.nodes.arguments import add_node_parsers
from swarm_sitl.rundir.load import RunDirError


def _node(role: str, args: argparse.Namespace) -> int:
    """``swarm-sitl controller|leader``: the node process itself (``nodes.entry``), imported when
    it runs: its modules (zenoh, pymavlink, its link) cost 0.35 s to import, measured, and no
    other command needs them."""
    from swarm_sitl.nodes.entry import run_role

    return run_role(role, args)


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="swarm-sitl", description="Software-in-the-loop bench for VTOL UAV swarms."
    )
    sub = p.add_subparsers(dest="command", required=True, metavar="COMMAND")
    tools.add_check(sub)
    tools.add_new(sub)
    runs.add_sim(sub)
    runs.add_run(sub)
    runs.add_vehicles(sub)
    runs.add_controllers(sub)
    add_node_parsers(sub, _node)
    tools.add_router(sub)
    tools.add_plot(sub)
    tools.add_export(sub)
    tools.add_merge(sub)
    view.add_view(sub)
    campaign.add_sweep(sub)
    falsify.add_falsify(sub)
    bench.add_bench(sub)
    return p


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    end_on_signals()
    try:
        return int(args.func(args))
    except (ConfigError, GraphError, RunDirError, CliError) as e:
        print(f"swarm-sitl: error: {e}", file=sys.stderr)
        return EXIT_USAGE
    except KeyboardInterrupt as e:
        code, name = interrupted_exit(e)
        print(f"swarm-sitl: interrupted ({name})", file=sys.stderr)
        return code
