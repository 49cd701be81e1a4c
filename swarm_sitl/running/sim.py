"""The whole swarm in one process, through the same step functions the processes run.

Per control tick ``k`` (``laws.contract`` says what a tick is to a law,
``sim_vehicles.plant.autopilot`` what it is to the vehicle): the leader emits its reference at
``t_k``; each vehicle is sampled through the MAVLink wire representation (float32, NED/FRD); each
follower's law steps with its in-neighbours' messages of tick ``k - 1``; each command crosses the
wire representation and is held by the vehicle for ``attitude_hz / control_hz`` attitude-loop
steps. Laws know the vehicle's mass and maximum thrust as the MAVLink parameter protocol reports
them (float32). This is what ``swarm-sitl run`` does across processes in lockstep; the transport
is the only difference.

A law that fails (``nodes.law_host.LawError``) ends the run there: ``SimFailedError`` carries what was
recorded up to it.
"""

from collections.abc import Callable, Mapping
from pathlib import Path
from typing import IO, Any, TypeVar

import numpy as np

from sim_vehicles.common.command import AttitudeCommand
from sim_vehicles.mavlink.wire_format import (
    SAMPLE_P,
    SAMPLE_Q,
    SAMPLE_V,
    command_roundtrip,
    sample_fields,
    sample_from_fields,
)
from sim_vehicles.models.build import build_vehicle, sensor_model
from sim_vehicles.models.vehicle_config import VehicleConfig
from swarm_sitl.bus.codec import Message
from swarm_sitl.config.schema import SwarmConfig
from swarm_sitl.laws.contract import Received, VehicleSample
from swarm_sitl.nodes.assembly import Uplink, build_law, build_leader, reported_vehicle_params
from swarm_sitl.nodes.law_guard import LawGuard, max_output_bytes
from swarm_sitl.nodes.law_host import LawError
from swarm_sitl.rundir.recording import Recording, SeriesMaker, in_memory, leader_series
from swarm_sitl.rundir.spool import SpooledRecording, SpooledSeries
from swarm_sitl.running.sim_plan import PlannedSwarm

R = TypeVar("R", Recording, SpooledRecording)


class SimFailedError(LawError):
    """A law failed mid-run; ``recording`` is what the run recorded before (NaN after)."""

    def __init__(self, error: LawError, recording: "Recording | SpooledRecording"):
        super().__init__(str(error))
        self.recording = recording


def sample_through_wire(t_s: float, state: np.ndarray) -> VehicleSample:
    """The vehicle state as a controller sees it in LOCAL_POSITION_NED and ATTITUDE_QUATERNION."""
    f = sample_fields(state)
    s = sample_from_fields(f[0:6], f[6:10])
    return VehicleSample(t_s, s[SAMPLE_P], s[SAMPLE_V], s[SAMPLE_Q])


def _load_kernels(spec: VehicleConfig, i: int, n_att: int, max_thrust: float) -> None:
    """A scratch vehicle's tick through the wire: the compiled kernels a tick runs loaded (their
    memory taken) before a law's guard measures what the law takes."""
    ap = build_vehicle(spec, i)
    ap.set_command(command_roundtrip(AttitudeCommand(np.array([1.0, 0.0, 0.0, 0.0]), 0.0), max_thrust))
    ap.advance(n_att)
    sample_through_wire(0.0, ap.state)


def run_sim(
    cfg: SwarmConfig,
    n_steps: int | None = None,
    progress: Callable[[int], None] | None = None,
    law_output: IO[str] | None = None,
    on_hard_stop: Callable[[str, Recording], None] | None = None,
) -> Recording:
    """Run ``n_steps`` control periods (default: the config's duration); rows 0..n_steps, in
    memory.

    A user's law runs guarded (``nodes.law_guard``): a step past ``run.tick_timeout_s``, memory
    past ``law.max_memory_mb``, ``sys.exit`` and ``os._exit`` each end the run with
    ``SimFailedError``; what it prints goes to ``law_output`` (None: where it would), bounded by
    ``law.max_output_mb``. A step that cannot be stopped (compiled code) ends the process after
    ``on_hard_stop`` is given its line and what was recorded."""

    def recording(series: Mapping[int, Any], events: list[dict[str, Any]]) -> Recording:
        n_rows = next(iter(series.values())).n
        t_s = np.arange(n_rows) * cfg.control_dt_s
        offsets = {i: np.asarray(cfg.follower(i).offset_m, dtype=float) for i in series}
        trajectory = cfg.trajectory()
        return Recording(
            leader_series(trajectory, t_s), {i: s.arrays() for i, s in series.items()}, offsets, events
        ).with_errors(trajectory)  # (a tick that carries an older sample: the reference at its time)

    return _fly(cfg, n_steps, progress, law_output, on_hard_stop, in_memory, recording)


def run_sim_spooled(
    cfg: SwarmConfig,
    spool_dir: Path,
    progress: Callable[[int], None] | None = None,
    law_output: IO[str] | None = None,
    on_hard_stop: Callable[[str, SpooledRecording], None] | None = None,
) -> SpooledRecording:
    """``run_sim`` of the config's duration with its rows spooled to ``spool_dir`` a block at a
    time (``rundir.spool``): memory that does not grow with the duration. The arrays
    ``rundir.outputs.write_spooled_outputs`` writes from it are ``run_sim``'s, byte for byte."""

    def make(i: int, n_rows: int, record_fields: Mapping[str, int], n_in: int) -> SpooledSeries:
        return SpooledSeries(spool_dir / str(i), n_rows, record_fields, n_in)

    def recording(series: Mapping[int, Any], events: list[dict[str, Any]]) -> SpooledRecording:
        offsets = {i: np.asarray(cfg.follower(i).offset_m, dtype=float) for i in series}
        closed = {i: s.close() for i, s in series.items()}
        return SpooledRecording(spool_dir, closed, offsets, cfg.control_dt_s, events)

    return _fly(cfg, None, progress, law_output, on_hard_stop, make, recording)


def _fly(
    cfg: SwarmConfig,
    n_steps: int | None,
    progress: Callable[[int], None] | None,
    law_output: IO[str] | None,
    on_hard_stop: Callable[[str, R], None] | None,
    make_series: SeriesMaker,
    finish: Callable[[Mapping[int, Any], list[dict[str, Any]]], R],
) -> R:
    """``run_sim``'s loop: each follower's rows recorded through ``make_series``, and ``finish``
    making what was recorded of them (and of the plan's events) at the end or at a failure."""
    n = cfg.n_control_steps if n_steps is None else n_steps
    ids = [f.id for f in cfg.followers]
    graph = cfg.build_graph()
    leader = build_leader(cfg)
    sources = {i: graph.in_neighbours(i) for i in ids}
    # a fault plan: the followers, their laws and vehicles as lockstep runs them under it
    # (``sim_plan``); without one, those of this loop
    planned = PlannedSwarm(cfg, n, sample_through_wire, make_series) if cfg.faults.plan else None
    laws = {} if planned else {i: build_law(cfg, i, *reported_vehicle_params(cfg)) for i in ids}
    specs = (
        {} if planned else {i: cfg.vehicle_config(i) for i in ids}
    )  # each vehicle as its process builds it
    aps = {i: build_vehicle(specs[i], i) for i in specs}
    series = (
        planned.series
        if planned
        else {i: make_series(i, n + 1, laws[i].law.record_fields, len(sources[i])) for i in ids}
    )
    max_thrust = cfg.vehicle.max_thrust_N
    uplinks = {i: Uplink(cfg, i) for i in specs}  # each setpoint as its vehicle takes it
    n_att = cfg.rates.attitude_steps_per_control
    dt = cfg.control_dt_s
    latest: dict[int, Message] = {}
    sensors = {i: sensor_model(specs[i], i) for i in specs}  # (None: the true state is sampled)

    def recording() -> R:
        events = sorted(planned.events, key=lambda e: e["t_s"]) if planned is not None else []
        return finish(series, events)

    def heard(i: int) -> list[tuple[int, Message]]:
        return [(s, latest[s]) for s, _ in sources[i] if s in latest]

    guard = None
    if not cfg.law.is_paper:
        _load_kernels(
            cfg.vehicle_config(ids[0]), ids[0], n_att, max_thrust
        )  # the guard counts the law's memory
        guard = LawGuard(
            cfg.run.tick_timeout_s,
            cfg.law.max_memory_mb,
            law_output,
            max_output_bytes(cfg.law.max_output_mb),
            None if on_hard_stop is None else lambda line: on_hard_stop(line, recording()),
        )
        for law in laws.values():
            law.guard = guard
        if planned is not None:
            planned.set_guard(guard)
    try:
        if planned is not None:
            for k in range(n + 1):
                try:
                    planned.tick(k, None if planned.down(0, k) else leader.step(k))
                except LawError as e:
                    raise SimFailedError(e, recording()) from e
                if progress is not None:
                    progress(k)
            return recording()
        for k in range(n + 1):
            t = k * dt
            inboxes = {i: {s: Received(m.values, m.t_s, t - m.t_s) for s, m in heard(i)} for i in ids}
            new: dict[int, Message] = {0: leader.step(k)}
            for i in ids:
                ap = aps[i]
                series[i].record_vehicle(k, t, ap.state)
                try:
                    s = sensors[i]
                    x = ap.state if s is None else s.reported(round(t * 1000), ap.state)
                    step = laws[i].step(t, sample_through_wire(t, x), inboxes[i])
                except LawError as e:
                    raise SimFailedError(e, recording()) from e
                ages = np.array([t - latest[s].t_s if s in latest else np.nan for s, _ in sources[i]])
                series[i].record_controller(k, step.command, step.record, ages)
                new[i] = Message(i, k, t, step.message)
                if k < n:
                    ap.set_command(uplinks[i](step.command, ap))
                    ap.advance(n_att)
            latest = new
            if progress is not None:
                progress(k)
    finally:
        if guard is not None:
            guard.close()
    return recording()
