"""The run directory: what a run writes and what plotting reads.

Layout::

    RUN_DIR/config.yaml        the resolved config (every default filled in)
    RUN_DIR/leader.npz         t_s, p_r, v_r, a_r              (N,), (N, 3) ...
    RUN_DIR/follower_<i>.npz   per-follower time series, one row per control tick (below)
    RUN_DIR/summary.json       final and peak errors, time to converge, invariant checks

Follower arrays (row k is tick k at ``t_s[k] = k * dt``, plus the follower's tick phase in a
staggered real-time run; vectors world ENU unless noted), for any law:

    t_s                         [s] the control tick
    sample_t_s                  [s] instant of the vehicle sample used at that tick (= t_s in sim and
                                lockstep; in real time the latest sample, up to a period older)
    p_W, v_W                    vehicle position [m], velocity [m/s] (true state)
    q_WB, omega_B               vehicle attitude [w,x,y,z; FLU->ENU], body rates [rad/s; FLU]
    thrust_N                    commanded thrust [N]
    q_c, omega_c, omegadot_c    command attitude, rate [rad/s; body], rate derivative [rad/s^2]
    pos_err_m, vel_err_mps      p - p_r - delta_i, v - v_r (p, v at sample_t_s, so is the reference)
    in_age_s                    [s] (N, in-degree): per in-neighbour (the graph's order of them,
                                ``Graph.in_neighbours(i)``), the age of the newest estimate the
                                tick had from it, used or past staleness; NaN before the first

then the law's own ``record_fields``, in its order. The paper's law records

    p_hat, v_hat, gamma, gamma_dot, eta, eta_dot   its state: estimates of the leader's p and v,
                                the estimator's gamma and the auxiliary system's eta
    u, u_dot, u_ddot            command force [m/s^2] and its derivatives
    a_hat, a_hat_dot            estimates of the leader's acceleration and jerk

and a law that records ``p_hat``, ``v_hat`` and ``a_hat`` (estimates of the leader's state)
gets their errors too: est_pos_err_m, est_vel_err_mps, est_acc_err_mps2 (p_hat - p_r, ...).

Load with ``numpy.load(path)``; ``load.load_run(RUN_DIR)`` gives them all. ``swarm-sitl run`` also
writes ``logs/``, ``tlogs/`` and ``procs/`` (each process's own rows, as they happen: ``layout``).
"""

import io
import json
import zipfile
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from sim_vehicles.common.command import AttitudeCommand
from sim_vehicles.common.state import POS, QUAT, RATE, STATE_SIZE, VEL
from swarm_sitl.laws.trajectories import Trajectory
from swarm_sitl.rundir.whole_files import whole, write_text_whole

#: what every tick records of the command, whatever the law: name -> width
COMMAND_FIELDS = {"thrust_N": 1, "q_c": 4, "omega_c": 3, "omegadot_c": 3}
COMMAND_WIDTH = sum(COMMAND_FIELDS.values())
ESTIMATES = ("p_hat", "v_hat", "a_hat")  #: a law's estimates of the leader's state, if it records them


def layout(fields: Mapping[str, int]) -> dict[str, slice]:
    """Where each field of ``fields`` (name -> width) lies in one flat row, in order."""
    out, at = {}, 0
    for name, width in fields.items():
        out[name] = slice(at, at + width)
        at += width
    return out


def command_parts(cmd: AttitudeCommand) -> tuple[tuple[float], np.ndarray, np.ndarray, np.ndarray]:
    """``cmd`` in ``COMMAND_FIELDS``' order, as parts of a row (``np.concatenate`` joins them)."""
    return (cmd.thrust_N,), cmd.q_c, cmd.omega_c_B, cmd.omegadot_c_B


class FollowerSeries:
    """Preallocated rows for one follower; ``arrays()`` splits them into the named series.
    ``record_fields``: the law's (name -> width)."""

    def __init__(self, n_rows: int, record_fields: Mapping[str, int], n_in: int = 0):
        """``n_in``: the follower's in-neighbours (``in_age_s``' columns)."""
        self.n = n_rows
        self.record_fields = dict(record_fields)
        self.in_age_s = np.full((n_rows, n_in), np.nan)
        self.t_s = np.full(n_rows, np.nan)
        self.vehicle = np.full((n_rows, STATE_SIZE), np.nan)
        self.command = np.full((n_rows, COMMAND_WIDTH), np.nan)
        self.record = np.full((n_rows, sum(self.record_fields.values())), np.nan)
        self.sample_t_s = np.full(n_rows, np.nan)

    def record_vehicle(self, k: int, t_s: float, state: np.ndarray, sample_t_s: float | None = None) -> None:
        self.t_s[k] = t_s
        self.sample_t_s[k] = t_s if sample_t_s is None else sample_t_s
        self.vehicle[k] = state

    def record_controller(
        self,
        k: int,
        command: AttitudeCommand,
        record: np.ndarray,
        in_age_s: np.ndarray | list[float] | None = None,
    ) -> None:
        """The law's command and flat record (``layout`` of ``record_fields``) at tick ``k``, and
        the ages of its in-neighbours' newest estimates."""
        if in_age_s is not None:
            self.in_age_s[k] = in_age_s
        np.concatenate(command_parts(command), out=self.command[k])
        self.record[k] = record

    #: what the rows are kept in, one array each (``spool`` writes each to its own file)
    GROUPS = ("t_s", "sample_t_s", "vehicle", "command", "record", "in_age_s")

    def arrays(self) -> dict[str, np.ndarray]:
        return series_arrays({g: getattr(self, g) for g in self.GROUPS}, self.record_fields)


class Series(Protocol):
    """What a run records a follower's rows through, tick by tick, in order: ``FollowerSeries``
    in memory, ``spool.SpooledSeries`` on disk."""

    def record_vehicle(
        self, k: int, t_s: float, state: np.ndarray, sample_t_s: float | None = None
    ) -> None: ...

    def record_controller(
        self,
        k: int,
        command: AttitudeCommand,
        record: np.ndarray,
        in_age_s: np.ndarray | list[float] | None = None,
    ) -> None: ...


#: makes follower ``i``'s series: ``(i, n_rows, record_fields, n_in)``
SeriesMaker = Callable[[int, int, Mapping[str, int], int], Series]


def in_memory(i: int, n_rows: int, record_fields: Mapping[str, int], n_in: int) -> FollowerSeries:
    """The ``SeriesMaker`` of a recording kept in memory."""
    return FollowerSeries(n_rows, record_fields, n_in)


def series_arrays(
    groups: Mapping[str, np.ndarray], record_fields: Mapping[str, int]
) -> dict[str, np.ndarray]:
    """A follower's named series (module docstring) from its rows' ``FollowerSeries.GROUPS``."""
    x, c, r = groups["vehicle"], groups["command"], groups["record"]
    out = {
        "t_s": groups["t_s"],
        "sample_t_s": groups["sample_t_s"],
        "p_W": x[:, POS],
        "v_W": x[:, VEL],
        "q_WB": x[:, QUAT],
        "omega_B": x[:, RATE],
        "in_age_s": groups["in_age_s"],
    }
    for name, at in layout(COMMAND_FIELDS).items():
        out[name] = c[:, at.start] if name == "thrust_N" else c[:, at]
    for name, at in layout(record_fields).items():
        out[name] = r[:, at.start] if record_fields[name] == 1 else r[:, at]
    return out


@dataclass
class Recording:
    """Everything a run produced, in memory."""

    leader: dict[str, np.ndarray]
    followers: dict[int, dict[str, np.ndarray]]
    offsets: dict[int, np.ndarray]
    #: what ``sim`` saw happen (its vehicles' ``failsafe_enter``/``_exit``: ``t_s``, ``kind`` and
    #: fields, as ``events.jsonl`` has them); a run of processes has its events in its directory
    events: list[dict[str, Any]] = field(default_factory=list)

    def with_errors(self, trajectory: Trajectory | None = None) -> "Recording":
        """Add the error series (idempotent). Where a follower's samples are not at the leader's
        ticks (``sample_t_s``, real time), ``trajectory`` gives the reference at the sample
        instants; where its own ticks are not (``t_s``, staggered real time), at its ticks."""
        L = self.leader

        def reference(t_s: np.ndarray, at_leader_ticks: bool) -> tuple[np.ndarray, ...]:
            if trajectory is None or at_leader_ticks:
                return L["p_r"], L["v_r"], L["a_r"]
            d = trajectory.derivatives(np.nan_to_num(t_s, nan=0.0))
            missing = np.isnan(t_s)[:, None]
            return tuple(np.where(missing, np.nan, d[:, j]) for j in range(3))

        for i, a in self.followers.items():
            t = a["t_s"]
            ts = a.get("sample_t_s", t)
            p_r, v_r, _ = reference(ts, np.array_equal(ts, L["t_s"], equal_nan=True))
            a["pos_err_m"] = a["p_W"] - p_r - self.offsets[i]
            a["vel_err_mps"] = a["v_W"] - v_r
            if all(name in a and a[name].shape == a["p_W"].shape for name in ESTIMATES):
                p_r, v_r, a_r = reference(t, np.array_equal(t, L["t_s"], equal_nan=True))
                a["est_pos_err_m"] = a["p_hat"] - p_r
                a["est_vel_err_mps"] = a["v_hat"] - v_r
                a["est_acc_err_mps2"] = a["a_hat"] - a_r
        return self


def leader_series(trajectory: Trajectory, t_s: np.ndarray) -> dict[str, np.ndarray]:
    d = trajectory.derivatives(t_s)
    return {"t_s": t_s, "p_r": d[:, 0], "v_r": d[:, 1], "a_r": d[:, 2]}


def save_npz(path: Path, arrays: dict[str, np.ndarray]) -> None:
    """``numpy.savez`` with fixed member dates, so the same arrays give the same bytes (numpy
    stamps each member with the time of writing), each in C order (as ``spool.NpzBlocks`` writes
    them a block at a time; numpy would keep a Fortran-ordered view so); ``numpy.load`` reads it
    as any .npz."""
    with whole(path) as tmp, zipfile.ZipFile(tmp, "w", zipfile.ZIP_STORED, allowZip64=True) as z:
        for name, a in arrays.items():
            buf = io.BytesIO()
            np.lib.format.write_array(buf, np.ascontiguousarray(a), allow_pickle=False)
            z.writestr(npz_member(name), buf.getvalue())


def npz_member(name: str) -> zipfile.ZipInfo:
    """The zip entry of array ``name`` in a run's .npz, dated as ``save_npz`` dates it."""
    return zipfile.ZipInfo(f"{name}.npy", date_time=(1980, 1, 1, 0, 0, 0))


def write_run(run_dir: Path, config_yaml: str, rec: Recording, summary: dict) -> None:
    run_dir.mkdir(parents=True, exist_ok=True)
    write_text_whole(run_dir / "config.yaml", config_yaml)
    save_npz(run_dir / "leader.npz", rec.leader)
    for i, arrays in rec.followers.items():
        save_npz(run_dir / f"follower_{i}.npz", {"offset_m": rec.offsets[i], **arrays})
    write_text_whole(run_dir / "summary.json", json.dumps(summary, indent=2) + "\n")
