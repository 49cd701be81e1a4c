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

from sim_vehicles.common.state import QUAT, RATE
from sim_vehicles.mavlink import frames, signing, tick_frames
from sim_vehicles.mavlink.signing import read_key
from sim_vehicles.mavlink.wire_format import command_roundtrip, encode_attitude_quaternion
from sim_vehicles.models.build import build_vehicle, sensor_model
from sim_vehicles.models.vehicle_config import Gusts, SensorNoise, VehicleConfig, VehicleConfigError
from sim_vehicles.plant.autopilot import Autopilot
from sim_vehicles.plant.failsafe import ACTION_LAND, ACTIONS, failsafe_command, hold_at
from sim_vehicles.plant.params import VehicleParamError
from sim_vehicles.runtime.lifeline import (
    batch_scheduling,
    hold_on,
    mark,
    process_figures,
    profiled,
    settle_heap,
)
from sim_vehicles.vehicle import lockstep_tick
from sim_vehicles.vehicle.autopilots import PROFILES
from sim_vehicles.vehicle.endpoint import VehicleEndpoint


def warm_up(spec: VehicleConfig) -> None:
    """Load the compiled kernels for the argument types they will see (the plant's for the hover
    command's read-only zero rates, then a command from the wire; the per-tick frames'), so the
    first setpoints are not held up by it. Kernels are typed by their arguments, not their
    values: a fork server that calls this once with any valid vehicle spares every vehicle it
    forks the loads."""
    ap = build_vehicle(dataclasses.replace(spec, wind=None, position_m=(0.0, 0.0, 0.0)), 1)
    params = ap.params
    ap.advance(1)
    ap.set_command(command_roundtrip(ap.command, params.max_thrust_N))
    ap.advance(1)
    tick_frames.warm_up()
    signing.warm_up()
    if isinstance(ap, Autopilot):  # the one-call lockstep tick is the paper model's
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


#: flags that set a field of the vehicle's config (``--mass-kg`` sets ``mass_kg``), over ``--config``'s
CONFIG_FLAGS = {
    "position": "position_m",
    "velocity": "velocity_mps",
    "quaternion": "quaternion_wxyz",
    "gravity_mps2": "g_mps2",
    "mass_kg": "mass_kg",
    "inertia_kgm2": "inertia_kgm2",
    "max_thrust_n": "max_thrust_N",
    "max_rate_rps": "max_rate_rps",
    "l_q": "l_q",
    "k_q": "k_q",
    "setpoint_timeout_s": "setpoint_timeout_s",
    "failsafe_action": "failsafe_action",
    "drag_ns2pm2": "drag_Ns2pm2",
    "attitude_hz": "attitude_hz",
    "model": "model",
    "autopilot": "autopilot",
}
WIND_FLAGS = {
    "wind_mps": "mean_mps",
    "gust_mps": "gust_mps",
    "gust_time_s": "gust_time_s",
    "wind_seed": "seed",
}
SENSOR_FLAGS = {
    "position_noise_m": "position_noise_m",
    "velocity_noise_mps": "velocity_noise_mps",
    "attitude_noise_rad": "attitude_noise_rad",
    "sensor_latency_s": "latency_s",
    "sensor_seed": "seed",
}


def _given(a: argparse.Namespace, flags: dict[str, str]) -> dict[str, object]:
    """The spec fields the flags in ``flags`` that were given set (lists as tuples)."""
    out: dict[str, object] = {}
    for flag, name in flags.items():
        v = getattr(a, flag)
        if v is not None:
            out[name] = tuple(v) if isinstance(v, list) else v
    return out


def vehicle_config(a: argparse.Namespace) -> VehicleConfig:
    """The vehicle the arguments describe: ``--config FILE`` (default: the paper's airframe at
    rest at the origin), with each physical flag given set over it; ``VehicleConfigError`` (one
    line) if the result is not a vehicle."""
    base = VehicleConfig.from_json(Path(a.config).read_text()) if a.config else VehicleConfig()
    wind, sensors = _given(a, WIND_FLAGS), _given(a, SENSOR_FLAGS)
    changes = _given(a, CONFIG_FLAGS)
    try:
        if wind:
            changes["wind"] = dataclasses.replace(base.wind or Gusts(), **wind)  # type: ignore[arg-type]
        if sensors:
            changes["sensors"] = dataclasses.replace(base.sensors or SensorNoise(), **sensors)  # type: ignore[arg-type]
        return dataclasses.replace(base, **changes)  # type: ignore[arg-type]
    except TypeError as e:
        raise VehicleConfigError(f"vehicle config: {e}") from None


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
        "--config",
        metavar="FILE",
        help="the vehicle's config, whole, as JSON (sim_vehicles.models.vehicle_config.VehicleConfig; a "
        "run writes one per vehicle to RUN_DIR/procs/vehicle_<i>.config.json); the flags below set "
        "fields over it",
    )
    p.add_argument("--spec", metavar="FILE", help=argparse.SUPPRESS)  # (its name before: read, with a notice)
    p.add_argument("--model", help="the vehicle model (default: paper_vtol)")
    p.add_argument(
        "--autopilot", choices=("px4", "ardupilot"), help="speak as PX4 (default) or as ArduCopter"
    )
    p.add_argument(
        "--position", type=float, nargs=3, metavar=("E", "N", "U"), help="initial position [m; ENU]"
    )
    p.add_argument("--velocity", type=float, nargs=3, metavar=("E", "N", "U"), help="[m/s; ENU]")
    p.add_argument(
        "--quaternion",
        type=float,
        nargs=4,
        metavar=("W", "X", "Y", "Z"),
        help="initial attitude [FLU -> ENU]",
    )
    p.add_argument("--gravity-mps2", type=float)
    p.add_argument("--mass-kg", type=float)
    p.add_argument("--inertia-kgm2", type=float, nargs=3)
    p.add_argument("--max-thrust-n", type=float)
    p.add_argument(
        "--max-rate-rps",
        type=float,
        nargs=3,
        metavar=("ROLL", "PITCH", "YAW"),
        help="commanded body rates are clipped to +- these [rad/s] (PX4's MC_*RATE_MAX)",
    )
    p.add_argument("--l-q", type=float)
    p.add_argument("--k-q", type=float)
    p.add_argument("--setpoint-timeout-s", type=float)
    p.add_argument(
        "--failsafe-action",
        choices=sorted(ACTIONS),
        help="what the vehicle flies when its setpoints stop (PX4's COM_OBL_RC_ACT): hold position or land",
    )
    p.add_argument("--drag-ns2pm2", type=float, help="quadratic drag rho C_d A / 2 [N s^2/m^2]")
    p.add_argument("--wind-mps", type=float, nargs=3, help="mean wind [m/s; ENU]")
    p.add_argument("--gust-mps", type=float, help="gusts' standard deviation per axis [m/s]")
    p.add_argument("--gust-time-s", type=float, help="gusts' correlation time [s]")
    p.add_argument("--wind-seed", type=int, help="seed of the gusts")
    p.add_argument("--position-noise-m", type=float, help="reported position noise, per axis [m]")
    p.add_argument("--velocity-noise-mps", type=float, help="reported velocity noise [m/s]")
    p.add_argument("--attitude-noise-rad", type=float, help="reported attitude noise [rad]")
    p.add_argument("--sensor-latency-s", type=float, help="the report is the state this long ago [s]")
    p.add_argument("--sensor-seed", type=int, help="seed of the reported state's noise")
    p.add_argument("--events", help="write failsafe events (JSON lines) to this file")
    p.add_argument(
        "--signing-key-file",
        help="MAVLink 2 signing: a file whose first line is the passphrase (key = its SHA-256, as "
        "MAVProxy and QGroundControl derive it); unsigned and wrongly signed messages are refused",
    )
    p.add_argument("--stats", help="write what the vehicle received and refused (JSON) to this file at exit")
    p.add_argument("--attitude-hz", type=float, help="the attitude loop's and plant's rate [Hz]")
    p.add_argument("--tlog", help="write the MAVLink traffic to this .tlog")
    p.add_argument("--truth", help="write the true state at every LOCAL_POSITION_NED to this row log")
    p.add_argument(
        "--lockstep-period-s",
        type=float,
        help="lockstep: advance this much simulated time per setpoint stamped with the current time",
    )
    p.add_argument("--duration", type=float, help="stop after this many seconds of wall time (real time)")
    a = p.parse_args(argv)
    if a.spec is not None:  # a script of before: the word "spec" is a run's requirements now
        notice = "--spec is --config now (the vehicle's config file); read as --config"
        print(f"sim_vehicles: notice: {notice}", file=sys.stderr)
        a.config = a.config or a.spec
    if not 1 <= a.id <= 255:
        print(f"sim_vehicles: error: --id must be 1..255, got {a.id}", file=sys.stderr)
        return 2
    if a.lockstep_period_s is not None:
        batch_scheduling()
    try:
        spec = vehicle_config(a)
        key = read_key(a.signing_key_file) if a.signing_key_file else None
        ep = VehicleEndpoint(
            build_vehicle(spec, a.id),
            a.id,
            (a.host, a.port),
            spec.setpoint_timeout_s,
            tlog_path=a.tlog,
            lockstep_period_s=a.lockstep_period_s,
            truth_path=a.truth,
            failsafe_action=ACTIONS[spec.failsafe_action],
            events_path=a.events,
            signing_key=key,
            gcs_bind=None if a.gcs_port is None else (a.host, a.gcs_port),
            gcs_remote=_host_port(a.gcs_remote) if a.gcs_remote else None,
            sensors=sensor_model(spec, a.id),
            profile=PROFILES[spec.autopilot],
        )
    except (VehicleParamError, ValueError) as e:  # VehicleConfigError, a bad key file or address
        print(f"sim_vehicles: error: {e}", file=sys.stderr)
        return 2
    except OSError as e:
        if a.config and e.filename == a.config:
            print(f"sim_vehicles: error: --config {a.config}: {e.strerror}", file=sys.stderr)
            return 2
        ports = f"{a.port}" + (f" or {a.gcs_port}" if a.gcs_port is not None else "")
        print(f"sim_vehicles: error: cannot bind udp {a.host}:{ports} ({e.strerror})", file=sys.stderr)
        return 2
    warm_up(spec)
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
            stats = {
                **dataclasses.asdict(ep.stats),
                "rx_unsigned": ep.unsigned_by_port(),
                "boot_unix_s": boot,
                "process": process_figures(),
            }
            Path(a.stats).write_text(json.dumps(stats, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
