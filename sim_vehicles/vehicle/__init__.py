"""One simulated vehicle behind its MAVLink 2 endpoint on UDP (``endpoint``), and its usual
lockstep tick in one compiled call (``lockstep_tick``); the autopilots it speaks as
(``autopilots``: PX4, ArduCopter), their modes (``modes``), its services and telemetry.

May import: common, runtime, plant, mavlink.
"""
