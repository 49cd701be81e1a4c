"""The leader's lockstep pacing (``nodes.leader.run_leader``) over a bus of its own, in process: it
runs at most ``run.lockstep_window`` ticks ahead of the followers' reported progress, and a leader
restarted by a fault plan, which cannot have heard the statuses sent before it started, still
runs the window past its resume tick, where its followers wait for it."""

import pytest

from swarm_sitl.bus.clock import StallError
from tests.fakes import LeaderBus, leader_config

pytestmark = pytest.mark.integration


@pytest.mark.parametrize("resume", [0, 500])
def test_the_leader_runs_the_window_past_what_it_has_heard_and_then_waits(resume):
    from swarm_sitl.nodes.leader import run_leader

    cfg = leader_config()
    w = cfg.run.lockstep_window
    bus = LeaderBus()
    with pytest.raises(StallError, match=r"followers \[1, 2, 3\] report no progress"):
        run_leader(cfg, bus, True, [1, 2, 3], resume_tick=resume)  # type: ignore[arg-type]
    # from its first tick to the window past where its followers must be (none heard: -1, or,
    # restarted, the tick before its own first)
    last = (resume - 1 if resume else -1) + w
    assert bus.published == list(range(resume, last + 1)), (bus.published[:3], bus.published[-3:])


def test_a_restarted_leader_runs_to_the_end_once_its_followers_report():
    from swarm_sitl.nodes.leader import run_leader

    cfg = leader_config()
    bus = LeaderBus(progress=cfg.n_control_steps)
    rep = run_leader(cfg, bus, True, [1, 2, 3], resume_tick=500)  # type: ignore[arg-type]
    assert bus.published == list(range(500, cfg.n_control_steps + 1)) and rep.late_ticks == 0
