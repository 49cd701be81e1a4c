"""swarm_sitl: the swarm side of the test bench.

Distributed estimator and position loop of each follower (the paper's laws, pure and compiled),
the leader's reference, the graph and its gain conditions, and the tools that run a swarm in one
process (``sim``) and plot what it recorded. It may use ``sim_vehicles``; never the reverse.
"""

__version__ = "0.1.0"
