"""The supervisor's loop (``running.observers.supervise``): each observer acts in its order, at
most once per its period, until every process that must finish has; what one raises ends the loop."""

import itertools
import random

import pytest

from swarm_sitl.running import observers
from swarm_sitl.running.observers import Observer, supervise

pytestmark = pytest.mark.unit


class _Sup:
    """A supervisor whose processes finish after ``passes`` looks."""

    def __init__(self, passes: int):
        self.left = passes

    def finished(self) -> bool:
        self.left -= 1
        return self.left < 0


@pytest.mark.parametrize("seed", range(5))
def test_each_observer_acts_in_order_no_more_often_than_its_period(monkeypatch, seed):
    rng = random.Random(seed)
    clock = [100.0]
    step_s = rng.choice([0.01, 0.02, 0.05])

    def sleep(s: float) -> None:  # the loop's sleep moves a fake monotonic clock
        clock[0] += step_s

    monkeypatch.setattr(observers.time, "monotonic", lambda: clock[0])
    monkeypatch.setattr(observers.time, "sleep", sleep)
    monkeypatch.setattr(observers.time, "time", lambda: clock[0] + 1000.0)
    periods = [rng.choice([0.0, 0.03, 0.1, 0.25, 1.0]) for _ in range(4)]
    log: list[tuple[int, float, float]] = []
    obs = [Observer(lambda r, now, j=j: log.append((j, r, now)), every_s=p) for j, p in enumerate(periods)]
    passes = rng.randrange(20, 80)
    supervise(_Sup(passes), obs, epoch_unix_s=1050.0)  # type: ignore[arg-type]
    for j, p in enumerate(periods):
        times = [now for k, _, now in log if k == j]
        gaps = [b - a for a, b in itertools.pairwise(times)]
        assert times and times[0] == 100.0  # at the first pass
        assert all(g >= p - 1e-9 for g in gaps), (j, p)  # no more often than its period
        if p <= step_s:  # due at every pass
            assert len(times) == passes
        else:  # and not a pass later than it is due
            assert all(g < p + step_s + 1e-9 for g in gaps), (j, p)
    assert all(r == pytest.approx(now + 1000.0 - 1050.0) for _, r, now in log)  # run time: since the epoch
    assert [j for j, _, now in log if now == 100.0] == list(range(len(periods)))  # in their order


def test_what_an_observer_raises_ends_the_loop(monkeypatch):
    monkeypatch.setattr(observers.time, "sleep", lambda s: None)
    acted: list[int] = []

    def fails(run_s: float, now: float) -> None:
        raise RuntimeError("the plan lost an aircraft")

    with pytest.raises(RuntimeError, match="lost an aircraft"):
        supervise(_Sup(10), [Observer(fails), Observer(lambda r, n: acted.append(1))], 0.0)  # type: ignore[arg-type]
    assert acted == []  # (the ones after it did not act)
