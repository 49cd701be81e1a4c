"""The supervisor on its own, with real child processes that end as a buggy process would
(``running.supervisor``, ``running.ends``): any unplanned exit, code 0 included, is named with its
code and its last tick; one ridden through is recorded and the run goes on; a real-time controller
whose ticks stop, or a run past its end, is named."""

import json
import sys
import time
from pathlib import Path

import pytest

from sim_vehicles.runtime.counter_file import CounterFile
from swarm_sitl.config.load import load_config
from swarm_sitl.rundir.layout import procs_dir, tick_path
from swarm_sitl.running import ends
from swarm_sitl.running.supervisor import RunFailedError, Supervisor
from tests.conftest import CONFIGS

pytestmark = pytest.mark.integration
DT = 0.01


def _exits(code: int, after_s: float = 0.0) -> list[str]:
    return [sys.executable, "-c", f"import time, sys; time.sleep({after_s}); sys.exit({code})"]


def _sleeps() -> list[str]:
    return [sys.executable, "-c", "import time; time.sleep(60)"]


def _supervisor(tmp_path: Path) -> Supervisor:
    sup = Supervisor(tmp_path)
    sup.completed = lambda c: ends.completed(tmp_path, c)
    sup.last_tick = lambda c: ends.last_tick(tmp_path, DT, c)
    procs_dir(tmp_path).mkdir(parents=True, exist_ok=True)
    return sup


def _ended(sup: Supervisor) -> None:
    end = time.monotonic() + 10
    while any(c.proc.poll() is None for c in sup.children if "sleep(60)" not in " ".join(c.proc.args)):
        assert time.monotonic() < end
        time.sleep(0.02)


def _ticked(run_dir: Path, stem: str, tick: int) -> CounterFile:
    f = CounterFile(tick_path(run_dir, stem))
    f.set(tick + 1)
    return f


@pytest.mark.parametrize("code", [0, 3])
def test_a_vehicle_that_exits_with_any_code_is_named(tmp_path, code):
    sup = _supervisor(tmp_path)
    try:
        sup.spawn("vehicle_2", _exits(code), False)
        _ended(sup)
        with pytest.raises(RunFailedError, match=rf"^vehicle_2 exited with code {code}"):
            sup.check()
    finally:
        sup.close()


def test_a_node_that_exits_0_before_its_last_tick_is_named_with_its_last_tick(tmp_path):
    sup = _supervisor(tmp_path)
    tick = _ticked(tmp_path, "controller_2", 49)
    try:
        sup.spawn("controller_2", _exits(0), True)
        _ended(sup)
        assert not sup.finished()
        with pytest.raises(
            RunFailedError,
            match=r"^controller_2 exited with code 0 before the run's end \(its last tick 49, t=0.490 s\)$",
        ):
            sup.check()
    finally:
        tick.close()
        sup.close()


def test_a_node_that_wrote_its_figures_and_exits_0_has_finished(tmp_path):
    sup = _supervisor(tmp_path)
    try:
        (procs_dir(tmp_path) / "controller_1.stats.json").write_text("{}")
        sup.spawn("controller_1", _exits(0), True)
        _ended(sup)
        sup.check()
        assert sup.finished()
    finally:
        sup.close()


def test_a_restarted_node_says_its_last_tick_from_where_it_resumed(tmp_path):
    sup = _supervisor(tmp_path)
    tick = _ticked(tmp_path, "controller_3.1", 812)
    try:
        sup.spawn("controller_3.1", [*_exits(5), "--resume-tick", "700"], True, "controller_3")
        _ended(sup)
        with pytest.raises(RunFailedError, match=r"^controller_3.1 exited with code 5 \(its last tick 812, "):
            sup.check()
        assert sup.children[0].first_tick == 700
    finally:
        tick.close()
        sup.close()


def test_ridden_through_an_exit_is_recorded_and_the_others_go_on(tmp_path):
    sup = _supervisor(tmp_path)
    lost = ends.LostLog(tmp_path, time.time())
    sup.ride_through, sup.on_lost = True, lost.add
    tick = CounterFile(tick_path(tmp_path, "controller_2"))
    try:
        sup.spawn("controller_2", _exits(1), True)
        sup.spawn("controller_1", _sleeps(), True)
        _ended(sup)
        sup.check()
        sup.check()  # said once
        assert sup.lost == ["controller_2 exited with code 1 (before its first tick)"]
        # (its tick file was made, and nothing counted in it yet)
        assert sup.children[0].retired and not sup.finished()  # controller_1 is still flying
    finally:
        tick.close()
        lost.close()
        sup.close()
    events = [json.loads(x) for x in (procs_dir(tmp_path) / "lost.events").read_text().splitlines()]
    assert [(e["kind"], e["process"], e["code"]) for e in events] == [("process_lost", "controller_2", 1)]


def test_a_real_time_controller_whose_ticks_stop_is_named_and_a_run_past_its_end(tmp_path):
    cfg = load_config(CONFIGS / "paper.yaml")
    sup = _supervisor(tmp_path)
    tick = _ticked(tmp_path, "controller_4", 120)
    try:
        sup.spawn("controller_4", _sleeps(), True)
        t0 = 1000.0
        watch = ends.TickWatch(cfg, tmp_path, t0)
        watch.check(sup.children, t0 + 1.0)
        watch.check(sup.children, t0 + 1.0 + watch.allowed_s - 0.01)  # not yet
        tick.set(122)  # it ticked: the wait starts again
        watch.check(sup.children, t0 + 1.0 + watch.allowed_s + 0.5)
        with pytest.raises(
            RunFailedError,
            match=rf"^controller_4 \(law {cfg.law.entry}\) has not ticked for .* last tick 121, t=1.210 s$",
        ):
            watch.check(sup.children, t0 + 1.0 + 2 * watch.allowed_s + 0.6)
        tick.set(cfg.n_control_steps + 1)  # its last tick: done, not stalled
        late = t0 + cfg.duration_s + watch.allowed_s + 0.1
        with pytest.raises(RunFailedError, match=r"^the run did not end .* controller_4 still running$"):
            watch.check(sup.children, late)
        watch.check(sup.children, late - 0.2)
    finally:
        tick.close()
        sup.close()
