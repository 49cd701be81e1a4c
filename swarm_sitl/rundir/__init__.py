"""The run directory: what a run writes, and everything that reads it afterwards.

- ``layout``: where each file is, and the columns of the rows the processes write;
- ``recording``: the arrays of a run in memory (``Recording``) and writing them; ``spool``: a
  run's rows on disk a block at a time, and its arrays written from there (``sim``'s flat memory);
- ``events``: what happened, merged from every process and the plan;
- ``merge``: the processes' raw records into a ``Recording``, and the summary's per-edge counts;
- ``load``: a run directory read back;
- ``requirements``: the run held to its config's ``spec:`` (each requirement's robustness);
- ``metrics``: the summary's figures (``settling``: when an error settles); ``rejoins``:
  whether the followers came back after a planned restart; ``plots``: the figures as PNG;
  ``mcap_export``: MCAP; ``ros2_bag``: a rosbag2 of the run's ROS 2 topics (``export --ros2``);
- ``outputs``: the run directory written from what was recorded; ``whole_files``: each file
  written whole or not at all; ``provenance``: what made the run (versions, plug-ins' hashes,
  seeds), in its summary; ``plugins``: the plug-ins' files kept in the run directory, so it reads
  and flies again anywhere.

Compute, record, plot: nothing here runs a swarm.

May import: sim_vehicles.common, sim_vehicles.runtime, laws, faults, config, specs, ros2.
"""
