"""Where does a law break: the search for the cheapest fault plan that violates a requirement.

``space`` (what may fail, how, where and when: a file's entries, each a set of plan entries with
their parameter ranges; a plan's cost), ``evaluate`` (one plan flown in ``sim``, the
requirement's robustness), ``workers`` (plans flown by this machine's worker processes or a Dask
cluster), ``shrink`` (a violating plan made minimal), ``outputs`` (what was found: the front, the
tables, the charts, the report, the lockstep confirmation), ``search`` (the study: Optuna's sampler
over the space, and the command's whole course).

May import: sim_vehicles, laws, bus, faults, config, rundir, specs, link, nodes, running, campaigns.
"""
