"""``run``'s options that name followers, checked against the config before anything starts:
``--external`` (a controller of the user's) and ``--ros2``/``--ros2-controller`` (the run on ROS 2
topics; a follower flown by a ROS 2 node). A bad one is one line (``CliError``)."""

from swarm_sitl.commands.common import CliError
from swarm_sitl.config.schema import SwarmConfig


def with_ros2(cfg: SwarmConfig, on: bool, flown: list[int]) -> SwarmConfig:
    """``--ros2`` (the run on ROS 2 topics, as the config's ``ros2:`` says) and each
    ``--ros2-controller I`` (follower I flown by a ROS 2 node; in lockstep it answers each tick),
    checked."""
    controllers = [*cfg.ros2.controllers, *flown]
    if not (on or controllers):
        return cfg
    known = {f.id for f in cfg.followers}
    for i in flown:
        if i not in known:
            raise CliError(
                f"--ros2-controller {i}: no follower {i} in {cfg.name} (followers {sorted(known)})"
            )
        if any(e.controller == i for e in cfg.faults.plan):
            raise CliError(
                f"--ros2-controller {i}: the fault plan acts on controller {i}, which a ROS 2 node flies"
            )
    if len(set(controllers)) != len(controllers):
        raise CliError(f"--ros2-controller: a follower named twice ({controllers})")
    ros2 = cfg.ros2.model_copy(update={"enabled": True, "controllers": controllers})
    return cfg.model_copy(update={"ros2": ros2})


def check_external(cfg: SwarmConfig, ids: list[int], realtime: bool) -> tuple[int, ...]:
    """``--external`` ids, checked against the config and the fault plan."""
    if not ids:
        return ()
    if not realtime:
        raise CliError("--external needs --realtime (a lockstep controller steps its vehicle's clock itself)")
    known = {f.id for f in cfg.followers}
    for i in ids:
        if i not in known:
            raise CliError(f"--external {i}: no follower {i} in {cfg.name} (followers {sorted(known)})")
        if any(e.controller == i for e in cfg.faults.plan):
            raise CliError(
                f"--external {i}: the fault plan acts on controller {i}, which this run does not start"
            )
    if len(set(ids)) != len(ids):
        raise CliError(f"--external: an id given twice ({ids})")
    return tuple(sorted(ids))
