"""sim_vehicles: the autopilot side of swarm-sitl.

A simulated VTOL vehicle: its 6-DOF rigid-body plant, its attitude loop (the paper's torque law),
and (in ``mavlink_endpoint``) the MAVLink 2 face it shows to the world. Nothing here knows about
swarms, graphs or estimators; this package is usable alone.

Conventions: ENU world, FLU body, Hamilton quaternions ``[w, x, y, z]`` rotating body to world.
NED/FRD appears only in ``frames`` and the MAVLink endpoint.
"""
