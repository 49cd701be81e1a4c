"""The bus between the nodes of a swarm, over Eclipse zenoh: one key per directed edge of the graph.

- ``keys``: the key layout (``swarm/<name>/edge/<src>/<dst>``, status, start, hold, liveliness);
- ``codec``: the payloads, byte by byte (versioned, fixed size, checked);
- ``session``: how a process joins (``ZenohSection``), the run's router, the start signal;
- ``access``: which node may use which key, its credentials, the router's access control;
- ``node_bus``: one node's bus (its in-edges in, its out-edges out), the interface its loop uses;
- ``estimates``: the estimates a node has heard and may use, per in-neighbour and tick;
- ``clock``: waiting for inputs or for a wall-clock instant, and the run's clock;
- ``hold``: a lockstep run held at a tick and stepped (a page's pause), the supervisor's side.

May import: sim_vehicles.runtime, laws.
"""
