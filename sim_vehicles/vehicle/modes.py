"""Arming and the autopilot's modes of one vehicle, and what it flies on its own.

The modes and how they are reported are the autopilot's (``autopilots.Profile``: PX4's Hold and
OFFBOARD, ArduCopter's STABILIZE, GUIDED, LAND and GUIDED_NOGPS); this is the state machine they
share:

- Disarmed, the vehicle is held where it is (as if on a stand); physics runs once armed.
- ``MODE_HOLD``: its own loop flies the mode's ``own`` action (a position hold where it was when
  the mode began or it was armed; ArduCopter's level at its altitude; a landing), setpoints not
  yet taken. A mode that ``follows`` setpoints (OFFBOARD, GUIDED, GUIDED_NOGPS) leaves it for
  ``MODE_OFFBOARD`` at its first valid setpoint; PX4's OFFBOARD is entered only while a setpoint
  stream runs (a setpoint within COM_OF_LOSS_T), and straight into ``MODE_OFFBOARD``.
- ``MODE_OFFBOARD``: it follows SET_ATTITUDE_TARGET (with an altitude loop of its own where an
  ArduCopter reads the thrust as a climb rate: ``climb_mps``).
- ``MODE_FAILSAFE``: setpoints missing for the setpoint timeout (PX4's COM_OF_LOSS_T, ArduCopter's
  GUID_TIMEOUT): it flies a position hold at the point of loss or a landing (PX4: COM_OBL_RC_ACT),
  or level at its altitude (ArduCopter's GUIDED_NOGPS), and a valid setpoint brings it back.
  Entering and leaving it is a STATUSTEXT and an event.

``FlightModes`` keeps the state and its rules; the endpoint asks it what to fly and reports it.
"""

import math
import time
from collections.abc import Callable
from typing import Any

import numpy as np
from pymavlink.dialects.v20 import common as mav

from sim_vehicles.plant.contract import VehicleModel
from sim_vehicles.plant.failsafe import (
    ACTION_HOLD,
    ACTION_NAMES,
    FAILSAFE_PERIOD_S,
    climb_command,
    failsafe_command,
    hold_at,
)
from sim_vehicles.runtime.event_log import EventLog
from sim_vehicles.vehicle.autopilots import PX4, Mode, Profile

MODE_HOLD = 0
MODE_OFFBOARD = 1
MODE_FAILSAFE = 2


class FlightModes:
    """Vehicle ``system_id``'s arming and mode over ``autopilot``, as ``profile``'s autopilot has
    them; ``say(severity, text)`` sends a STATUSTEXT, ``events`` records entering and leaving the
    failsafe."""

    def __init__(
        self,
        autopilot: VehicleModel,
        system_id: int,
        setpoint_timeout_s: float,
        failsafe_action: int,
        events: EventLog,
        say: Callable[[int, str], None],
        profile: Profile = PX4,
    ):
        self.autopilot = autopilot
        self.system_id = system_id
        self.profile = profile
        self.setpoint_timeout_s = setpoint_timeout_s  #: COM_OF_LOSS_T or GUID_TIMEOUT [s; simulated]
        self.failsafe_action = failsafe_action  #: PX4's on setpoint loss: ``failsafe.ACTION_*``
        self.events = events
        self.say = say
        self.armed = False
        self.number = profile.boot_mode  #: the autopilot's mode, by its number
        self.mode = MODE_HOLD
        self.last_setpoint_s = -math.inf  #: the last valid setpoint taken [s; simulated]
        #: the last SET_ATTITUDE_TARGET for it, valid or clock-only [s; simulated]: PX4 accepts
        #: OFFBOARD only while a setpoint stream runs
        self.offboard_signal_s = -math.inf
        #: an ArduCopter's climb rate to hold under the setpoint's attitude (thrust read as a
        #: climb rate), or None [m/s]
        self.climb_mps: float | None = None
        self._action = ACTION_HOLD  #: what its own loop flies in failsafe
        self._hold = hold_at(autopilot.state, 0.0)
        self._own_steps = max(1, round(FAILSAFE_PERIOD_S / autopilot.dt_s))
        self._own_next = 0  #: attitude step at which its own loop runs next

    @property
    def current(self) -> Mode:
        return self.profile.modes[self.number]

    def arm(self, arm: bool, forced: bool) -> bool:
        """Arm, or disarm (refused in flight unless ``forced``, as PX4 and ArduCopter do); False
        if refused. Armed in a mode its own loop flies, it holds where it is."""
        if self.armed and not arm and not forced:
            return False
        if arm and not self.armed and self.mode == MODE_HOLD:
            self._hold_here()
        self.armed = arm
        return True

    def set_mode(self, wanted: int | None) -> int:
        """MAV_CMD_DO_SET_MODE to the mode numbered ``wanted``: the MAV_RESULT (the profile's
        refusal for a mode it does not have; TEMPORARILY_REJECTED for PX4's OFFBOARD without a
        setpoint stream)."""
        ap = self.autopilot
        mode = self.profile.modes.get(wanted) if wanted is not None else None
        if mode is None:
            return self.profile.refused_mode
        if mode.needs_stream and ap.time_s - self.offboard_signal_s > self.setpoint_timeout_s:
            return mav.MAV_RESULT_TEMPORARILY_REJECTED  # no setpoint stream yet
        if self.mode == MODE_FAILSAFE:
            self._event("failsafe_exit", vehicle=self.system_id)
        was = (self.mode, self.number)
        self.number = mode.number
        self.climb_mps = None
        if mode.needs_stream:
            self.mode = MODE_OFFBOARD
            self.last_setpoint_s = ap.time_s
        else:
            self.mode = MODE_HOLD
            self.last_setpoint_s = -math.inf
            if was != (MODE_HOLD, mode.number):  # (the same mode again: where it was)
                self._hold_here()
        return mav.MAV_RESULT_ACCEPTED

    def take_setpoint(self, climb_mps: float | None = None) -> bool:
        """A valid setpoint came now: it ends the failsafe; whether the vehicle flies it (in a
        mode that follows setpoints). ``climb_mps``: an ArduCopter's thrust read as a climb rate."""
        if self.mode == MODE_HOLD and not self.current.follows:  # (a mode its own loop flies)
            return False
        ap = self.autopilot
        self.last_setpoint_s = ap.time_s
        if self.mode == MODE_FAILSAFE:
            self._event("failsafe_exit", vehicle=self.system_id)
            self.say(mav.MAV_SEVERITY_NOTICE, f"Failsafe cleared: {self._kind} setpoints back")
        if self.mode == MODE_OFFBOARD and self.climb_mps is not None and climb_mps is not None:
            # a new climb rate from where the altitude target is now (it moves with the rate)
            h = self._hold
            z = h.p_W[2] + self.climb_mps * (ap.time_s - h.t_s)
            self._hold = h._replace(p_W=np.array([h.p_W[0], h.p_W[1], z]), t_s=ap.time_s)
        elif climb_mps is not None or self.mode != MODE_OFFBOARD:
            self._hold_here()  # (a climb rate's altitude target starts where it is)
        self.climb_mps = climb_mps
        self.mode = MODE_OFFBOARD
        return True

    def check_failsafe(self) -> None:
        """Enter the failsafe if setpoints have been missing for the setpoint timeout."""
        ap = self.autopilot
        if self.mode == MODE_OFFBOARD and ap.time_s - self.last_setpoint_s > self.setpoint_timeout_s:
            self.mode = MODE_FAILSAFE
            self.climb_mps = None
            self._action = self.failsafe_action if self.profile is PX4 else self.current.own
            self._hold = hold_at(ap.state, ap.time_s)
            self._own_next = ap.step_index
            action = ACTION_NAMES[self._action]
            self._event("failsafe_enter", vehicle=self.system_id, action=action, p_W=self._hold.p_W.tolist())
            self.say(mav.MAV_SEVERITY_WARNING, f"Failsafe: {self._kind} setpoints lost, {action}")

    def own_steps(self, left: int) -> int:
        """Where its own loop sets the command (a mode it flies itself, its failsafe, an
        altitude held under a setpoint's attitude) it does so every ``FAILSAFE_PERIOD_S`` if due;
        the steps (of ``left``) to fly before it is due again (all of them otherwise)."""
        climbing = self.mode == MODE_OFFBOARD and self.climb_mps is not None
        if self.mode == MODE_OFFBOARD and not climbing:
            return left
        ap = self.autopilot
        if ap.step_index >= self._own_next:
            if climbing:
                q_c = np.asarray(ap.command.q_c, dtype=float)
                assert self.climb_mps is not None
                cmd = climb_command(ap.state, q_c, self._hold, ap.time_s, self.climb_mps, ap.params)
                ap.set_command(cmd._replace(omega_c_B=ap.command.omega_c_B))
            else:
                action = self._action if self.mode == MODE_FAILSAFE else self.current.own
                speed = self.profile.land_speed_mps
                ap.set_command(failsafe_command(ap.state, self._hold, ap.time_s, action, ap.params, speed))
            self._own_next = ap.step_index + self._own_steps
        return min(left, self._own_next - ap.step_index)

    @property
    def _kind(self) -> str:
        """What its setpoints are called: PX4's offboard, ArduCopter's guided."""
        return "offboard" if self.profile is PX4 else "guided"

    def reported_mode(self) -> int:
        """The mode as the autopilot reports it in ``custom_mode`` (PX4: its failsafe as what it
        flies)."""
        return self.profile.reported(self.number, self.mode, self._action)

    def heartbeat(self) -> tuple[int, int, int]:
        """HEARTBEAT's ``base_mode``, ``custom_mode`` and ``system_status``."""
        failsafe = self.mode == MODE_FAILSAFE
        return (
            self.profile.base_mode(self.number, self.armed),
            self.reported_mode(),
            self.profile.status(self.armed, failsafe),
        )

    def _hold_here(self) -> None:
        """Its own loop from now: where it is, now."""
        ap = self.autopilot
        self._hold = hold_at(ap.state, ap.time_s)
        self._own_next = ap.step_index

    def _event(self, kind: str, **fields: Any) -> None:
        """An event at the vehicle's boot time, with the UNIX time for a real-time run's clock."""
        self.events.add(self.autopilot.time_s, kind, unix_s=time.time(), **fields)
