"""What a controller does with inputs that are missing or old: what a lockstep controller waits for
when a neighbour's process is gone (``nodes.controller``), and what its error says when old inputs
made the paper's estimator diverge (``laws.zou_meng``, through ``nodes.law_host``)."""

import math

import numpy as np
import pytest

from swarm_sitl.bus.clock import StallError
from swarm_sitl.bus.codec import HOLD_NONE, Message
from swarm_sitl.laws.command_attitude import SingularCommandError
from swarm_sitl.laws.contract import Received, VehicleSample
from swarm_sitl.nodes import controller as controller_node
from swarm_sitl.nodes.assembly import build_law
from swarm_sitl.nodes.controller import _Inputs
from swarm_sitl.nodes.law_host import LawError

pytestmark = pytest.mark.unit


class _Bus:
    def __init__(self) -> None:
        self.estimates: dict[tuple[int, int], Message] = {}
        self.gone: set[int] = set()

    def estimate(self, src: int, step: int) -> Message | None:
        return self.estimates.get((src, step))

    def settled(self, src: int, step: int) -> bool:
        return (src, step) in self.estimates

    def lost(self) -> set[int]:
        return set(self.gone)

    def fileno(self) -> int:
        return -1

    def hold_tick(self) -> int:
        return HOLD_NONE


class _Link:
    stamps_arrivals = True
    sample_ms = 90  # the vehicle sample of this tick (100 ms) has not come either

    def fileno(self) -> int:
        return -1

    def sample_settled(self, time_boot_ms: int) -> bool:
        return self.sample_ms == time_boot_ms


def _waiting_at_tick_10(bus: _Bus) -> _Inputs:
    io = _Inputs("follower 4", 4, _Link(), bus, [1, 2], 0.01)  # type: ignore[arg-type]
    io.k, io.t_ms, io.need = 10, 100, [1, 2]
    return io


def _estimate(src: int, step: int) -> Message:
    return Message(src, step, step * 0.01, np.zeros(12))


def test_a_neighbour_that_finished_after_sending_what_is_needed_does_not_stall_the_tick(monkeypatch):
    monkeypatch.setattr(controller_node, "LOST_GRACE_S", -1.0)  # no grace: any stall raises at once
    bus = _Bus()
    bus.estimates[(2, 9)] = _estimate(2, 9)
    bus.gone = {2}  # node 2 ran ahead, finished and exited; node 1's estimate is still on its way
    io = _waiting_at_tick_10(bus)
    io.idle()  # no StallError: what is missing comes from a node that is still there
    assert io._lacking() == [1] and io._lost_since == math.inf  # waiting, not counting a stall
    assert "no estimate of node 1 for tick 9" in io.missing() and "went away" not in io.missing()


def test_a_missing_estimate_from_a_node_that_is_gone_stalls_the_tick_naming_it(monkeypatch):
    monkeypatch.setattr(controller_node, "LOST_GRACE_S", -1.0)
    bus = _Bus()
    bus.estimates[(2, 9)] = _estimate(2, 9)
    bus.gone = {1, 2}
    with pytest.raises(StallError, match=r"no estimate of node 1 for tick 9.*node\(s\) \[1\] went away"):
        _waiting_at_tick_10(bus).idle()


def test_a_gone_node_gets_a_grace_period_for_messages_still_in_flight():
    bus = _Bus()
    bus.gone = {1}
    io = _waiting_at_tick_10(bus)
    io.idle()  # within LOST_GRACE_S of noticing: no error yet, but the stall clock runs
    assert io._lost_since < math.inf and io._lacking() == [1, 2]
    bus.estimates[(1, 9)] = _estimate(1, 9)
    bus.estimates[(2, 9)] = _estimate(2, 9)
    io.idle()  # it came: nothing is lacking from a node that is gone, and the clock stops
    assert io._lacking() == [] and io._lost_since == math.inf


@pytest.mark.parametrize("age_s", [0.01, 0.47])
def test_a_diverged_controller_says_when_its_inputs_were_old(paper_cfg, age_s):
    """A neighbour estimate that makes the output non-finite stops the controller with one line; if
    the estimate was many periods old (a saturated real-time machine) the line says how old and
    what that suggests, and otherwise it does not."""
    law = build_law(paper_cfg, 4)
    q, x = np.array([1.0, 0.0, 0.0, 0.0]), np.zeros(3)
    law.step(0.0, VehicleSample(0.0, x, x, q), {})
    k = 50
    t = k * paper_cfg.control_dt_s
    bad = Received(np.concatenate([np.full(3, np.inf), np.zeros(9)]), t - age_s, age_s)
    with pytest.raises(LawError) as e:
        law.step(t, VehicleSample(t, x, x, q), {1: bad, 2: bad})
    assert isinstance(e.value.__cause__, SingularCommandError)  # the paper's own diagnosis, kept
    text = str(e.value)
    assert text.startswith("law swarm_sitl.laws.zou_meng:ZouMengLaw, follower 4 at t=0.500 s: ")
    assert "not finite" in text and "\n" not in text
    old = age_s > 5 * paper_cfg.control_dt_s
    assert ("a machine too slow for the swarm" in text) == old
    assert (f"inputs were up to {age_s:.2f} s old" in text) == old
