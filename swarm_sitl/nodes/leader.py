"""The leader as a process: node 0 publishes the reference ``p_r`` and its derivatives.

Real time: tick ``k`` at ``epoch + t_k`` on the wall clock. Lockstep: as fast as its out-neighbours
allow, at most ``run.lockstep_window`` ticks ahead of the slowest of them (their status messages
say where they are), so a follower never has an unbounded backlog; and no further than the
supervisor's hold (``clock.wait_while_held``: a page's pause), which it obeys as a follower does.
"""

from collections.abc import Callable

from sim_vehicles.runtime.lifeline import settle_heap
from swarm_sitl.bus.clock import wall_epoch_to_monotonic
from swarm_sitl.bus.codec import Message
from swarm_sitl.bus.node_bus import NodeBus
from swarm_sitl.config.schema import SwarmConfig
from swarm_sitl.nodes.assembly import build_leader
from swarm_sitl.nodes.controller import NodeReport, wait_for_start
from swarm_sitl.nodes.pacing import Pacer, pacer

#: lockstep: how long the leader sleeps when it is ``lockstep_window`` ticks ahead of a follower.
#: Long enough that it wakes a few times per window, not per tick, and publishes the ticks it may
#: then run in one burst (zenoh sends them in one batch, each follower reads them in one wake-up);
#: short enough that followers never wait for it below 5000 ticks/s (the default window of 50
#: ticks lasts 10 ms at that rate).
LEADER_POLL_S = 0.01


def run_leader(
    cfg: SwarmConfig,
    bus: NodeBus,
    lockstep: bool,
    out_neighbours: list[int],
    clock: Pacer | None = None,
    resume_tick: int = 0,
    published: Callable[[float], None] | None = None,
) -> NodeReport:
    """Node 0: the reference at every tick, on the wall clock or a window ahead of the followers
    (``pacing``: one loop for both clocks). ``resume_tick``: a leader restarted by a fault plan
    resumes there in lockstep; in real time it joins at the tick the swarm's clock is at.
    ``published(t_s)``: told of each tick's time once its reference is out (``ros2_clock``)."""
    r = cfg.run
    clock = pacer(lockstep, cfg.control_dt_s) if clock is None else clock
    clock.attach(bus, r.stall_timeout_s)
    leader = build_leader(cfg)
    settle_heap()
    n = cfg.n_control_steps
    clock.epoch_mono = wall_epoch_to_monotonic(wait_for_start(bus, None, r.start_timeout_s, "leader"))
    first = clock.first_tick(resume_tick, 0.0)
    # a leader restarted by the plan has heard no status yet: its followers are blocked on its
    # resume tick (they publish none until it comes), so it may run the window past it until
    # they speak; a status from before its start is gone (a put keeps no history)
    floor = resume_tick - 1 if resume_tick else -1

    def ahead_ok() -> bool:  # (of the tick being run: the clock's)
        return all(max(bus.progress(j), floor) >= clock.tick - r.lockstep_window for j in out_neighbours)

    def behind() -> str:
        at = [bus.progress(j) for j in out_neighbours]
        return f"leader at tick {clock.tick}: followers {out_neighbours} report no progress (at ticks {at})"

    for k in range(first, n + 1):
        clock.wait_instant(k, 0.0, [], bus.poll, bus.poll, skip=False)
        # the window, and the hold (followers held stop reporting progress)
        clock.wait_for(k, ahead_ok, behind, bus.poll, LEADER_POLL_S)
        msg: Message = leader.step(k)
        bus.publish(msg)
        if published is not None:
            published(msg.t_s)
    clock.end(n, 0.0)
    return NodeReport(n + 1 - first, clock.late, 0.0, 0, bus.dropped)
