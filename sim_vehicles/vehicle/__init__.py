"""One simulated vehicle behind its MAVLink 2 endpoint on UDP (``endpoint``), and its usual
lockstep tick in one compiled call (``lockstep_tick``); the autopilots it speaks as
(``autopilots``: PX4, ArduCopter), their modes (``modes``), its services and telemetry
(``services``, ``telemetry``), its two UDP ports with their peers and signing (``port``), and its
two run loops, real time and lockstep (``loops``).

May import: common, runtime, plant, mavlink.
"""
