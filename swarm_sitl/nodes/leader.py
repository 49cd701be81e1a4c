"""The leader as a process: node 0 publishes the reference ``p_r`` and its derivatives.

Real time: tick ``k`` at ``epoch + t_k`` on the wall clock. Lockstep: as fast as its out-neighbours
allow, at most ``run.lockstep_window`` ticks ahead of the slowest of them (their status messages
say where they are), so a follower never has an unbounded backlog; and no further than the
supervisor's hold (``clock.wait_while_held``: a page's pause), which it obeys as a follower does.
"""

import time

from sim_vehicles.runtime.lifeline import settle_heap
from swarm_sitl.bus.clock import (
    RunClock,
    join_tick,
    linger_after_last_tick,
    sleep_until,
    wait_until,
    wait_while_held,
    wall_epoch_to_monotonic,
)
from swarm_sitl.bus.codec import Message
from swarm_sitl.bus.node_bus import NodeBus
from swarm_sitl.config.schema import SwarmConfig
from swarm_sitl.nodes.assembly import build_leader
from swarm_sitl.nodes.controller import NodeReport, wait_for_start

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
    clock: RunClock | None = None,
    resume_tick: int = 0,
) -> NodeReport:
    """Node 0: the reference at every tick, on the wall clock or a window ahead of the followers.
    ``resume_tick``: a leader restarted by a fault plan in lockstep resumes there."""
    clock = RunClock(lockstep, cfg.control_dt_s) if clock is None else clock
    leader = build_leader(cfg)
    settle_heap()
    r = cfg.run
    dt = cfg.control_dt_s
    n = cfg.n_control_steps
    epoch_mono = wall_epoch_to_monotonic(wait_for_start(bus, None, r.start_timeout_s, "leader"))
    clock.epoch_mono = epoch_mono
    late = 0
    step = [0]

    def ahead_ok() -> bool:
        # a leader restarted by the plan has heard no status yet: its followers are blocked on
        # its resume tick (they publish none until it comes), so it may run the window past it
        # until they speak; a status from before its start is gone (a put keeps no history)
        floor = resume_tick - 1 if resume_tick else -1
        return all(max(bus.progress(j), floor) >= step[0] - r.lockstep_window for j in out_neighbours)

    def held() -> bool:  # the tick before this one is at or past the hold
        return step[0] - 1 >= bus.hold_tick()

    def behind() -> str:
        at = [bus.progress(j) for j in out_neighbours]
        return f"leader at tick {step[0]}: followers {out_neighbours} report no progress (at ticks {at})"

    # real time: a leader started again by a fault plan joins at the current tick
    first = resume_tick if lockstep else join_tick(time.monotonic(), epoch_mono, 0.0, dt)
    for k in range(first, n + 1):
        step[0] = clock.tick = k
        if lockstep:
            while True:  # the window, and the hold (followers held stop reporting progress)
                wait_until(
                    lambda: ahead_ok() or held(),
                    bus.poll,
                    [],
                    r.stall_timeout_s,
                    behind,
                    block_s=lambda: LEADER_POLL_S,
                    hold=bus.hold_tick,
                )
                if not held():
                    break
                wait_while_held(bus.hold_tick, k - 1, bus.poll, [])
        else:
            sleep_until(epoch_mono + k * dt, [], bus.poll)
            if time.monotonic() - epoch_mono - k * dt > dt:
                late += 1
        msg: Message = leader.step(k)
        bus.publish(msg)
    if not lockstep:
        linger_after_last_tick(epoch_mono + n * dt, dt)
    else:
        bus.drain(r.stall_timeout_s)  # the followers have every estimate before the session closes
    return NodeReport(n + 1 - first, late, 0.0, 0, bus.dropped)
