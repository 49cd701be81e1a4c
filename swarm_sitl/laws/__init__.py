"""The control laws, pure: the contract every law meets, the paper's law behind it, and what it
needs. No I/O, no clock, no process.

- ``contract``: what a law gets from the bench (``LawContext``, ``VehicleSample``, its inbox of
  ``Received`` messages) and gives back (``LawOutput``): the one module a law's author reads;
- ``template``: a runnable law that does nothing clever (it hovers), to copy;
- ``zou_meng``: the paper's law behind the contract (the default), assembled from

  - ``estimator``: the distributed estimator of the leader's state;
  - ``position_loop``: the command force with its saturated auxiliary system, and its derivatives;
  - ``command_attitude``: the singularity-free command attitude, its rate and acceleration;
  - ``follower_law``: the three assembled, in compiled kernels;
  - ``gain_conditions``, ``gain_report``: Theorem 1's sufficient conditions, and their text;
  - ``paper_gains``: its gains, one type for the config, the law and ``check``;

- ``trajectories``: the leader's reference and its derivatives;
- ``graph``: the directed communication graph (leader 0, followers 1..n).

The torque law is the vehicle's attitude loop: ``sim_vehicles/plant/torque_law.py``.

May import: sim_vehicles.common.
"""
