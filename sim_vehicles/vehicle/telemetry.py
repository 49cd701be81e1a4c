"""What a vehicle streams, and each message of it built from the vehicle's state now.

- ``TelemetryRates``: the rate of each stream [Hz], PX4-like defaults; ``GCS_RATES`` a ground-station
  port's (PX4's "normal" MAVLink mode). The heartbeat runs on the wall clock in both clock modes
  (it says the link is alive); everything else on the vehicle's simulated time, whose
  ``time_boot_ms`` every message carries.
- each port streams them on its own schedule (``port.Streams``).
- ``Telemetry``: the encoders, each queueing its message on a port: LOCAL_POSITION_NED,
  ATTITUDE, ATTITUDE_QUATERNION, ATTITUDE_TARGET, HIGHRES_IMU (specific force, body FRD),
  SYS_STATUS (sensor and pre-arm health bits), GLOBAL_POSITION_INT and GPS_RAW_INT (around the
  vehicle's ``home``), EXTENDED_SYS_STATE (landed state), HOME_POSITION, and AUTOPILOT_VERSION on
  request. NED/FRD is ``enu_ned``'s and the per-tick pair is packed by ``tick_frames``.
"""

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

import numpy as np
from pymavlink.dialects.v20 import common as mav

from sim_vehicles.common.quaternion import rotation_matrix
from sim_vehicles.common.state import POS, QUAT, RATE, VEL
from sim_vehicles.mavlink import frames, tick_frames
from sim_vehicles.mavlink import px4_profile as px4
from sim_vehicles.mavlink.enu_ned import enu_to_ned, flu_to_frd
from sim_vehicles.mavlink.wire_format import encode_attitude, encode_attitude_quaternion
from sim_vehicles.plant.contract import VehicleModel
from sim_vehicles.vehicle.autopilots import Profile
from sim_vehicles.vehicle.port import Port


@dataclass(frozen=True)
class TelemetryRates:
    """Stream rates [Hz], PX4-like defaults (0 = off)."""

    local_position_hz: float = 50.0
    attitude_hz: float = 50.0
    attitude_quaternion_hz: float = 50.0
    attitude_target_hz: float = 10.0
    imu_hz: float = 50.0
    sys_status_hz: float = 1.0
    global_position_hz: float = 5.0
    gps_raw_hz: float = 1.0
    extended_sys_state_hz: float = 1.0
    home_position_hz: float = 0.5
    heartbeat_hz: float = 1.0  #: on the wall clock, in both clock modes

    def by_message(self) -> dict[int, float]:
        """The streams' rates by message id, in the order a pass sends them."""
        return {
            mav.MAVLINK_MSG_ID_LOCAL_POSITION_NED: self.local_position_hz,
            mav.MAVLINK_MSG_ID_ATTITUDE: self.attitude_hz,
            mav.MAVLINK_MSG_ID_ATTITUDE_QUATERNION: self.attitude_quaternion_hz,
            mav.MAVLINK_MSG_ID_ATTITUDE_TARGET: self.attitude_target_hz,
            mav.MAVLINK_MSG_ID_HIGHRES_IMU: self.imu_hz,
            mav.MAVLINK_MSG_ID_SYS_STATUS: self.sys_status_hz,
            mav.MAVLINK_MSG_ID_GLOBAL_POSITION_INT: self.global_position_hz,
            mav.MAVLINK_MSG_ID_GPS_RAW_INT: self.gps_raw_hz,
            mav.MAVLINK_MSG_ID_EXTENDED_SYS_STATE: self.extended_sys_state_hz,
            mav.MAVLINK_MSG_ID_HOME_POSITION: self.home_position_hz,
        }


#: a ground-station port's default rates: PX4's "normal" MAVLink mode (``mavlink_main.cpp``)
GCS_RATES = TelemetryRates(
    local_position_hz=1.0,
    attitude_hz=15.0,
    attitude_quaternion_hz=10.0,
    attitude_target_hz=2.0,
    imu_hz=0.0,
    sys_status_hz=1.0,
    global_position_hz=5.0,
    gps_raw_hz=1.0,
    extended_sys_state_hz=1.0,
    home_position_hz=0.5,
)


class VehicleState(Protocol):
    """What the encoders read of the vehicle."""

    autopilot: VehicleModel
    armed: bool
    home: px4.Home
    system_id: int
    profile: Profile  #: the autopilot it speaks as (``autopilots``)

    def reported_state(self, ms: int) -> np.ndarray:
        """The state a sample at ``time_boot_ms`` ``ms`` reports (``plant.sensors``)."""
        ...


class Telemetry:
    """The vehicle's telemetry messages: ``senders`` (the streams) and ``on_request`` (those and
    AUTOPILOT_VERSION), by message id, each ``(port, time_boot_ms) -> None``."""

    def __init__(self, vehicle: VehicleState):
        self.vehicle = vehicle
        self._out = np.zeros(tick_frames.FRAME_BYTES, np.uint8)
        self.senders: dict[int, Callable[[Port, int], None]] = {
            mav.MAVLINK_MSG_ID_LOCAL_POSITION_NED: self.local_position,
            mav.MAVLINK_MSG_ID_ATTITUDE: self.attitude,
            mav.MAVLINK_MSG_ID_ATTITUDE_QUATERNION: self.attitude_quaternion,
            mav.MAVLINK_MSG_ID_ATTITUDE_TARGET: self.attitude_target,
            mav.MAVLINK_MSG_ID_HIGHRES_IMU: self.imu,
            mav.MAVLINK_MSG_ID_SYS_STATUS: self.sys_status,
            mav.MAVLINK_MSG_ID_GLOBAL_POSITION_INT: self.global_position,
            mav.MAVLINK_MSG_ID_GPS_RAW_INT: self.gps_raw,
            mav.MAVLINK_MSG_ID_EXTENDED_SYS_STATE: self.extended_sys_state,
            mav.MAVLINK_MSG_ID_HOME_POSITION: self.home_position,
        }
        #: sent on request only (MAV_CMD_REQUEST_MESSAGE, or their own commands)
        self.on_request: dict[int, Callable[[Port, int], None]] = {
            **self.senders,
            mav.MAVLINK_MSG_ID_AUTOPILOT_VERSION: self.autopilot_version,
        }

    @property
    def _ap(self) -> VehicleModel:
        return self.vehicle.autopilot

    def _sample_part(self, port: Port, pack: Callable[..., int], layout: frames.Layout, ms: int) -> None:
        """LOCAL_POSITION_NED or ATTITUDE_QUATERNION of the current state, converted and packed in
        one compiled call (``tick_frames``). Plain, like every frame queued: the port signs what
        it sends on a signed link."""
        x = self.vehicle.reported_state(ms)
        n = pack(self._out, port.mav.seq, self.vehicle.system_id, px4.AUTOPILOT, layout.spec, ms, x)
        port.take(self._out, n)

    def local_position(self, port: Port, ms: int) -> None:
        self._sample_part(port, tick_frames.pack_local_position, frames.LOCAL_POSITION_NED, ms)

    def attitude_quaternion(self, port: Port, ms: int) -> None:
        self._sample_part(port, tick_frames.pack_attitude_quaternion, frames.ATTITUDE_QUATERNION, ms)

    def attitude(self, port: Port, ms: int) -> None:
        x = self._ap.state
        port.send_fields(frames.ATTITUDE, (ms, *encode_attitude(x[QUAT], x[RATE])))

    def attitude_target(self, port: Port, ms: int) -> None:
        ap = self._ap
        c = ap.command
        f = encode_attitude_quaternion(c.q_c, c.omega_c_B)
        thrust = float(c.thrust_N) / ap.params.max_thrust_N
        port.send_fields(frames.ATTITUDE_TARGET, (ms, 0, *f[0:4], f[4], f[5], f[6], thrust))

    def imu(self, port: Port, ms: int) -> None:
        ap = self._ap
        x, p = ap.state, ap.params
        if (
            self.vehicle.armed
        ):  # specific force [m/s^2; body FLU]: thrust when flying, the stand's reaction when held
            T = min(max(float(ap.command.thrust_N), 0.0), p.max_thrust_N)
            f_b = np.array([0.0, 0.0, T / p.mass_kg])
        else:
            f_b = rotation_matrix(x[QUAT]).T @ np.array([0.0, 0.0, p.g_mps2])
        acc, gyro = flu_to_frd(f_b), flu_to_frd(x[RATE])
        port.send_fields(frames.HIGHRES_IMU, (ms * 1000, *acc, *gyro, 0, 0, 0, 1013.25, 0, 0, 0.0, 0b111111))

    def sys_status(self, port: Port, ms: int) -> None:
        on = px4.SENSORS
        health = on | mav.MAV_SYS_STATUS_GEOFENCE  # no fence, so none breached (MAVProxy reads it)
        port.send(port.mav.sys_status_encode(on, on, health, 0, 12000, -1, -1, 0, 0, 0, 0, 0, 0))

    def _global(self) -> tuple[int, int, int, int]:
        """(lat, lon [deg 1e7], alt AMSL, alt above home [mm]) of the current position."""
        p = self._ap.state[POS]
        lat, lon, alt = self.vehicle.home.global_of(float(p[0]), float(p[1]), float(p[2]))
        return round(lat * 1e7), round(lon * 1e7), round(alt * 1000), round(float(p[2]) * 1000)

    def global_position(self, port: Port, ms: int) -> None:
        lat, lon, alt, rel = self._global()
        v = enu_to_ned(self._ap.state[VEL])
        heading = self._heading_cdeg()
        port.send(
            port.mav.global_position_int_encode(
                ms, lat, lon, alt, rel, round(v[0] * 100), round(v[1] * 100), round(v[2] * 100), heading
            )
        )

    def _heading_cdeg(self) -> int:
        """Yaw of the body x axis from north, clockwise [cdeg 0..35999]."""
        x_N = enu_to_ned(rotation_matrix(self._ap.state[QUAT])[:, 0])
        return round(math.degrees(math.atan2(x_N[1], x_N[0])) % 360.0 * 100) % 36000

    def gps_raw(self, port: Port, ms: int) -> None:
        lat, lon, alt, _ = self._global()
        v = self._ap.state[VEL]
        speed = round(math.hypot(v[0], v[1]) * 100)
        fix = mav.GPS_FIX_TYPE_3D_FIX
        port.send(port.mav.gps_raw_int_encode(ms * 1000, fix, lat, lon, alt, 80, 120, speed, 65535, 12))

    def extended_sys_state(self, port: Port, ms: int) -> None:
        landed = mav.MAV_LANDED_STATE_IN_AIR if self.vehicle.armed else mav.MAV_LANDED_STATE_ON_GROUND
        port.send(port.mav.extended_sys_state_encode(mav.MAV_VTOL_STATE_UNDEFINED, landed))

    def home_position(self, port: Port, ms: int) -> None:
        h = self.vehicle.home
        lat, lon = round(h.latitude_deg * 1e7), round(h.longitude_deg * 1e7)
        port.send(
            port.mav.home_position_encode(
                lat, lon, round(h.altitude_m * 1000), 0, 0, 0, [1, 0, 0, 0], 0, 0, 0, ms * 1000
            )
        )

    def autopilot_version(self, port: Port, ms: int) -> None:
        port.send(
            port.mav.autopilot_version_encode(
                self.vehicle.profile.capabilities,
                self.vehicle.profile.flight_sw_version,
                0,
                0,
                0,
                [0] * 8,
                [0] * 8,
                [0] * 8,
                0,
                0,
                self.vehicle.system_id,
            )
        )
