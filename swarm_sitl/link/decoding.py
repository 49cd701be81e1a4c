"""What a controller reads from its vehicle: the decoding layer of ``VehicleLink``.

- The sample: the last LOCAL_POSITION_NED and ATTITUDE_QUATERNION of the same ``time_boot_ms``
  from the vehicle's autopilot, in ENU/FLU (``sim_vehicles.mavlink.wire_format``), with the
  arrival of the datagram that completed it. A datagram that is just the sample (what a lockstep
  vehicle sends every period) is read and converted in one compiled call
  (``tick_frames.read_sample``), with any telemetry beside it checked and counted, not decoded;
- everything else goes the general way both ends of a vehicle link share
  (``sim_vehicles.mavlink.decoder``): the sample's two messages are read without pymavlink,
  HEARTBEAT, PARAM_VALUE and COMMAND_ACK are decoded, other messages (the telemetry a ground
  station shows) only have their CRC checked, and garbage or a frame cut short is counted;
- the autopilot's last STATUSTEXT (what a refusal's line quotes), and whether the vehicle is
  ``gone``: rebooted (its clock went back by more than ``REBOOT_MS``) or disarmed after it had
  been armed.

``rx_bad`` counts what was dropped: bad CRCs, frames that do not decode, garbage.
"""

import math
from typing import Any

import numpy as np
from pymavlink.dialects.v20 import common as mav

from sim_vehicles.mavlink import decoder, frames, tick_frames
from sim_vehicles.mavlink.enu_ned import flu_to_frd
from sim_vehicles.mavlink.px4_profile import AUTOPILOT
from sim_vehicles.mavlink.wire_format import SAMPLE_P, SAMPLE_Q, SAMPLE_V, sample_from_fields

_LPOS = frames.LOCAL_POSITION_NED
_ATTQ = frames.ATTITUDE_QUATERNION
_SAMPLE_LAYOUTS = {_LPOS.msg_id: _LPOS, _ATTQ.msg_id: _ATTQ}
#: what is decoded besides the sample; other messages are only checked and counted
HANDLED = frozenset(
    {
        mav.MAVLINK_MSG_ID_HEARTBEAT,
        mav.MAVLINK_MSG_ID_PARAM_VALUE,
        mav.MAVLINK_MSG_ID_COMMAND_ACK,
        mav.MAVLINK_MSG_ID_STATUSTEXT,
    }
)
#: a sample this much older than the newest is the vehicle's clock starting again: it rebooted
#: (a sample a fault plan held back is a few periods old) [ms]
REBOOT_MS = 1000
#: ``tick_frames.read_sample``'s table of the messages only checked and counted: CRC extra by id,
#: -1 for those read (the sample, ``HANDLED``) and for ids the common set does not have
_IGNORED = np.full(max(mav.mavlink_map) + 1, -1, dtype=np.int64)
for _id, _cls in mav.mavlink_map.items():
    if _id not in HANDLED and _id not in _SAMPLE_LAYOUTS:
        _IGNORED[_id] = _cls.crc_extra


class Downlink:
    """What has come from vehicle ``system_id``; ``parser`` is the connection's pymavlink
    ``MAVLink`` object, ``whole``: each read is a whole datagram (UDP)."""

    def __init__(self, system_id: int, parser: Any, whole: bool):
        self.system_id = system_id
        self.parser = parser
        self.whole = whole
        self.rx_bad = 0
        self.heartbeat: Any = None  #: the autopilot's latest HEARTBEAT
        self.statustext = ""  #: the autopilot's latest STATUSTEXT
        #: why the vehicle is no longer the one the controller engaged ("": it is): its clock
        #: started again (a reboot), or it disarmed after it had been armed
        self.gone = ""
        self._armed = False
        self.params: dict[str, float] = {}  #: its parameters, as PARAM_VALUE gave them
        self.acks: dict[int, int] = {}  #: the latest COMMAND_ACK's result by command
        self._lpos: tuple = ()  #: LOCAL_POSITION_NED fields, declared order
        self._attq: tuple = ()  #: ATTITUDE_QUATERNION fields, declared order
        self.sample_fields = np.zeros(10)  #: the latest complete sample (``wire_format.SAMPLE_*``)
        self.sample_ms = -1  #: time_boot_ms of the latest complete sample
        self.sample_arrival_mono = math.nan  #: when it arrived [s; time.monotonic]

    def read(self, data: bytes, arrival: float) -> tuple[int, int]:
        """The messages of one plain datagram that came at ``arrival``; returns how many, and the
        ``time_boot_ms`` of the sample if the datagram was just the sample (-1: it was not)."""
        if self.whole:
            s = tick_frames.read_sample(data, self.system_id, AUTOPILOT, _LPOS.spec, _ATTQ.spec, _IGNORED)
            v = s.tolist()  # Python floats: one call, where each numpy scalar costs one
            if v[tick_frames.RS_OK]:  # the sample, and telemetry that is only counted
                self.rx_bad += int(v[tick_frames.RS_BAD])
                ms = int(v[tick_frames.RS_TIME_MS])
                self._lpos = self._attq = (ms,)  # this instant is complete: no half to wait for
                self._set_sample(ms, s[tick_frames.RS_SAMPLE], arrival)
                return int(v[tick_frames.RS_FRAMES]), ms
        n = 0
        for got in decoder.messages(data, self.parser, _SAMPLE_LAYOUTS, HANDLED.__contains__, self.whole):
            if got is decoder.GARBAGE:
                self.rx_bad += 1
                continue
            n += 1
            if got.bad:
                self.rx_bad += 1
            elif got.values is not None:
                if got.system == self.system_id and got.component == AUTOPILOT:
                    self._sample_part(got.msg_id == _LPOS.msg_id, got.values, arrival)
            elif got.message is not None:
                self.handle(got.message, arrival)
        return n, -1

    def handle(self, m: Any, arrival: float) -> None:
        """A message pymavlink decoded, from the vehicle's autopilot or not."""
        if m.get_srcSystem() != self.system_id or m.get_srcComponent() != AUTOPILOT:
            return
        t = m.get_type()
        if t == "LOCAL_POSITION_NED":
            self._sample_part(True, (m.time_boot_ms, m.x, m.y, m.z, m.vx, m.vy, m.vz), arrival)
        elif t == "ATTITUDE_QUATERNION":
            fields = (m.time_boot_ms, m.q1, m.q2, m.q3, m.q4, m.rollspeed, m.pitchspeed, m.yawspeed)
            self._sample_part(False, fields, arrival)
        elif t == "HEARTBEAT":
            self.heartbeat = m
            armed = bool(m.base_mode & mav.MAV_MODE_FLAG_SAFETY_ARMED)
            if self._armed and not armed and not self.gone:
                self.gone = "it disarmed (its HEARTBEAT)"
            self._armed = armed
        elif t == "STATUSTEXT":
            self.statustext = m.text
        elif t == "PARAM_VALUE":
            self.params[m.param_id] = float(m.param_value)
        elif t == "COMMAND_ACK":
            self.acks[m.command] = m.result

    def rates_B(self) -> np.ndarray:
        """The body rates of the newest ATTITUDE_QUATERNION [rad/s, FLU]; NaN before one."""
        a = self._attq
        if len(a) < 8:
            return np.full(3, math.nan)
        return flu_to_frd(np.array(a[5:8], dtype=float))  # (FRD -> FLU: the same sign flips)

    def _sample_part(self, is_position: bool, fields: tuple, arrival: float) -> None:
        if is_position:
            self._lpos = fields
        else:
            self._attq = fields
        lpos, attq = self._lpos, self._attq
        if len(lpos) > 1 and len(attq) > 1 and lpos[0] == attq[0]:
            decoded = sample_from_fields(np.array(lpos[1:7], dtype=float), np.array(attq[1:5], dtype=float))
            self._set_sample(int(lpos[0]), decoded, arrival)

    def _set_sample(self, time_boot_ms: int, decoded: np.ndarray, arrival: float) -> None:
        if time_boot_ms < self.sample_ms:  # a sample a fault held back, older than the one we have
            if time_boot_ms < self.sample_ms - REBOOT_MS and not self.gone:
                self.gone = f"it rebooted (its time_boot_ms went from {self.sample_ms} to {time_boot_ms})"
            return
        self.sample_fields = decoded
        self.sample_ms = time_boot_ms
        self.sample_arrival_mono = arrival

    def sample(self) -> tuple[float, np.ndarray, np.ndarray, np.ndarray]:
        """``(time_boot_s, p_W, v_W, q_WB)`` of the latest complete sample, in ENU/FLU."""
        s = self.sample_fields
        return self.sample_ms / 1000.0, s[SAMPLE_P], s[SAMPLE_V], s[SAMPLE_Q]
