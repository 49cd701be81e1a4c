"""``/clock`` on ROS 2 (a run with ``ros2:`` on): the leader puts its reference's time at every
tick it publishes, so the clock steps by ``control_dt_s`` and a ROS 2 node run with
``use_sim_time`` sees the run's simulated time. In real time that is the swarm's clock; in
lockstep the leader runs at most ``run.lockstep_window`` ticks ahead of its slowest follower, and
so may ``/clock`` (each vehicle's pose is stamped with its own tick).

In rmw_zenoh's layout (``ros2.wire``): a node ``swarm_sitl_clock`` in the run's namespace and one
publisher, its puts in CDR with their attachments; a put the link cannot take now is dropped,
never waited for (``ros2.publisher``): the leader never waits for what ROS 2 sees.
"""

from typing import Any

from swarm_sitl.config.ros2_section import Ros2Section
from swarm_sitl.ros2 import types, wire
from swarm_sitl.ros2.messages import clock_cdr
from swarm_sitl.ros2.names import RunTopics
from swarm_sitl.ros2.publisher import Publisher

NODE = "swarm_sitl_clock"  #: the clock's node name, in the run's namespace


class Ros2Clock:
    """The leader's ``/clock`` through ``session`` (the config's ``ros2:`` section ``r``)."""

    def __init__(self, session: Any, r: Ros2Section):
        zid = str(session.info.zid())
        self._node = session.liveliness().declare_token(
            wire.node_token(r.domain_id, zid, 0, r.namespace, NODE)
        )
        self._pub = Publisher(
            session, r.domain_id, zid, r.namespace, NODE, 1, RunTopics.clock, types.CLOCK, r.distro
        )

    def tick(self, t_s: float) -> None:
        """The leader published its reference at ``t_s`` (simulated)."""
        self._pub.put_cdr(clock_cdr(t_s))

    def close(self) -> None:
        self._pub.close()
        self._node.undeclare()
