"""Where a run directory keeps what, and the columns of the rows its processes write.

Layout (``recording`` has the arrays and their units)::

    RUN_DIR/config.yaml            the resolved config (every default filled in)
    RUN_DIR/leader.npz             the reference at each tick
    RUN_DIR/follower_<i>.npz       one row per control tick
    RUN_DIR/summary.json           final and peak errors, time to converge, invariants; a run adds
                                   links, inputs, lost, faults and vehicles
    RUN_DIR/events.jsonl           what happened, in time order (``events``)
    RUN_DIR/logs/<process>.log     each process's output
    RUN_DIR/tlogs/vehicle_<i>.tlog every MAVLink message in and out of vehicle i
    RUN_DIR/procs/                 each process's own rows, events and figures, written as they
                                   happen (merged by ``merge``):
        controller_<i>[.<n>].rows        ``controller_columns`` (incarnation n of a restarted one)
        controller_<i>[.<n>].events      and .stats.json
        vehicle_<i>.truth                ``TRUTH_COLUMNS``: the true state at each sample it sent
        vehicle_<i>.events, vehicle_<i>.stats.json, leader[.<n>].stats.json
        supervisor.events, start.json
    RUN_DIR/mavlink_signing.key    the run's MAVLink signing passphrase (0600)
    RUN_DIR/zenoh_users.txt        the run's zenoh router's users and passwords (0600)
"""

import json
from collections.abc import Mapping
from pathlib import Path

from sim_vehicles.common.state import TRUTH_COLUMNS
from swarm_sitl.rundir.recording import COMMAND_FIELDS

__all__ = ["SAMPLE_COLUMNS", "TRUTH_COLUMNS", "controller_columns"]

#: the vehicle sample a controller's tick used [ENU/FLU]
SAMPLE_COLUMNS = [f"sample_{n}" for n in ("px", "py", "pz", "vx", "vy", "vz", "qw", "qx", "qy", "qz")]


def controller_columns(record_fields: Mapping[str, int], n_in: int = 0) -> list[str]:
    """A controller's row per tick (``procs/controller_<i>.rows``): the tick and its instants [s],
    the vehicle sample it used, the command (``recording.COMMAND_FIELDS``), the law's record
    (its ``record_fields``), a field of width w as ``name.0`` .. ``name.<w-1>``, and the age of
    the newest estimate it had from each of its ``n_in`` in-neighbours (``in_age_s.j``, in the
    graph's order; NaN before it had one)."""

    def named(fields: Mapping[str, int]) -> list[str]:
        return [f"{name}.{j}" for name, width in fields.items() for j in range(width)]

    return [
        "k",
        "t_s",
        "sample_boot_s",
        "sample_t_s",
        "late_s",
        "done_s",
        *SAMPLE_COLUMNS,
        *named(COMMAND_FIELDS),
        *named(record_fields),
        *(f"in_age_s.{j}" for j in range(n_in)),
    ]


def procs_dir(run_dir: Path) -> Path:
    return run_dir / "procs"


def _incarnated(name: str, incarnation: int) -> str:
    """A process's file stem: ``controller_2``, then ``controller_2.1`` once restarted, ..."""
    return name if incarnation == 0 else f"{name}.{incarnation}"


def controller_rows_path(run_dir: Path, i: int, incarnation: int = 0) -> Path:
    return procs_dir(run_dir) / f"{_incarnated(f'controller_{i}', incarnation)}.rows"


def controller_incarnations(run_dir: Path, i: int, suffix: str, killed: str = "") -> list[Path]:
    """Follower ``i``'s controller files of kind ``suffix`` (``.rows``, ``.events``,
    ``.stats.json``) that exist, one per incarnation (each has its rows from the start), in order.
    A killed incarnation wrote no ``.stats.json``; with ``killed`` (``.counts``), its file of that
    kind stands in for it if it has one."""
    found = []
    for n in range(1000):
        stem = procs_dir(run_dir) / _incarnated(f"controller_{i}", n)
        if not stem.with_name(stem.name + ".rows").is_file():
            break
        for kind in (suffix, killed) if killed else (suffix,):
            p = stem.with_name(stem.name + kind)
            if p.is_file():
                found.append(p)
                break
    return found


def vehicle_config_path(run_dir: Path, i: int) -> Path:
    """What vehicle ``i`` is (``sim_vehicles.models.vehicle_config``), as the run hands it to its process."""
    return procs_dir(run_dir) / f"vehicle_{i}.config.json"


def vehicle_truth_path(run_dir: Path, i: int) -> Path:
    return procs_dir(run_dir) / f"vehicle_{i}.truth"


def controller_events_path(run_dir: Path, i: int, incarnation: int = 0) -> Path:
    return procs_dir(run_dir) / f"{_incarnated(f'controller_{i}', incarnation)}.events"


def controller_stats_path(run_dir: Path, i: int, incarnation: int = 0) -> Path:
    return procs_dir(run_dir) / f"{_incarnated(f'controller_{i}', incarnation)}.stats.json"


def counts_path(run_dir: Path, i: int, incarnation: int = 0) -> Path:
    """What follower ``i``'s controller counted on its in-edges and its MAVLink link under a fault
    plan, in one incarnation (``NamedCounts``), kept even when the incarnation is killed."""
    return procs_dir(run_dir) / f"{_incarnated(f'controller_{i}', incarnation)}.counts"


def published_path(run_dir: Path, node: int, incarnation: int = 0) -> Path:
    """How many messages node ``node`` (0: the leader) published in one incarnation: a counter
    file (``sim_vehicles.runtime.counter_file``), kept even when the incarnation is killed."""
    name = "leader" if node == 0 else f"controller_{node}"
    return procs_dir(run_dir) / f"{_incarnated(name, incarnation)}.published"


def tick_path(run_dir: Path, stem: str) -> Path:
    """Process ``stem``'s (``controller_2.1``, ``leader``) newest published tick plus one: a counter
    file (0: none yet), kept when the process ends (``running.ends``)."""
    return procs_dir(run_dir) / f"{stem}.tick"


def node_stem(node: int, incarnation: int = 0) -> str:
    return _incarnated("leader" if node == 0 else f"controller_{node}", incarnation)


def leader_stats_path(run_dir: Path, incarnation: int = 0) -> Path:
    return procs_dir(run_dir) / f"{_incarnated('leader', incarnation)}.stats.json"


def supervisor_events_path(run_dir: Path) -> Path:
    return procs_dir(run_dir) / "supervisor.events"


def lost_events_path(run_dir: Path) -> Path:
    """Processes that exited unplanned and that a real-time run flew on without (``process_lost``)."""
    return procs_dir(run_dir) / "lost.events"


def router_events_path(run_dir: Path) -> Path:
    """The zenoh router's loss and return, as the supervisor saw them (``zenoh.mode: client``)."""
    return procs_dir(run_dir) / "router.events"


def vehicle_stats_path(run_dir: Path, i: int) -> Path:
    return procs_dir(run_dir) / f"vehicle_{i}.stats.json"


def vehicle_events_path(run_dir: Path, i: int) -> Path:
    return procs_dir(run_dir) / f"vehicle_{i}.events"


def external_path(run_dir: Path) -> Path:
    """What ``run --external`` tells the controllers it does not run (``docs/bus.md``; 0600)."""
    return run_dir / "external.json"


def start_path(run_dir: Path) -> Path:
    """The start signal of a multi-process run: ``{"epoch_unix_s": ..., "lockstep": ...}``."""
    return procs_dir(run_dir) / "start.json"


def read_start(run_dir: Path) -> dict | None:
    try:
        d = json.loads(start_path(run_dir).read_text())
    except (OSError, ValueError):
        return None
    return d if isinstance(d, dict) and isinstance(d.get("epoch_unix_s"), int | float) else None


def signing_key_path(run_dir: Path) -> Path:
    """The MAVLink signing passphrase of a run's own vehicles (mode 0600)."""
    return run_dir / "mavlink_signing.key"


def zenoh_users_path(run_dir: Path) -> Path:
    """The zenoh router's ``user:password`` dictionary of a run (mode 0600)."""
    return run_dir / "zenoh_users.txt"


def ros2_join_path(run_dir: Path) -> Path:
    """A run with ``ros2:`` on: how a ROS 2 node joins it (``ros2_join.json``: the router's
    endpoint, the user, its password's file, the domain, and the one line for a shell)."""
    return run_dir / "ros2_join.json"


def zenoh_ros2_controller_password_path(run_dir: Path, follower: int) -> Path:
    """The password of the user the ROS 2 node flying ``follower`` joins as, alone (mode 0600)."""
    return run_dir / f"zenoh_ros2_controller_{follower}_password.txt"


def zenoh_ros2_password_path(run_dir: Path) -> Path:
    """A run with ``ros2:`` on: the password of the router's ROS 2 user, alone (mode 0600)."""
    return run_dir / "zenoh_ros2_password.txt"


#: bytes a vehicle's .tlog takes per control tick (its setpoint, its sample and the slower streams,
#: each with an 8-byte timestamp): measured on the paper run, 300 rounds it up
TLOG_BYTES_PER_TICK = 300


def expected_run_bytes(n_ticks: int, n_followers: int, record_fields: Mapping[str, int]) -> int:
    """About how many bytes a multi-process run writes: per follower and tick its controller's
    row, the same row again in ``follower_<i>.npz``, its vehicle's truth row and .tlog traffic
    (the paper run, 4 followers for 60 s: 33.3 MB written, 32.9 MB estimated)."""
    row = 8 * len(controller_columns(record_fields))
    per_tick = 2 * row + 8 * len(TRUTH_COLUMNS) + TLOG_BYTES_PER_TICK
    return n_ticks * n_followers * per_tick


def sim_spool_dir(run_dir: Path) -> Path:
    """``sim``'s rows, spooled a block at a time until its arrays are written (``spool``);
    removed then."""
    return run_dir / ".spool"
