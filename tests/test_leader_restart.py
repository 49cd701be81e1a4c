"""The leader's lockstep pacing (``nodes.leader.run_leader``) over a bus of its own, in process: it
runs at most ``run.lockstep_window`` ticks ahead of the followers' reported progress, and a leader
restarted by a fault plan, which cannot have heard the statuses sent before it started, still
runs the window past its resume tick, where its followers wait for it."""

import time

import pytest

from swarm_sitl.bus.clock import StallError
from swarm_sitl.bus.codec import HOLD_NONE
from swarm_sitl.config.load import load_config
from tests.conftest import CONFIGS

pytestmark = pytest.mark.integration


class _Bus:
    """A bus with no one on it but what the test says: the followers' progress, the start."""

    def __init__(self, progress: int = -1):
        self.published: list[int] = []
        self.at = progress
        self.dropped = 0

    def set_ready(self) -> None: ...
    def fileno(self) -> int:
        return -1

    def poll(self) -> None: ...
    def hold_tick(self) -> int:
        return HOLD_NONE

    def start_epoch(self) -> float:
        return time.time()

    def progress(self, follower: int) -> int:
        return self.at

    def publish(self, msg) -> None:
        self.published.append(msg.step)

    def drain(self, timeout_s: float) -> bool:
        return True


def _cfg():
    cfg = load_config(CONFIGS / "paper.yaml").model_copy(update={"duration_s": 8.0})
    return cfg.model_copy(update={"run": cfg.run.model_copy(update={"stall_timeout_s": 0.3})})


@pytest.mark.parametrize("resume", [0, 500])
def test_the_leader_runs_the_window_past_what_it_has_heard_and_then_waits(resume):
    from swarm_sitl.nodes.leader import run_leader

    cfg = _cfg()
    w = cfg.run.lockstep_window
    bus = _Bus()
    with pytest.raises(StallError, match=r"followers \[1, 2, 3\] report no progress"):
        run_leader(cfg, bus, True, [1, 2, 3], resume_tick=resume)  # type: ignore[arg-type]
    # from its first tick to the window past where its followers must be (none heard: -1, or,
    # restarted, the tick before its own first)
    last = (resume - 1 if resume else -1) + w
    assert bus.published == list(range(resume, last + 1)), (bus.published[:3], bus.published[-3:])


def test_a_restarted_leader_runs_to_the_end_once_its_followers_report():
    from swarm_sitl.nodes.leader import run_leader

    cfg = _cfg()
    bus = _Bus(progress=cfg.n_control_steps)
    rep = run_leader(cfg, bus, True, [1, 2, 3], resume_tick=500)  # type: ignore[arg-type]
    assert bus.published == list(range(500, cfg.n_control_steps + 1)) and rep.late_ticks == 0
