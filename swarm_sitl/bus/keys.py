"""The zenoh key expressions of a swarm: one per directed edge, and a few for running it.

::

    swarm/<name>/edge/<src>/<dst>     estimate of node src for node dst (src 0: the leader's reference)
    swarm/<name>/status/<i>           follower i's progress and position, every ``run.status_every`` ticks
    swarm/<name>/state/<i>            follower i's vehicle state, as often (a run with ``ros2:`` on)
    swarm/<name>/start                the supervisor's start signal (the real-time epoch)
    swarm/<name>/hold                 lockstep: the last tick a node may finish before it waits
    swarm/<name>/alive/<node>         liveliness token of node 0 (leader) or follower i, once ready

A controller publishes on each of its out-edges and subscribes to each of its in-edges, by its
full key: never a wildcard, so the bus carries exactly the graph. Payloads are in ``codec``.
"""


def edge(swarm: str, src: int, dst: int) -> str:
    return f"swarm/{swarm}/edge/{src}/{dst}"


def status(swarm: str, follower: int) -> str:
    return f"swarm/{swarm}/status/{follower}"


def state(swarm: str, follower: int) -> str:
    return f"swarm/{swarm}/state/{follower}"


def start(swarm: str) -> str:
    return f"swarm/{swarm}/start"


def hold(swarm: str) -> str:
    return f"swarm/{swarm}/hold"


def alive(swarm: str, node: int) -> str:
    return f"swarm/{swarm}/alive/{node}"
