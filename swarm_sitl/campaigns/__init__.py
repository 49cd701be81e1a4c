"""Robustness campaigns: a grid of config or fault-plan values times seeds, each point a lockstep
run (``swarm-sitl run``, in a process of its own), its metrics a row of one table: ``grid`` (what
varies), ``point`` (one run and its metrics), ``table`` (the CSV), ``runner`` (this machine's cores
or a Dask cluster), ``breaking`` (where the formation breaks), ``charts``, ``sweep`` (a campaign).

May import: sim_vehicles, laws, bus, faults, config, rundir, running.
"""
