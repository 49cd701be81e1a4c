"""The MAVLink wire, pure: ENU/FLU <-> NED/FRD (``enu_ned``), the fields of the messages the swarm
uses (``wire_format``), their frames without message objects (``frames``, ``tick_frames``),
MAVLink 2 signing (``signing``, ``sha256``), PX4's and ArduCopter's conventions (``px4_profile``,
``ardupilot_profile``, and ArduCopter's reading of a setpoint: ``ardupilot_guided``) and the one
map between a thrust and the setpoint's thrust field (``thrust_map``); the decoder of the frames a
vehicle gets, bytes to fields in one compiled call (``decoder``). No sockets.

May import: common.
"""
