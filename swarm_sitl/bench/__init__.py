"""Speed figures, measured and printed (``swarm-sitl bench``), never asserted by a timed test:
``speed`` (the paper run against ``sim``, real time, another source tree alternated), ``scale``
(how the cost grows with the swarm), ``empty_swarm`` (the process structure with no work in it),
``cost_split`` (where a process's CPU goes, by activity), ``cpu_gap`` (what a run spends beyond the
empty swarm and ``sim``), ``plan_cost`` (``sim`` without and with a
fault plan), ``view_cost`` (a run without and with a page open on it), ``ros2_cost`` (without and with its
ROS 2 face and a reader), ``sim_memory`` (``sim``'s peak memory by duration) and ``soak`` (a long
real-time run watched for leaks).

May import: sim_vehicles, laws, bus, faults, config, rundir, link, nodes, running.
"""
