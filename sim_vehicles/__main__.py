"""``python -m sim_vehicles``: one simulated vehicle behind a MAVLink 2 UDP endpoint, in real time."""

import argparse
import signal
import sys

from sim_vehicles.autopilot import Autopilot
from sim_vehicles.mavlink_endpoint import VehicleEndpoint
from sim_vehicles.params import AttitudeGains, VehicleParamError, VehicleParams
from sim_vehicles.rigid_body import make_state


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m sim_vehicles", description=__doc__)
    p.add_argument("--id", type=int, default=1, help="MAVLink system id (1..255)")
    p.add_argument("--host", default="127.0.0.1", help="address to bind (loopback by default)")
    p.add_argument("--port", type=int, default=14560, help="UDP port to bind")
    p.add_argument(
        "--position",
        type=float,
        nargs=3,
        default=[0.0, 0.0, 0.0],
        metavar=("E", "N", "U"),
        help="initial position [m; ENU]",
    )
    p.add_argument("--mass-kg", type=float, default=0.85)
    p.add_argument("--inertia-kgm2", type=float, nargs=3, default=[4.856e-2, 4.856e-2, 8.801e-2])
    p.add_argument("--max-thrust-n", type=float, default=25.0)
    p.add_argument("--l-q", type=float, default=16.0)
    p.add_argument("--k-q", type=float, default=16.0)
    p.add_argument("--setpoint-timeout-s", type=float, default=0.5)
    p.add_argument("--attitude-hz", type=float, default=1000.0)
    p.add_argument("--tlog", help="write the MAVLink traffic to this .tlog")
    p.add_argument("--duration", type=float, help="stop after this many seconds of wall time")
    a = p.parse_args(argv)
    if not 1 <= a.id <= 255:
        print(f"sim_vehicles: error: --id must be 1..255, got {a.id}", file=sys.stderr)
        return 2
    try:
        params = VehicleParams(a.mass_kg, tuple(a.inertia_kgm2), a.max_thrust_n)
        gains = AttitudeGains(a.l_q, a.k_q)
    except VehicleParamError as e:
        print(f"sim_vehicles: error: {e}", file=sys.stderr)
        return 2
    try:
        ep = VehicleEndpoint(
            Autopilot(params, gains, make_state(a.position), 1.0 / a.attitude_hz),
            a.id,
            (a.host, a.port),
            a.setpoint_timeout_s,
            tlog_path=a.tlog,
        )
    except OSError as e:
        print(f"sim_vehicles: error: cannot bind udp {a.host}:{a.port} ({e.strerror})", file=sys.stderr)
        return 2
    print(f"vehicle {a.id} listening on udp:{ep.address[0]}:{ep.address[1]}", flush=True)

    def _terminate(signum: int, frame: object) -> None:
        raise KeyboardInterrupt  # close the .tlog through the finally below

    signal.signal(signal.SIGTERM, _terminate)
    try:
        ep.run_realtime(a.duration)
    except KeyboardInterrupt:
        pass
    finally:
        ep.close()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
