"""One simulated vehicle behind its MAVLink 2 endpoint on UDP (``endpoint``), and its usual
lockstep tick in one compiled call (``lockstep_tick``).

May import: common, runtime, plant, mavlink.
"""
