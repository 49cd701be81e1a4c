"""swarm_sitl: the swarm side of the test bench.

Distributed estimator and position loop of each follower (the paper's laws, pure and compiled),
the leader's reference, the graph and its gain conditions, and the tools that run a swarm in one
process (``sim``) and plot what it recorded. It may use ``sim_vehicles``; never the reverse.

``Swarm`` (``swarm_sitl.api``) runs a swarm from Python, with a fault plan, and returns its results.
"""

from typing import Any

__version__ = "0.1.0"
__all__ = ["Swarm", "SwarmResult"]


def __getattr__(name: str) -> Any:
    # imported on first use: ``python -m swarm_sitl`` and the node processes do not load the API
    if name in __all__:
        from swarm_sitl import api

        return getattr(api, name)
    raise AttributeError(name)
