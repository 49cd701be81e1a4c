"""The supervisor on its own, with real child processes that end as a buggy process would
(``running.supervisor``, ``running.ends``): any unplanned exit, code 0 included, is named with its
code and its last tick; one ridden through is recorded and the run goes on; a real-time controller
whose ticks stop, or a run past its end, is named."""

import json
import signal
import sys
import time
import types
import unittest.mock
from pathlib import Path

import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from sim_vehicles.runtime.counter_file import CounterFile
from swarm_sitl.nodes.law_guard import HARD_STOP_S
from swarm_sitl.rundir.layout import procs_dir, tick_path
from swarm_sitl.running import ends, observers
from swarm_sitl.running.supervisor import SUPERVISE_EVERY_S, Child, RunFailedError, Supervisor
from tests.support import config

pytestmark = pytest.mark.integration
DT = 0.01


def _exits(code: int, after_s: float = 0.0) -> list[str]:
    return [sys.executable, "-c", f"import time, sys; time.sleep({after_s}); sys.exit({code})"]


def _sleeps() -> list[str]:
    return [sys.executable, "-c", "import time; time.sleep(60)"]


def _supervisor(tmp_path: Path) -> Supervisor:
    sup = Supervisor(tmp_path, rules=ends.RunExits(tmp_path, DT))
    procs_dir(tmp_path).mkdir(parents=True, exist_ok=True)
    return sup


class _Frozen:
    """A fault plan that stopped the processes of ``names`` and killed those of ``killed``."""

    def __init__(self, names: set[str], killed: frozenset[str] = frozenset()):
        self.names = names
        self.killed = killed

    def planned_exit(self, child: Child, code: int) -> bool:
        return child.process in self.killed and code == -signal.SIGKILL

    def frozen(self, process: str) -> bool:
        return process in self.names


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
    rules = sup.rules
    assert isinstance(rules, ends.RunExits)
    rules.lost = lost
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
    assert [(e["kind"], e["process"], e["code"], e["line"]) for e in events] == [
        ("process_lost", "controller_2", 1, sup.lost[0])
    ]
    assert 0.0 < events[0]["t_s"] < 10.0 and events[0]["source"] == "supervisor"  # since the epoch


def test_a_real_time_controller_whose_ticks_stop_is_named_and_a_run_past_its_end(tmp_path):
    cfg = config("paper")
    sup = _supervisor(tmp_path)
    tick = _ticked(tmp_path, "controller_4", 120)
    leader_tick = _ticked(tmp_path, "leader", 30)  # stalled too: only a controller's ticks are watched
    try:
        sup.spawn("leader", _sleeps(), True)
        sup.spawn("controller_4", _sleeps(), True)
        t0 = 1000.0
        watch = ends.TickWatch(cfg, tmp_path, t0)
        watch.check(sup.children, t0 + 1.0)
        # its law's guard gets its turn first: the stop after tick_timeout_s and the hard stop
        assert (
            cfg.run.tick_timeout_s + HARD_STOP_S
            <= watch.allowed_s
            <= cfg.run.tick_timeout_s + HARD_STOP_S + 1.5
        )
        watch.check(sup.children, t0 + 1.0 + watch.allowed_s - 0.01)  # not yet
        tick.set(122)  # it ticked: the wait starts again
        watch.check(sup.children, t0 + 1.0 + watch.allowed_s + 0.5)
        with pytest.raises(
            RunFailedError,
            match=rf"^controller_4 \(law {cfg.law.entry}\) has not ticked for {watch.allowed_s + 0.1:.1f} s "
            r".* last tick 121, t=1.210 s$",
        ):
            watch.check(sup.children, t0 + 1.0 + 2 * watch.allowed_s + 0.6)
        tick.set(cfg.n_control_steps + 1)  # its last tick: done, not stalled (writing its figures)
        assert 5.0 + 2 * watch.allowed_s < cfg.duration_s
        watch.check(sup.children, t0 + 5.0)
        watch.check(sup.children, t0 + 5.0 + 2 * watch.allowed_s)
        late = t0 + cfg.duration_s + watch.allowed_s + 0.1
        sup.spawn("vehicle_4", _sleeps(), False)  # a vehicle runs until torn down: not named
        with pytest.raises(
            RunFailedError, match=r"^the run did not end .*: leader, controller_4 still running$"
        ):
            watch.check(sup.children, late)
        watch.check(sup.children, late - 0.2)
        for c in sup.children[:2]:
            c.retired = True
        with pytest.raises(RunFailedError, match=r"^the run did not end .*: no process still running$"):
            watch.check(sup.children, late)
    finally:
        tick.close()
        leader_tick.close()
        sup.close()


def test_the_exit_line_says_why_from_the_log_for_a_failure_and_not_for_code_0(tmp_path):
    sup = _supervisor(tmp_path)
    try:
        sup.spawn(
            "vehicle_1",
            [sys.executable, "-c", "print('first'); print('boom: it broke'); print(); exit(3)"],
            False,
        )
        sup.spawn("leader", [sys.executable, "-c", "print('a line that is not a reason')"], True)
        garbled = "import sys; sys.stdout.buffer.write(b'bad \\xff\\xfe byte\\n'); sys.exit(4)"
        sup.spawn("vehicle_2", [sys.executable, "-c", garbled], False)  # its last words not UTF-8
        _ended(sup)
        lines = [sup.exit_line(c, c.proc.poll()) for c in sup.children]
        assert lines == [
            "vehicle_1 exited with code 3: boom: it broke",
            "leader exited with code 0 before the run's end",
            "vehicle_2 exited with code 4: bad \ufffd\ufffd byte",
        ]
        assert sup.children[1].first_tick == 0
    finally:
        sup.close()


def test_a_leader_says_its_last_tick_and_tick_0_is_a_tick(tmp_path):
    sup = _supervisor(tmp_path)
    ticks = [_ticked(tmp_path, "leader", 0), _ticked(tmp_path, "controller_1", -1)]
    try:
        sup.spawn("leader", _exits(0), True)
        sup.spawn("controller_1", _exits(0), True)
        _ended(sup)
        assert [sup.rules.last_tick(c) for c in sup.children] == [
            "its last tick 0, t=0.000 s",
            "before its first tick",
        ]
        assert ends.newest_tick(tmp_path, sup.children[0]) == 0
    finally:
        for t in ticks:
            t.close()
        sup.close()


def test_a_child_stopped_by_no_plan_fails_the_run_after_its_grace_and_one_the_plan_stopped_does_not(tmp_path):
    from swarm_sitl.running.supervisor import STOPPED_GRACE_S

    sup = _supervisor(tmp_path)
    try:
        sup.spawn("controller_1", _sleeps(), True)  # running on: each child is looked at
        victim = sup.spawn("controller_2", _sleeps(), True)
        time.sleep(0.5)  # the interpreter is up
        victim.proc.send_signal(signal.SIGSTOP)
        end = time.monotonic() + 5
        while not victim.stopped():
            assert time.monotonic() < end
            time.sleep(0.02)
        frozen = {"controller_2"}
        rules = sup.rules
        assert isinstance(rules, ends.RunExits)
        rules.faults = _Frozen(frozen)
        sup.check()
        time.sleep(STOPPED_GRACE_S + 0.1)
        sup.check()  # the plan stopped it: no failure
        frozen.clear()
        sup.check()  # seen stopped from now: within its grace
        time.sleep(STOPPED_GRACE_S + 0.1)
        with pytest.raises(RunFailedError, match=r"^controller_2 is stopped \(SIGSTOP or a debugger\)"):
            sup.check()
    finally:
        sup.close()
    assert victim.proc.poll() is not None  # close() woke it and ended it


#: a child that lets any process trace it and forks one that does (a debugger attached: the
#: child is in a tracing stop, ``t`` in /proc, not ``T``); the tracer says whether it could attach
_TRACED = """
import ctypes, os, time
libc = ctypes.CDLL(None, use_errno=True)
libc.prctl(0x59616D61, ctypes.c_ulong(-1), 0, 0, 0)  # PR_SET_PTRACER, PR_SET_PTRACER_ANY
me = os.getpid()
if os.fork() == 0:
    ok = libc.ptrace(16, me, 0, 0) == 0  # PTRACE_ATTACH
    print("attached" if ok else f"no ptrace: {os.strerror(ctypes.get_errno())}", flush=True)
    time.sleep(60)
    os._exit(0)
time.sleep(60)
"""


def test_a_child_held_by_a_debugger_fails_the_run_as_a_stopped_one_does(tmp_path, monkeypatch):
    import swarm_sitl.running.supervisor as supervisor

    monkeypatch.setattr(supervisor, "TERM_GRACE_S", 0.5)  # (a tracee takes no SIGTERM: killed at once)
    sup = _supervisor(tmp_path)
    try:
        held = sup.spawn("controller_3", [sys.executable, "-c", _TRACED], True)
        end = time.monotonic() + 20
        while not held.last_line():
            assert time.monotonic() < end
            time.sleep(0.02)
        if held.last_line() != "attached":  # (a container may forbid ptrace)
            pytest.skip(f"no process may trace another here: {held.last_line()}")
        while not held.stopped():
            assert time.monotonic() < end
            time.sleep(0.02)
        sup.check()  # seen stopped from now
        time.sleep(supervisor.STOPPED_GRACE_S + 0.1)
        with pytest.raises(RunFailedError, match=r"^controller_3 is stopped \(SIGSTOP or a debugger\)"):
            sup.check()
    finally:
        sup.close()
    assert held.proc.poll() == -signal.SIGKILL


def test_a_controller_stuck_at_its_first_tick_is_named_and_one_that_never_ticked_is_left_to_the_start(
    tmp_path,
):
    cfg = config("paper")
    sup = _supervisor(tmp_path)
    ticks = [_ticked(tmp_path, "controller_1", 0), _ticked(tmp_path, "controller_2", -1)]
    try:
        sup.spawn("controller_2", _sleeps(), True)
        sup.spawn("controller_1", _sleeps(), True)
        watch = ends.TickWatch(cfg, tmp_path, 0.0)
        watch.check(sup.children, 0.5)
        with pytest.raises(RunFailedError, match=r"^controller_1 .* its last tick 0, t=0.000 s$"):
            watch.check(sup.children, 0.5 + watch.allowed_s + 0.1)
    finally:
        for t in ticks:
            t.close()
        sup.close()


@settings(max_examples=100, deadline=None)
@given(
    st.lists(
        st.tuples(
            st.sampled_from(["controller", "vehicle", "leader"]),
            st.integers(1, 254),
            st.text(alphabet=st.characters(blacklist_categories=("Cc", "Cs")), max_size=60),
        ),
        max_size=40,
    )
)
def test_the_exits_ridden_through_are_one_line_naming_every_process_and_the_first_whole(exits):
    """However many processes are lost (32 followers on too small a machine lose a dozen), the
    run's last line is one line: the first ``WHOLE_LOST`` exits whole, then how many more and every
    one's process by name; no more text than those and the names."""
    lost = [f"{kind}_{i} exited with code 1 (its last tick 7): {why}" for kind, i, why in exits]
    line = ends.lost_line(lost)
    assert "\n" not in line
    whole = lost[: ends.WHOLE_LOST]
    assert line.startswith("; ".join(whole))
    rest = lost[ends.WHOLE_LOST :]
    names = [x.split(" ", 1)[0] for x in rest]
    if rest:
        assert f"and {len(rest)} more lost: {', '.join(names)} " in line
    else:  # (a handful: each whole, nothing added)
        assert line == "; ".join(whole)
    assert len(line) <= len("; ".join(whole)) + sum(len(n) + 2 for n in names) + 80


def test_an_exit_the_plan_made_is_no_failure_and_the_same_exit_of_another_process_is(tmp_path):
    sup = _supervisor(tmp_path)
    rules = sup.rules
    assert isinstance(rules, ends.RunExits)
    rules.faults = _Frozen(set(), frozenset({"controller_3"}))
    try:
        killed = [sys.executable, "-c", "import os, signal; os.kill(os.getpid(), signal.SIGKILL)"]
        for name in ("controller_3", "controller_2"):
            sup.spawn(name, killed, True)
        _ended(sup)
        with pytest.raises(RunFailedError, match=r"^controller_2 exited with code -9"):
            sup.check()
    finally:
        sup.close()


def test_a_loss_with_no_run_epoch_yet_is_recorded_at_time_0(tmp_path):
    """Lost before the run's epoch was known (a child lost while the run started): at t 0."""
    procs_dir(tmp_path).mkdir(parents=True)
    lost = ends.LostLog(tmp_path, None)
    sup = _supervisor(tmp_path)
    try:
        child = sup.spawn("vehicle_1", _exits(1), False)
        lost.add(child, 1, "vehicle_1 exited with code 1")
    finally:
        lost.close()
        sup.close()
    events = [json.loads(x) for x in (procs_dir(tmp_path) / "lost.events").read_text().splitlines()]
    assert [(e["t_s"], e["process"], e["code"]) for e in events] == [(0.0, "vehicle_1", 1)]


@settings(max_examples=30, deadline=None)
@given(
    periods=st.lists(st.floats(0.0, 0.5), min_size=1, max_size=4),
    passes=st.integers(1, 40),
    epoch_s=st.floats(-1e6, 1e6),
)
# a period of one or two passes, as the fake clock sums them: due exactly at a pass ("at least")
@example(periods=[SUPERVISE_EVERY_S, 2 * SUPERVISE_EVERY_S], passes=12, epoch_s=0.0)
def test_the_loop_runs_each_observer_in_order_when_it_is_due_until_the_run_is_finished(
    periods, passes, epoch_s
):
    """``observers.supervise`` on a clock that moves only in its sleeps: it passes ``passes`` times
    (the supervisor finished after that many looks), each pass one ``SUPERVISE_EVERY_S`` after the
    last; an observer of period ``e`` acts at the first pass, then at the first pass at least ``e``
    after the pass it last acted at; in a pass, the observers act in their order, each told the run's
    time (the UNIX clock less the epoch) and the monotonic instant."""
    clock = {"mono": 100.0}
    unix_minus_mono = 1.7e9
    fake_time = types.SimpleNamespace(
        monotonic=lambda: clock["mono"],
        time=lambda: clock["mono"] + unix_minus_mono,
        sleep=lambda s: clock.update(mono=clock["mono"] + s),
    )
    looks = []

    class Sup:
        def finished(self):
            looks.append(clock["mono"])
            return len(looks) > passes

    acted = []
    watch = [
        observers.Observer(lambda run_s, mono_s, j=j: acted.append((j, run_s, mono_s)), every_s=e)
        for j, e in enumerate(periods)
    ]
    with unittest.mock.patch.object(observers, "time", fake_time):
        observers.supervise(Sup(), watch, epoch_s)
    instants, mono = [], 100.0
    for _ in range(passes):  # (each pass's instant: the sum of the sleeps before it)
        instants.append(mono)
        mono += SUPERVISE_EVERY_S
    expected = []
    last = {j: None for j in range(len(periods))}
    for mono in instants:
        for j, e in enumerate(periods):
            if last[j] is None or mono >= last[j] + e:
                expected.append((j, mono))
                last[j] = mono
    assert [(j, mono_s) for j, _, mono_s in acted] == expected
    for _, run_s, mono_s in acted:  # (about 1.7e9 s: a float64 step there is 2.4e-7 s; four of them)
        assert run_s == pytest.approx(mono_s + unix_minus_mono - epoch_s, abs=1e-6)
    assert len(looks) == passes + 1
