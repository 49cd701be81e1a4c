"""A run described by one file: the schema (``schema``; its ``vehicle:`` and ``wind:`` sections in
``vehicle_section``; its ``ros2:`` section in ``ros2_section``; the run's one seed and its streams
in ``seeds``; its ``law:`` entry made a class in ``law_entry``), reading a file into it with
one-line errors (``load``; a run directory's without importing its plug-ins), a generated swarm's
config (``generator``, ``swarm-sitl new``) and the reference of every key (``reference``,
``docs/config.md``).

May import: sim_vehicles.common, sim_vehicles.plant, sim_vehicles.models, laws, bus, faults, specs, ros2.
"""
