"""Arming and PX4's modes of one vehicle, and what it flies on its own.

- Disarmed, the vehicle is held where it is (as if on a stand); physics runs once armed.
- ``MODE_HOLD``: PX4's AUTO.LOITER ("Hold"), a position hold where it was when the mode began or
  it was armed, by its own loop as in its failsafe; setpoints are ignored.
- ``MODE_OFFBOARD``: it follows SET_ATTITUDE_TARGET. PX4's rule: OFFBOARD is entered only while a
  setpoint stream runs (a setpoint within SP_TIMEOUT_S).
- ``MODE_FAILSAFE``: setpoints lost for SP_TIMEOUT_S in offboard (PX4's COM_OF_LOSS_T) are its
  failsafe: it flies a position hold at the point of loss or a landing (``plant.failsafe``, the
  parameter COM_OBL_ACT), reported as AUTO.LOITER or AUTO.LAND with ``system_status``
  MAV_STATE_CRITICAL, and a valid setpoint brings it back to offboard. Entering and leaving it is
  a STATUSTEXT and an event.

``FlightModes`` keeps the state and its rules; the endpoint asks it what to fly and reports it.
"""

import math
import time
from collections.abc import Callable
from typing import Any

from pymavlink.dialects.v20 import common as mav

from sim_vehicles.mavlink import px4_profile as px4
from sim_vehicles.plant.contract import VehicleModel
from sim_vehicles.plant.failsafe import ACTION_HOLD, FAILSAFE_PERIOD_S, failsafe_command, hold_at
from sim_vehicles.runtime.event_log import EventLog

MODE_HOLD = 0
MODE_OFFBOARD = 1
MODE_FAILSAFE = 2


class FlightModes:
    """Vehicle ``system_id``'s arming and mode over ``autopilot``; ``say(severity, text)`` sends a
    STATUSTEXT, ``events`` records entering and leaving the failsafe."""

    def __init__(
        self,
        autopilot: VehicleModel,
        system_id: int,
        setpoint_timeout_s: float,
        failsafe_action: int,
        events: EventLog,
        say: Callable[[int, str], None],
    ):
        self.autopilot = autopilot
        self.system_id = system_id
        self.setpoint_timeout_s = setpoint_timeout_s  #: SP_TIMEOUT_S [s of simulated time]
        self.failsafe_action = failsafe_action  #: ``failsafe.ACTION_*`` (COM_OBL_ACT)
        self.events = events
        self.say = say
        self.armed = False
        self.mode = MODE_HOLD
        self.last_setpoint_s = -math.inf  #: the last valid setpoint taken [s; simulated]
        #: the last SET_ATTITUDE_TARGET for it, valid or clock-only [s; simulated]: PX4 accepts
        #: OFFBOARD only while a setpoint stream runs
        self.offboard_signal_s = -math.inf
        self._hold = hold_at(autopilot.state, 0.0)
        self._own_steps = max(1, round(FAILSAFE_PERIOD_S / autopilot.dt_s))
        self._own_next = 0  #: attitude step at which its own position loop runs next

    def arm(self, arm: bool, forced: bool) -> bool:
        """Arm, or disarm (refused in flight unless ``forced``, as PX4 does); False if refused.
        Armed in Hold, it holds where it is."""
        if self.armed and not arm and not forced:
            return False
        if arm and not self.armed and self.mode == MODE_HOLD:
            self._hold_here()
        self.armed = arm
        return True

    def set_mode(self, wanted: int | None) -> int:
        """MAV_CMD_DO_SET_MODE to PX4's ``wanted`` custom mode: Hold (AUTO.LOITER), or OFFBOARD
        while a setpoint stream runs; the MAV_RESULT (DENIED: a mode it does not have)."""
        ap = self.autopilot
        if wanted == px4.HOLD:
            mode = MODE_HOLD
        elif wanted == px4.OFFBOARD:
            if ap.time_s - self.offboard_signal_s > self.setpoint_timeout_s:
                return mav.MAV_RESULT_TEMPORARILY_REJECTED  # no setpoint stream yet
            mode = MODE_OFFBOARD
        else:
            return mav.MAV_RESULT_DENIED
        if self.mode == MODE_FAILSAFE:
            self._event("failsafe_exit", vehicle=self.system_id)
        if mode == MODE_HOLD and self.mode != MODE_HOLD:
            self._hold_here()
        self.mode = mode
        self.last_setpoint_s = ap.time_s if mode == MODE_OFFBOARD else -math.inf
        return mav.MAV_RESULT_ACCEPTED

    def take_setpoint(self) -> bool:
        """A valid setpoint came now: it ends the failsafe; whether the vehicle flies it (in
        offboard, or back to it from the failsafe)."""
        self.last_setpoint_s = self.autopilot.time_s
        if self.mode == MODE_FAILSAFE:
            self._event("failsafe_exit", vehicle=self.system_id)
            self.say(mav.MAV_SEVERITY_NOTICE, "Failsafe cleared: offboard setpoints back")
        if self.mode in (MODE_OFFBOARD, MODE_FAILSAFE):
            self.mode = MODE_OFFBOARD
            return True
        return False

    def check_failsafe(self) -> None:
        """Enter the failsafe if offboard setpoints have been missing for SP_TIMEOUT_S."""
        ap = self.autopilot
        if self.mode == MODE_OFFBOARD and ap.time_s - self.last_setpoint_s > self.setpoint_timeout_s:
            self.mode = MODE_FAILSAFE
            self._hold = hold_at(ap.state, ap.time_s)
            self._own_next = ap.step_index
            action = "land" if self.failsafe_action != ACTION_HOLD else "hold"
            self._event("failsafe_enter", vehicle=self.system_id, action=action, p_W=self._hold.p_W.tolist())
            self.say(mav.MAV_SEVERITY_WARNING, f"Failsafe: offboard setpoints lost, {action}")

    def own_steps(self, left: int) -> int:
        """In Hold or failsafe the vehicle's own position loop sets its command every
        ``FAILSAFE_PERIOD_S``: do so if due; the steps (of ``left``) to fly before it is due
        again (all of them in offboard)."""
        if self.mode not in (MODE_FAILSAFE, MODE_HOLD):
            return left
        ap = self.autopilot
        if ap.step_index >= self._own_next:
            action = self.failsafe_action if self.mode == MODE_FAILSAFE else ACTION_HOLD
            ap.set_command(failsafe_command(ap.state, self._hold, ap.time_s, action, ap.params))
            self._own_next = ap.step_index + self._own_steps
        return min(left, self._own_next - ap.step_index)

    def px4_mode(self) -> int:
        """The mode as PX4 reports it in ``custom_mode``: the failsafe as what it flies."""
        if self.mode == MODE_OFFBOARD:
            return px4.OFFBOARD
        if self.mode == MODE_FAILSAFE and self.failsafe_action != ACTION_HOLD:
            return px4.LAND
        return px4.HOLD

    def heartbeat(self) -> tuple[int, int, int]:
        """HEARTBEAT's ``base_mode``, ``custom_mode`` and ``system_status``."""
        base = px4.BASE_FLAGS | (mav.MAV_MODE_FLAG_SAFETY_ARMED if self.armed else 0)
        status = (
            mav.MAV_STATE_CRITICAL
            if self.mode == MODE_FAILSAFE
            else (mav.MAV_STATE_ACTIVE if self.armed else mav.MAV_STATE_STANDBY)
        )
        return base, self.px4_mode(), status

    def _hold_here(self) -> None:
        """Hold (PX4's AUTO.LOITER) from now: a position hold where it is, by its own loop."""
        ap = self.autopilot
        self._hold = hold_at(ap.state, ap.time_s)
        self._own_next = ap.step_index

    def _event(self, kind: str, **fields: Any) -> None:
        """An event at the vehicle's boot time, with the UNIX time for a real-time run's clock."""
        self.events.add(self.autopilot.time_s, kind, unix_s=time.time(), **fields)
