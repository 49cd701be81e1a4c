"""The vehicles of a run: one ``python -m sim_vehicles`` per follower, started, and their ports.

``start_vehicles`` spawns one vehicle per follower from the config (its plant, its attitude loop,
its failsafe, its signing, its files under the run directory) and waits until each says where it
listens: its controller's port and its ground station's. ``signing_key_file`` is the passphrase
every vehicle link of the run is signed with.
"""

import contextlib
import re
import secrets
import time
from collections.abc import Mapping
from pathlib import Path

from sim_vehicles.mavlink.signing import SigningKeyError, read_key
from sim_vehicles.runtime.secret_file import write_secret
from swarm_sitl.config.schema import SwarmConfig
from swarm_sitl.rundir.layout import (
    procs_dir,
    signing_key_path,
    vehicle_config_path,
    vehicle_events_path,
    vehicle_stats_path,
    vehicle_truth_path,
)
from swarm_sitl.running.children import module_argv
from swarm_sitl.running.supervisor import RunFailedError, Supervisor

_LISTENING = re.compile(r"listening on udp:([0-9.]+):(\d+)")
_GROUND_STATION = re.compile(r"ground station on udp:([0-9.]+):(\d+)")
#: ``--base-port B``: vehicle i listens for its controller on B + i and for a ground station on
#: B + GCS_PORT_OFFSET + i, and its ground-station port sends to GCS_REMOTE until one speaks to it:
#: with B = 14580, PX4 SITL's scheme (offboard 14580 + i, ground station 18570 + i -> 14550)
PX4_BASE_PORT = 14580
GCS_PORT_OFFSET = 3990
GCS_REMOTE = "127.0.0.1:14550"


def signing_key_file(cfg: SwarmConfig, run_dir: Path, own_vehicles: bool) -> Path | None:
    """The passphrase file every vehicle link of this run is signed with (``SigningSection``), or
    None: the one the config gives, else for vehicles this run spawns a fresh random one written
    to ``RUN_DIR/mavlink_signing.key``, readable by this user only."""
    if not cfg.signing.enabled:
        return None
    if cfg.signing.passphrase_file is not None:
        try:  # refused now, in one line, rather than in every child
            read_key(cfg.signing.passphrase_file)
        except SigningKeyError as e:
            raise RunFailedError(f"signing.passphrase_file: {e}") from None
        return Path(cfg.signing.passphrase_file)
    if not own_vehicles:
        return None
    path = signing_key_path(run_dir)
    write_secret(path, secrets.token_hex(32) + "\n")
    return path


def vehicle_argv(
    cfg: SwarmConfig,
    i: int,
    run_dir: Path,
    lockstep: bool,
    port: int = 0,
    key_file: Path | None = None,
    gcs_port: int = 0,
    gcs_remote: str | None = None,
    host: str = "127.0.0.1",
) -> list[str]:
    """Vehicle ``i``'s command line: what it is goes whole in its config file
    (``RUN_DIR/procs/vehicle_<i>.config.json``, written here), where it listens and writes in flags."""
    spec = vehicle_config_path(run_dir, i)
    spec.parent.mkdir(parents=True, exist_ok=True)
    spec.write_text(cfg.vehicle_config(i).to_json())
    argv = [
        *module_argv("sim_vehicles"),
        "--id",
        str(i),
        "--config",
        str(spec),
        "--host",
        host,
        "--port",
        str(port),
        "--events",
        str(vehicle_events_path(run_dir, i)),
        "--stats",
        str(vehicle_stats_path(run_dir, i)),
        *(["--signing-key-file", str(key_file)] if key_file is not None else []),
        "--gcs-port",
        str(gcs_port),
        *(["--gcs-remote", gcs_remote] if gcs_remote else []),
        "--tlog",
        str(run_dir / "tlogs" / f"vehicle_{i}.tlog"),
        "--truth",
        str(vehicle_truth_path(run_dir, i)),
    ]
    if lockstep:
        argv += ["--lockstep-period-s", repr(cfg.control_dt_s)]
    return argv


def start_vehicles(
    sup: Supervisor,
    cfg: SwarmConfig,
    lockstep: bool,
    base_port: int = 0,
    key_file: Path | None = None,
    host: str = "127.0.0.1",
    behind_relay: frozenset[int] = frozenset(),
    only: list[int] | None = None,
) -> tuple[dict[int, str], dict[int, str]]:
    """Spawn one vehicle per follower bound to ``host``, signing with ``key_file``'s key if given,
    on the ports of ``base_port`` (``PX4_BASE_PORT``; 0: free ports); returns ``{id:
    "udp:host:port"}`` of their controller ports and of their ground-station ports once each is
    listening. A vehicle in ``behind_relay`` takes its controller on a free loopback port (a
    ``vehicle_relay`` takes the one it would have had). ``only``: these followers' vehicles (the
    others are outside the run)."""
    run_dir = sup.run_dir
    (run_dir / "tlogs").mkdir(parents=True, exist_ok=True)
    procs_dir(run_dir).mkdir(parents=True, exist_ok=True)
    children = {}
    for f in cfg.followers:
        if only is not None and f.id not in only:
            continue
        port, gcs_port = (base_port + f.id, base_port + GCS_PORT_OFFSET + f.id) if base_port else (0, 0)
        if f.id in behind_relay:
            port = 0
        argv = vehicle_argv(
            cfg, f.id, run_dir, lockstep, port, key_file, gcs_port, GCS_REMOTE if base_port else None, host
        )
        children[f.id] = sup.spawn(f"vehicle_{f.id}", argv, False)
    endpoints: dict[int, str] = {}
    ground: dict[int, str] = {}
    end = time.monotonic() + cfg.run.start_timeout_s
    while len(endpoints) < len(children):
        sup.check()
        for i, c in children.items():
            if i not in endpoints:
                with contextlib.suppress(OSError):
                    log = c.log_path.read_text(errors="replace")
                    m, g = _LISTENING.search(log), _GROUND_STATION.search(log)
                    if m and g:
                        endpoints[i] = f"udp:{m.group(1)}:{m.group(2)}"
                        ground[i] = f"udp:{g.group(1)}:{g.group(2)}"
        if time.monotonic() > end:
            late = sorted(set(children) - set(endpoints))
            raise RunFailedError(
                f"vehicle(s) {late} did not start listening within {cfg.run.start_timeout_s:g} s"
            )
        time.sleep(0.02)
    return endpoints, ground


def port_lines(endpoints: Mapping[int, str], ground: Mapping[int, str]) -> list[str]:
    """One line per vehicle: where its controller and a ground station reach it."""
    return [
        f"  vehicle {i}: controller udpout:{endpoints[i].removeprefix('udp:')}, ground station "
        f"udpout:{ground[i].removeprefix('udp:')}  (MAVLink system id {i})"
        for i in sorted(endpoints)
    ]
