"""``python -m sim_vehicles``: one simulated vehicle behind a MAVLink 2 UDP endpoint.

Real time by default; ``--lockstep-period-s`` makes simulated time advance one period per
SET_ATTITUDE_TARGET stamped with the vehicle's current time (see ``vehicle.endpoint``). SIGTERM
or SIGINT closes the .tlog and the truth log and exits 0.
"""

import argparse
import dataclasses
import json
import math
import signal
import sys
from pathlib import Path

import numpy as np
from pymavlink.dialects.v20 import common as mav

from sim_vehicles.common.state import QUAT, RATE, make_state
from sim_vehicles.mavlink import frames, signing, tick_frames
from sim_vehicles.mavlink.signing import read_key
from sim_vehicles.mavlink.wire_format import command_roundtrip, encode_attitude_quaternion
from sim_vehicles.plant.autopilot import Autopilot
from sim_vehicles.plant.failsafe import ACTION_LAND, ACTIONS, failsafe_command, hold_at
from sim_vehicles.plant.params import MAX_RATE_DEFAULT_RPS, AttitudeGains, VehicleParamError, VehicleParams
from sim_vehicles.plant.sensors import SensorModel
from sim_vehicles.plant.wind import WindModel
from sim_vehicles.runtime.lifeline import (
    batch_scheduling,
    hold_on,
    mark,
    process_figures,
    profiled,
    settle_heap,
)
from sim_vehicles.vehicle import lockstep_tick
from sim_vehicles.vehicle.endpoint import VehicleEndpoint


def warm_up(params: VehicleParams, gains: AttitudeGains, attitude_hz: float) -> None:
    """Load the compiled kernels for the argument types they will see (the plant's for the hover
    command's read-only zero rates, then a command from the wire; the per-tick frames'), so the
    first setpoints are not held up by it. Kernels are typed by their arguments, not their
    values: a fork server that calls this once with any valid vehicle spares every vehicle it
    forks the loads."""
    ap = Autopilot(params, gains, make_state([0.0, 0.0, 0.0]), 1.0 / attitude_hz)
    ap.advance(1)
    ap.set_command(command_roundtrip(ap.command, params.max_thrust_N))
    ap.advance(1)
    tick_frames.warm_up()
    signing.warm_up()
    lockstep_tick.step_and_sample(
        ap.state,
        ap.kernel_args,
        1,
        np.zeros(lockstep_tick.SAMPLE_BYTES, np.uint8),
        0,
        1,
        1,
        frames.LOCAL_POSITION_NED.spec,
        frames.ATTITUDE_QUATERNION.spec,
        0,
    )
    # the lower-rate streams (ATTITUDE, ATTITUDE_TARGET, HIGHRES_IMU) and the failsafe's loop:
    # without these a vehicle loaded them in flight, 20-70 ms of CPU each
    x = ap.state
    encode_attitude_quaternion(x[QUAT], x[RATE])
    frames.pack_frame(mav.MAVLink(None), frames.ATTITUDE, [0.0] * len(frames.ATTITUDE.names))
    failsafe_command(x, hold_at(x, 0.0), 0.0, ACTION_LAND, params)


def _host_port(text: str) -> tuple[str, int]:
    host, _, port = text.rpartition(":")
    if not host or not port.isdigit() or not 0 < int(port) < 65536:
        raise ValueError(f"--gcs-remote must be HOST:PORT, got {text!r}")
    return host, int(port)


def _wind(a: argparse.Namespace) -> WindModel | None:
    """The wind the arguments ask for (None: still air)."""
    if a.gust_mps < 0 or not a.gust_time_s > 0:
        raise ValueError("--gust-mps is zero or positive and --gust-time-s positive")
    if not any(a.wind_mps) and a.gust_mps == 0:
        return None
    return WindModel(a.id, tuple(a.wind_mps), a.gust_mps, a.gust_time_s, a.wind_seed)


def _sensors(a: argparse.Namespace) -> SensorModel | None:
    """The sensor model the arguments ask for (None: the true state is reported)."""
    values = (a.position_noise_m, a.velocity_noise_mps, a.attitude_noise_rad, a.sensor_latency_s)
    if any(v < 0 or v != v for v in values):
        raise ValueError("sensor noise and latency are zero or positive")
    if not any(values):
        return None
    return SensorModel(a.id, *values, seed=a.sensor_seed)


def main(argv: list[str] | None = None) -> int:
    hold_on()  # a supervisor's child dies with it
    mark("main")
    p = argparse.ArgumentParser(prog="python -m sim_vehicles", description=__doc__)
    p.add_argument("--id", type=int, default=1, help="MAVLink system id (1..255)")
    p.add_argument("--host", default="127.0.0.1", help="address to bind (loopback by default)")
    p.add_argument("--port", type=int, default=14560, help="UDP port to bind (0: any free port)")
    p.add_argument(
        "--gcs-port",
        type=int,
        help="a ground station's own UDP port: its own peer, PX4's GCS stream rates (0: any free port)",
    )
    p.add_argument(
        "--gcs-remote",
        metavar="HOST:PORT",
        help="the ground-station port sends here until someone speaks to it (PX4 SITL: 127.0.0.1:14550)",
    )
    p.add_argument(
        "--position",
        type=float,
        nargs=3,
        default=[0.0, 0.0, 0.0],
        metavar=("E", "N", "U"),
        help="initial position [m; ENU]",
    )
    p.add_argument(
        "--velocity", type=float, nargs=3, default=[0.0, 0.0, 0.0], metavar=("E", "N", "U"), help="[m/s; ENU]"
    )
    p.add_argument(
        "--quaternion",
        type=float,
        nargs=4,
        default=[1.0, 0.0, 0.0, 0.0],
        metavar=("W", "X", "Y", "Z"),
        help="initial attitude [FLU -> ENU]",
    )
    p.add_argument("--gravity-mps2", type=float, default=9.81)
    p.add_argument("--mass-kg", type=float, default=0.85)
    p.add_argument("--inertia-kgm2", type=float, nargs=3, default=[4.856e-2, 4.856e-2, 8.801e-2])
    p.add_argument("--max-thrust-n", type=float, default=25.0)
    p.add_argument(
        "--max-rate-rps",
        type=float,
        nargs=3,
        default=[MAX_RATE_DEFAULT_RPS] * 3,
        metavar=("ROLL", "PITCH", "YAW"),
        help="commanded body rates are clipped to +- these [rad/s] (PX4's MC_*RATE_MAX)",
    )
    p.add_argument("--l-q", type=float, default=16.0)
    p.add_argument("--k-q", type=float, default=16.0)
    p.add_argument("--setpoint-timeout-s", type=float, default=0.5)
    p.add_argument(
        "--failsafe-action",
        choices=sorted(ACTIONS),
        default="hold",
        help="what the vehicle flies when its setpoints stop (PX4's COM_OBL_ACT): hold position or land",
    )
    p.add_argument("--drag-ns2pm2", type=float, default=0.0, help="quadratic drag rho C_d A / 2 [N s^2/m^2]")
    p.add_argument("--wind-mps", type=float, nargs=3, default=[0.0, 0.0, 0.0], help="mean wind [m/s; ENU]")
    p.add_argument("--gust-mps", type=float, default=0.0, help="gusts' standard deviation per axis [m/s]")
    p.add_argument("--gust-time-s", type=float, default=1.0, help="gusts' correlation time [s]")
    p.add_argument("--wind-seed", type=int, default=0, help="seed of the gusts")
    p.add_argument(
        "--position-noise-m", type=float, default=0.0, help="reported position noise, per axis [m]"
    )
    p.add_argument("--velocity-noise-mps", type=float, default=0.0, help="reported velocity noise [m/s]")
    p.add_argument("--attitude-noise-rad", type=float, default=0.0, help="reported attitude noise [rad]")
    p.add_argument(
        "--sensor-latency-s", type=float, default=0.0, help="the report is the state this long ago [s]"
    )
    p.add_argument("--sensor-seed", type=int, default=0, help="seed of the reported state's noise")
    p.add_argument("--events", help="write failsafe events (JSON lines) to this file")
    p.add_argument(
        "--signing-key-file",
        help="MAVLink 2 signing: a file whose first line is the passphrase (key = its SHA-256, as "
        "MAVProxy and QGroundControl derive it); unsigned and wrongly signed messages are refused",
    )
    p.add_argument("--stats", help="write what the vehicle received and refused (JSON) to this file at exit")
    p.add_argument("--attitude-hz", type=float, default=1000.0)
    p.add_argument("--tlog", help="write the MAVLink traffic to this .tlog")
    p.add_argument("--truth", help="write the true state at every LOCAL_POSITION_NED to this row log")
    p.add_argument(
        "--lockstep-period-s",
        type=float,
        help="lockstep: advance this much simulated time per setpoint stamped with the current time",
    )
    p.add_argument("--duration", type=float, help="stop after this many seconds of wall time (real time)")
    a = p.parse_args(argv)
    if not 1 <= a.id <= 255:
        print(f"sim_vehicles: error: --id must be 1..255, got {a.id}", file=sys.stderr)
        return 2
    q = np.asarray(a.quaternion, dtype=float)
    if abs(float(np.linalg.norm(q)) - 1.0) > 1e-6:
        print(
            f"sim_vehicles: error: --quaternion must be a unit quaternion, got {a.quaternion}",
            file=sys.stderr,
        )
        return 2
    if not a.attitude_hz > 0:
        print(f"sim_vehicles: error: --attitude-hz must be > 0, got {a.attitude_hz}", file=sys.stderr)
        return 2
    if a.lockstep_period_s is not None:
        batch_scheduling()
    try:
        key = read_key(a.signing_key_file) if a.signing_key_file else None
        params = VehicleParams(
            a.mass_kg,
            tuple(a.inertia_kgm2),
            a.max_thrust_n,
            a.gravity_mps2,
            tuple(a.max_rate_rps),
            a.drag_ns2pm2,
        )
        gains = AttitudeGains(a.l_q, a.k_q)
        ep = VehicleEndpoint(
            Autopilot(params, gains, make_state(a.position, a.velocity, q), 1.0 / a.attitude_hz),
            a.id,
            (a.host, a.port),
            a.setpoint_timeout_s,
            tlog_path=a.tlog,
            lockstep_period_s=a.lockstep_period_s,
            truth_path=a.truth,
            failsafe_action=ACTIONS[a.failsafe_action],
            events_path=a.events,
            signing_key=key,
            gcs_bind=None if a.gcs_port is None else (a.host, a.gcs_port),
            gcs_remote=_host_port(a.gcs_remote) if a.gcs_remote else None,
            sensors=_sensors(a),
        )
        ep.autopilot.wind = _wind(a)
    except (VehicleParamError, ValueError) as e:
        print(f"sim_vehicles: error: {e}", file=sys.stderr)
        return 2
    except OSError as e:
        ports = f"{a.port}" + (f" or {a.gcs_port}" if a.gcs_port is not None else "")
        print(f"sim_vehicles: error: cannot bind udp {a.host}:{ports} ({e.strerror})", file=sys.stderr)
        return 2
    warm_up(params, gains, a.attitude_hz)
    mark("ready")
    gcs = ep.gcs_address
    tail = f", ground station on udp:{gcs[0]}:{gcs[1]}" if gcs else ""
    print(f"vehicle {a.id} listening on udp:{ep.address[0]}:{ep.address[1]}{tail}", flush=True)

    def _terminate(signum: int, frame: object) -> None:
        raise KeyboardInterrupt  # close the .tlog through the finally below

    signal.signal(signal.SIGTERM, _terminate)
    settle_heap()
    try:
        if a.lockstep_period_s is not None:
            profiled(f"vehicle_{a.id}", ep.run_lockstep)
        else:
            profiled(f"vehicle_{a.id}", lambda: ep.run_realtime(a.duration))
    except KeyboardInterrupt:
        pass
    finally:
        ep.close()
        if a.stats:
            boot = None if math.isnan(ep.boot_unix_s) else ep.boot_unix_s
            stats = {**dataclasses.asdict(ep.stats), "boot_unix_s": boot, "process": process_figures()}
            Path(a.stats).write_text(json.dumps(stats, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
