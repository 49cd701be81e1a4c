"""sim_vehicles: a simulated VTOL vehicle behind a PX4-like MAVLink 2 endpoint, usable alone.

Its 6-DOF rigid-body plant and its attitude loop (the paper's torque law), and the MAVLink face it
shows the world. Nothing here knows about swarms, graphs or estimators. Its folders, each allowed
to import only those before it (``tests/test_layout.py``):

- ``common``: what both packages share (the JIT helper, quaternions, the state layout, the command);
- ``runtime``: process helpers (UDP arrival stamps, a supervised life, crash-safe logs);
- ``plant``: the aircraft, pure (rigid body, torque law, attitude loop, failsafe);
- ``models``: what one vehicle is, whole (``VehicleConfig``), and the one function that builds it;
- ``mavlink``: the wire, pure (ENU/NED, message fields and frames, the decoder, signing, PX4);
- ``vehicle``: the endpoint (ports, telemetry, services, flight modes, run loops);

and ``__main__`` (``python -m sim_vehicles``): one vehicle as a process.

Conventions: ENU world, FLU body, Hamilton quaternions ``[w, x, y, z]`` rotating body to world;
NED/FRD only in ``mavlink`` (``docs/paper.md``).
"""
