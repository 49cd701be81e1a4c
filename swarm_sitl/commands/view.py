"""``swarm-sitl view RUN_DIR``: a finished run in the browser (``view``), with a time slider, play,
pause and speed. Any run directory, made before the view or after: it reads what every run writes.
And what ``run --view`` and ``run --foxglove`` start: the page's server, the Foxglove stream.
"""

import argparse
import sys
import threading
from typing import Any

from swarm_sitl.commands.common import CliError
from swarm_sitl.config.schema import SwarmConfig
from swarm_sitl.view.foxglove_live import FoxgloveError, FoxgloveStream
from swarm_sitl.view.replay import ReplaySource, replay_document
from swarm_sitl.view.server import ViewError, ViewServer

DEFAULT_PORT = 8470  #: the page's port unless told another (0: a free one)


def port_number(text: str) -> int:
    """A TCP port from the command line (0: a free one)."""
    if not text.isdigit() or int(text) > 65535:
        raise argparse.ArgumentTypeError(f"a port is 0..65535, not {text!r}")
    return int(text)


def serve(source: Any, host: str, port: int, what: str) -> ViewServer:
    """The page of ``source`` served from now on; prints where (one line)."""
    try:
        server = ViewServer(source, host, port).start()
    except ViewError as e:
        raise CliError(str(e)) from None
    print(f"{what}: {server.url}", flush=True)
    return server


def stream_to_foxglove(cfg: SwarmConfig, host: str, port: int) -> FoxgloveStream:
    """A Foxglove WebSocket server for the run of ``cfg`` from now on; prints where (one line)."""
    try:
        stream = FoxgloveStream(cfg, host, port)
    except FoxgloveError as e:
        raise CliError(str(e)) from None
    print(f"foxglove: {stream.url} (Foxglove: open connection, Foxglove WebSocket)", flush=True)
    return stream


def cmd_view(args: argparse.Namespace) -> int:
    doc = replay_document(args.run_dir)  # (RunDirError: one line)
    server = serve(ReplaySource(doc), args.host, args.port, f"{doc['name']} ({args.run_dir})")
    print("Ctrl-C ends it", file=sys.stderr, flush=True)
    try:
        threading.Event().wait()  # until Ctrl-C or a signal
    finally:
        server.close()
    return 0


def add_view(sub: Any) -> None:
    """``swarm-sitl view``: a run directory in the browser."""
    v = sub.add_parser("view", help="show a finished run in the browser (time slider, play, speed)")
    v.add_argument("run_dir")
    v.add_argument(
        "--port", type=port_number, default=DEFAULT_PORT, help=f"(default {DEFAULT_PORT}; 0: a free one)"
    )
    v.add_argument("--host", default="127.0.0.1", help="the address to serve on (default: loopback only)")
    v.set_defaults(func=cmd_view)
