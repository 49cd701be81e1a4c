"""The config's ``ros2:`` section: the run on ROS 2 topics (``running.ros2_face``) and the
followers flown by ROS 2 nodes (``nodes.ros2_controller``)."""

from typing import Annotated, Literal

from pydantic import BaseModel, ConfigDict, Field, field_validator

from swarm_sitl.ros2.names import RosNameError, check_namespace


class Ros2Section(BaseModel):
    """The run on ROS 2 topics (``docs/ros2.md``): the supervisor republishes it in rmw_zenoh's
    layout on the run's router, for ROS 2 nodes to read (``running.ros2_face``)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    enabled: bool = False  #: republish the run on ROS 2 topics (``run --ros2`` turns it on)
    domain_id: Annotated[int, Field(ge=0, le=232)] = 0  #: the ROS 2 domain (``ROS_DOMAIN_ID``)
    namespace: str = "/swarm"  #: the topics' namespace: ``<namespace>/follower_<i>/pose``, ...
    #: whose message definitions and type hashes (Humble's rmw_zenoh has no type hashes)
    distro: Literal["jazzy", "humble"] = "jazzy"
    #: how often the newest of each topic is republished [Hz, wall clock]: in lockstep the run's
    #: simulated time goes faster than the wall's, and ROS 2 sees it at this rate
    rate_hz: Annotated[float, Field(gt=0, le=1000)] = 20.0
    #: followers flown by a ROS 2 node, not by the law (``run --ros2-controller I``; in lockstep
    #: the node answers each tick):
    #: each node joins as user ``ros2_controller_<i>`` and may write only its follower's
    #: ``<namespace>/follower_<i>/control/setpoint`` and ``message`` (``docs/ros2.md``)
    controllers: list[Annotated[int, Field(ge=1)]] = []

    @field_validator("namespace")
    @classmethod
    def _ros2_name(cls, ns: str) -> str:
        try:
            return check_namespace(ns)
        except RosNameError as e:
            raise ValueError(str(e)) from None
