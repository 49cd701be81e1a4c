"""The control system, pure: the paper's laws and what they need. No I/O, no clock, no process.

- ``trajectories``: the leader's reference and its derivatives;
- ``graph``: the directed communication graph (leader 0, followers 1..n);
- ``estimator``: the distributed estimator of the leader's state;
- ``position_loop``: the command force with its saturated auxiliary system, and its derivatives;
- ``command_attitude``: the singularity-free command attitude, its rate and acceleration;
- ``follower_law``: one follower's law assembled from those three, in compiled kernels;
- ``follower``: the follower's sampled-data controller (and the leader's reference node): the
  step functions ``sim`` and the processes run;
- ``gain_conditions``, ``gain_report``: Theorem 1's sufficient conditions, and their text.

The torque law is the vehicle's attitude loop: ``sim_vehicles/plant/torque_law.py``.

May import: sim_vehicles.common.
"""
