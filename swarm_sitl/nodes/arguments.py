"""The arguments of a node process (``controller``, ``leader``), defined once for the node's own
entry (``python -m swarm_sitl.nodes``, ``entry``) and for ``swarm-sitl controller|leader``.
Light on purpose: it imports nothing a node runs, so the command line builds its parser without
the node's modules.
"""

import argparse
from collections.abc import Callable
from typing import Any


def add_node_parsers(sub: Any, run: Callable[[str, argparse.Namespace], int]) -> None:
    """The ``controller`` and ``leader`` subcommands; ``run(role, args)`` runs one."""
    c = sub.add_parser("controller", help="one follower's controller process (spawned by run/controllers)")
    c.add_argument("config")
    c.add_argument("--id", type=int, required=True, help="follower id (= its vehicle's MAVLink system id)")
    c.add_argument(
        "--mavlink", required=True, help="pymavlink connection string, e.g. udpout:127.0.0.1:14561"
    )
    c.add_argument("--signing-key-file", help="sign the MAVLink link with this passphrase file's key")
    _common(c)
    c.set_defaults(func=lambda a: run("controller", a))
    ld = sub.add_parser("leader", help="the leader's process (spawned by run/controllers)")
    ld.add_argument("config")
    _common(ld)
    ld.set_defaults(func=lambda a: run("leader", a))


def _common(p: argparse.ArgumentParser) -> None:
    p.add_argument("--lockstep", action="store_true", help="lockstep clock (default: real time)")
    p.add_argument("--connect", action="append", default=[], help="extra zenoh endpoint to connect to")
    p.add_argument("--out", help="run directory to record into")
    p.add_argument("--duration", type=float, help="override duration_s [s]")
    p.add_argument(
        "--resume-tick",
        type=int,
        default=0,
        help="lockstep: a node restarted by a fault plan resumes at this tick",
    )
    p.add_argument(
        "--incarnation", type=int, default=0, help="how often this node was restarted (names its files)"
    )
