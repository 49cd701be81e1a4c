"""swarm_sitl: the swarm side of the test bench. It may use ``sim_vehicles``; never the reverse.

Its folders, each allowed to import only those before it (``tests/test_layout.py``): ``ros2``
(ROS 2's names, rmw_zenoh's wire layout, message types: no ROS needed), ``laws`` (the paper's laws,
pure), ``bus`` (zenoh), ``faults`` (the fault plan and its wrappers),
``config`` (the schema), ``link`` (a controller's MAVLink link), ``rundir`` (the run directory),
``specs`` (requirements in signal temporal logic), ``nodes`` (the controller and leader
processes), ``running`` (``sim``, the supervisor, a run), ``view`` (the swarm in a browser),
``bench`` (speed figures), ``campaigns`` (robustness sweeps), ``falsify`` (the search for a plan
that breaks a requirement), ``commands`` (the CLI's subcommands). Above them all: ``cli``
(``swarm-sitl``; ``__main__``: ``python -m swarm_sitl``), ``api`` (``Swarm``: runs from Python,
with a fault plan, as objects) and ``pytest_plugin`` (the ``swarm`` fixture); ``sweep`` is
``campaigns.sweep.sweep``, ``falsify`` and ``assert_no_counterexample`` are ``falsify.search``'s.
"""

from typing import Any

__version__ = "0.1.0"
__all__ = ["Swarm", "SwarmResult", "assert_no_counterexample", "falsify", "sweep"]


def __getattr__(name: str) -> Any:
    # imported on first use: ``python -m swarm_sitl`` and the node processes do not load the API
    if name == "sweep":
        from swarm_sitl.campaigns.sweep import sweep

        return sweep
    if name in ("falsify", "assert_no_counterexample"):
        from swarm_sitl.falsify import search

        return getattr(search, name)
    if name in __all__:
        from swarm_sitl import api

        return getattr(api, name)
    raise AttributeError(name)
