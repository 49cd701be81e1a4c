"""The MAVLink wire, pure: ENU/FLU <-> NED/FRD (``enu_ned``), the fields of the messages the swarm
uses (``wire_format``), their frames without message objects (``frames``, ``tick_frames``),
MAVLink 2 signing (``signing``, ``sha256``) and PX4's conventions (``px4_profile``). No sockets.

May import: common.
"""
