"""The processes of a swarm but the vehicles: each follower's controller and the leader.

- ``assembly``: the laws of a node built from the config (``sim`` builds them the same way);
- ``law_host``: a law stepped through its contract; ``law_guard``: a user's law kept from hanging,
  ending or flooding the process that hosts it (``sim`` too);
- ``controller``: follower i's loop: its vehicle over MAVLink, its neighbours over the bus, one
  loop for both clocks; ``neighbour_inbox``: which neighbour estimates a tick uses (riding
  through silent ones); ``ros2_controller``: a follower flown by a ROS 2 node, in the law's place;
- ``leader``: node 0, the reference, on the wall clock or a window ahead of the followers;
  ``ros2_clock``: its ``/clock`` on ROS 2, every tick (a run with ``ros2:`` on);
- ``pacing``: the two clocks the loops run on (``Lockstep``, ``WallClock``): the first tick,
  waiting for tick k and its lateness, the hold, the end; each is also the node's ``RunClock``;
- ``entry``: the process entry (``python -m swarm_sitl.nodes controller|leader``, ``__main__``):
  a node built from its config, its link, bus, fault wrappers and recording, run, its figures
  written; ``arguments``: its command line, shared with ``swarm-sitl controller|leader``.

May import: sim_vehicles.common, sim_vehicles.mavlink, sim_vehicles.plant, sim_vehicles.models,
sim_vehicles.runtime, laws, bus, faults, config, rundir, link, ros2.
"""
