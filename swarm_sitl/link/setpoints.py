"""What a controller sends its vehicle: the uplink layer of ``VehicleLink``.

- ``send``: SET_ATTITUDE_TARGET of a command, every field taken, stamped with the vehicle's
  ``time_boot_ms``; converted to NED/FRD and packed in one compiled call
  (``tick_frames.pack_setpoint``), thrust as 0..1 of the full thrust the link divides by
  (``sim_vehicles.mavlink.thrust_map``);
- ``clock_only``: a lockstep clock-only SET_ATTITUDE_TARGET (every field ignored): the vehicle
  moves its clock to the stamp on what it holds, and sends its sample there;
- ``heartbeat_if_due``: the companion computer's HEARTBEAT, once a second;
- ``command``: a COMMAND_LONG to the vehicle's autopilot.
"""

import time

import numpy as np
from pymavlink.dialects.v20 import common as mav

from sim_vehicles.common.command import AttitudeCommand
from sim_vehicles.mavlink import frames, tick_frames
from sim_vehicles.mavlink.px4_profile import AUTOPILOT
from sim_vehicles.mavlink.wire_format import IGNORE_ALL
from swarm_sitl.link.transport import Transport

_SETPOINT_SPEC = frames.SET_ATTITUDE_TARGET.spec


class Setpoints:
    """The uplink to vehicle ``system_id`` over ``transport``."""

    def __init__(self, transport: Transport, system_id: int):
        self.transport = transport
        self.system_id = system_id
        self._out = np.zeros(tick_frames.FRAME_BYTES, np.uint8)
        self._next_hb = 0.0

    def send(self, cmd: AttitudeCommand, time_boot_ms: int, max_thrust_N: float) -> None:
        """``cmd`` as SET_ATTITUDE_TARGET stamped ``time_boot_ms``, thrust 0..1 of ``max_thrust_N``."""
        mav_ = self.transport.conn.mav
        q_c, omega = cmd.q_c, cmd.omega_c_B
        # writable float arrays, as tick_frames.warm_up compiles the kernel for: a read-only one
        # (AttitudeCommand's default rates, ZERO3) is another type to numba, compiled at the first
        # setpoint in every controller (seconds on a fresh install: a real-time run's first ticks
        # stalled past run.tick_timeout_s)
        if not (
            type(q_c) is np.ndarray
            and type(omega) is np.ndarray
            and q_c.flags.writeable
            and omega.flags.writeable
        ):
            q_c, omega = np.array(q_c, dtype=float), np.array(omega, dtype=float)
        n = tick_frames.pack_setpoint(
            self._out,
            mav_.seq,
            mav_.srcSystem,
            mav_.srcComponent,
            _SETPOINT_SPEC,
            time_boot_ms,
            self.system_id,
            AUTOPILOT,
            q_c,
            omega,
            float(cmd.thrust_N),
            max_thrust_N,
        )
        self.transport.send(frames.take_frame(mav_, self._out, n), time_boot_ms, self.clock_only)

    def clock_only(self, time_boot_ms: int) -> None:
        """Lockstep: move the vehicle's clock to ``time_boot_ms`` on what it holds."""
        self.transport.conn.mav.set_attitude_target_send(
            time_boot_ms, self.system_id, AUTOPILOT, IGNORE_ALL, [1.0, 0.0, 0.0, 0.0], 0, 0, 0, 0
        )

    def heartbeat_if_due(self) -> None:
        now = time.monotonic()
        if now >= self._next_hb:
            self._next_hb = now + 1.0
            self.transport.conn.mav.heartbeat_send(
                mav.MAV_TYPE_ONBOARD_CONTROLLER, mav.MAV_AUTOPILOT_INVALID, 0, 0, 0
            )

    def command(self, command: int, *params: float) -> None:
        p = [*params, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0][:7]
        self.transport.conn.mav.command_long_send(self.system_id, AUTOPILOT, command, 0, *p)
