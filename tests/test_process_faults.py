"""The supervisor's side of a fault plan (``faults.processes.ProcessFaults``), in process: which
processes it kills, when it starts them again and with which tick, what it records, and when a
lost aircraft ends the run. The victims are real processes (``sleep``, each its own process group,
as the supervisor's children are), so each kill is a real SIGKILL that the test sees."""

import json
import signal
import subprocess
import time
from dataclasses import dataclass, field

import pytest

from swarm_sitl.faults.plan import FaultPlan, tick_of
from swarm_sitl.faults.processes import LostAircraftError, process_faults

pytestmark = pytest.mark.integration
DT = 0.02


@dataclass
class _Child:
    process: str
    proc: subprocess.Popen
    retired: bool = False

    @property
    def pid(self) -> int:
        return self.proc.pid


@dataclass
class _Supervisor:
    """The ``Processes`` a plan acts on: live ``sleep`` processes by name, and what was spawned."""

    children: dict[str, _Child] = field(default_factory=dict)
    spawned: list[tuple[str, list[str], str]] = field(default_factory=list)
    must_finish: list[bool] = field(default_factory=list)

    def start(self, *names: str) -> None:
        for n in names:
            proc = subprocess.Popen(["sleep", "60"], start_new_session=True)
            self.children[n] = _Child(n, proc)

    def child(self, process: str) -> _Child | None:
        c = self.children.get(process)
        return None if c is None or c.retired else c

    def spawn(self, name: str, argv: list[str], must_finish: bool, process: str | None = None) -> None:
        self.spawned.append((name, argv, process or name))
        self.must_finish.append(must_finish)

    def dead(self, name: str) -> bool:
        return self.children[name].proc.poll() == -signal.SIGKILL

    def close(self) -> None:
        for c in self.children.values():
            c.proc.kill()
            c.proc.wait()


@pytest.fixture
def sup():
    s = _Supervisor()
    s.start("leader", *(f"{k}_{i}" for k in ("controller", "vehicle") for i in (1, 2, 3)))
    yield s
    s.close()


def _faults(sup, tmp_path, plan: list[dict], lockstep: bool = False, stop_on_loss: bool = False):
    pf = process_faults(
        FaultPlan(seed=1, plan=plan), DT, stop_on_loss, sup, lockstep, tmp_path / "sup.events"
    )
    pf.set_restart(lambda name, n, resume: ["restart", name, str(n), str(resume)])
    return pf


def _events(pf, tmp_path) -> list[tuple[str, str, float]]:
    pf.close()
    lines = (tmp_path / "sup.events").read_text().splitlines()
    return [(e["kind"], e["process"], e["t_s"]) for e in map(json.loads, lines)]


@pytest.mark.parametrize("process", ["controller_2", "leader"])
def test_real_time_a_killed_process_is_started_again_restart_after_s_later(sup, tmp_path, process):
    entry = {"controller": 2} if process == "controller_2" else {"leader": True}
    pf = _faults(sup, tmp_path, [{**entry, "kill": True, "from_s": 1.0, "restart_after_s": 0.5}])
    pf.act(0.99, 0)
    assert not sup.dead(process) and not pf.down
    pf.act(1.01, 0)
    sup.children[process].proc.wait(timeout=5)
    assert sup.dead(process) and sup.children[process].retired
    assert pf.down == ({2} if process == "controller_2" else set())
    pf.act(1.50, 0)  # 0.49 s after the kill: not yet
    assert sup.spawned == []
    pf.act(1.52, 0)
    assert sup.spawned == [(f"{process}.1", ["restart", process, "1", "0"], process)]  # joins now
    assert not pf.down
    pf.act(9.0, 0)  # once
    assert len(sup.spawned) == 1
    assert _events(pf, tmp_path) == [("process_killed", process, 1.01), ("process_restarted", process, 1.52)]
    others = [n for n in sup.children if n != process]
    assert not any(sup.dead(n) for n in others)


def test_a_killed_process_without_restart_stays_down(sup, tmp_path):
    pf = _faults(sup, tmp_path, [{"leader": True, "kill": True, "from_s": 2.0}])
    for t in (2.0, 5.0, 60.0):
        pf.act(t, 0)
    sup.children["leader"].proc.wait(timeout=5)
    assert sup.dead("leader") and sup.spawned == [] and not pf.lost
    assert _events(pf, tmp_path) == [("process_killed", "leader", 2.0)]


def test_a_lost_vehicle_takes_its_controller_unless_told_not_to(sup, tmp_path):
    pf = _faults(
        sup,
        tmp_path,
        [
            {"vehicle": 1, "kill": True, "from_s": 1.0},
            {"vehicle": 3, "kill": True, "from_s": 1.0, "with_controller": False},
        ],
    )
    pf.act(1.0, 0)
    for n in ("vehicle_1", "controller_1", "vehicle_3"):
        sup.children[n].proc.wait(timeout=5)
    assert sup.dead("vehicle_1") and sup.dead("controller_1") and sup.dead("vehicle_3")
    assert sup.children["controller_3"].proc.poll() is None  # its controller flies on, vehicle-less
    assert pf.lost == {1, 3} and pf.down == {1} and sup.spawned == []
    kinds = _events(pf, tmp_path)
    assert ("vehicle_lost", "vehicle_1", 1.0) in kinds and ("vehicle_lost", "vehicle_3", 1.0) in kinds
    assert ("process_killed", "controller_1", 1.0) in kinds
    assert not any(p == "controller_3" for _k, p, _t in kinds)


def test_stop_on_loss_ends_the_run_in_one_line_naming_the_vehicle(sup, tmp_path):
    pf = _faults(sup, tmp_path, [{"vehicle": 2, "kill": True, "from_s": 3.0}], stop_on_loss=True)
    pf.act(2.9, 0)
    with pytest.raises(LostAircraftError, match=r"^vehicle_2 lost at 3 s \(run.stop_on_loss\)$"):
        pf.act(3.0, 0)
    sup.children["vehicle_2"].proc.wait(timeout=5)
    assert sup.dead("vehicle_2")
    # without it, the same loss is recorded and the run goes on
    sup.start("vehicle_2")
    (tmp_path / "on").mkdir()
    on = _faults(sup, tmp_path / "on", [{"vehicle": 2, "kill": True, "from_s": 3.0}])
    on.act(3.0, 0)
    assert on.lost == {2}


def test_lockstep_a_node_that_killed_itself_is_planned_and_resumes_at_its_restart_tick(sup, tmp_path):
    pf = _faults(
        sup,
        tmp_path,
        [{"controller": 2, "kill": True, "from_s": 1.0, "restart_after_s": 0.5}],
        lockstep=True,
    )
    pf.act(0.0, 10_000)  # in lockstep the supervisor never kills: the node does, at its tick
    assert sup.children["controller_2"].proc.poll() is None
    c2 = sup.children["controller_2"]
    c2.proc.send_signal(signal.SIGKILL)
    c2.proc.wait(timeout=5)
    assert not pf.planned_exit(sup.children["controller_3"], 1)  # an exit the plan did not make
    assert pf.planned_exit(c2, -signal.SIGKILL)
    resume = tick_of(1.0, DT) + round(0.5 / DT)
    assert sup.spawned == [("controller_2.1", ["restart", "controller_2", "1", str(resume)], "controller_2")]
    assert not pf.planned_exit(c2.__class__("controller_2", c2.proc), -signal.SIGKILL)  # once
    assert _events(pf, tmp_path) == [
        ("process_killed", "controller_2", tick_of(1.0, DT) * DT),
        ("process_restarted", "controller_2", 1.5),
    ]


def _state(proc: subprocess.Popen) -> str:
    """The process's state letter from /proc (T: stopped)."""
    return open(f"/proc/{proc.pid}/stat").read().rsplit(")", 1)[1].split()[0]


def _wait_state(proc: subprocess.Popen, want: str) -> bool:
    end = time.monotonic() + 5
    while time.monotonic() < end:
        if _state(proc) == want:
            return True
        time.sleep(0.01)
    return False


@pytest.mark.parametrize("lockstep", [False, True], ids=["real time", "lockstep"])
def test_a_frozen_process_is_stopped_for_freeze_s_of_wall_time_then_continued(sup, tmp_path, lockstep):
    pf = _faults(sup, tmp_path, [{"controller": 2, "freeze_s": 0.3, "from_s": 1.0}], lockstep=lockstep)
    c2 = sup.children["controller_2"].proc
    # real time: at run second 1.0; lockstep: once every live follower has done tick 1.0 / dt
    early, due = (0.99, 1.0) if not lockstep else (0.0, 0.0)
    steps = (0, 0) if not lockstep else (tick_of(1.0, DT) - 1, tick_of(1.0, DT))
    pf.act(early, steps[0])
    assert _state(c2) != "T" and not pf.frozen("controller_2")
    pf.act(due, steps[1])
    t0 = time.monotonic()
    assert _wait_state(c2, "T") and pf.frozen("controller_2")
    pf.act(due, steps[1])
    assert pf.frozen("controller_2")  # not before freeze_s
    while time.monotonic() - t0 < 0.3:
        time.sleep(0.01)
    pf.act(due + 0.5, steps[1])
    assert _wait_state(c2, "S") and not pf.frozen("controller_2")
    kinds = _events(pf, tmp_path)
    assert [k for k, _p, _t in kinds] == ["process_frozen", "process_thawed"]
    assert kinds[0][1] == "controller_2" and kinds[0][2] == (1.0 if lockstep else due)
    assert sup.spawned == [] and not sup.dead("controller_2")


def test_closing_never_leaves_a_process_stopped(sup, tmp_path):
    pf = _faults(sup, tmp_path, [{"leader": True, "freeze_s": 60.0, "from_s": 0.0}])
    pf.act(0.0, 0)
    leader = sup.children["leader"].proc
    assert _wait_state(leader, "T")
    pf.close()
    assert _wait_state(leader, "S") and not pf.frozen("leader")


def test_lockstep_a_lost_aircraft_takes_its_vehicle_when_its_controller_kills_itself(sup, tmp_path):
    pf = _faults(sup, tmp_path, [{"vehicle": 1, "kill": True, "from_s": 2.0}], lockstep=True)
    c1 = sup.children["controller_1"]
    c1.proc.send_signal(signal.SIGKILL)  # the controller reached its planned tick
    c1.proc.wait(timeout=5)
    assert not pf.planned_exit(sup.children["controller_2"], -signal.SIGKILL)  # not in the plan
    assert pf.planned_exit(c1, -signal.SIGKILL) and c1.retired
    sup.children["vehicle_1"].proc.wait(timeout=5)
    # ended with SIGTERM: idle since its controller died, it keeps what it recorded up to the loss
    assert sup.children["vehicle_1"].proc.poll() == -signal.SIGTERM and sup.children["vehicle_1"].retired
    assert pf.lost == {1} and pf.down == {1} and sup.spawned == []
    assert not any(sup.dead(n) for n in sup.children if n not in ("controller_1", "vehicle_1"))
    t = tick_of(2.0, DT) * DT
    assert _events(pf, tmp_path) == [
        ("process_killed", "controller_1", t),
        ("process_killed", "vehicle_1", t),
        ("vehicle_lost", "vehicle_1", t),
    ]


def _all_events(pf, tmp_path) -> list[dict]:
    pf.close()
    return [json.loads(line) for line in (tmp_path / "sup.events").read_text().splitlines()]


def test_each_restart_of_a_process_is_its_next_incarnation_which_must_finish(sup, tmp_path):
    plan = [
        {"controller": 2, "kill": True, "from_s": 1.0, "restart_after_s": 0.5},
        {"controller": 2, "kill": True, "from_s": 3.0, "restart_after_s": 0.5},
    ]
    pf = _faults(sup, tmp_path, plan)
    for t in (1.0, 1.6):
        pf.act(t, 0)
    sup.start("controller_2")  # what the restart started, as the supervisor would have it
    for t in (3.0, 3.6):
        pf.act(t, 0)
    assert [name for name, _argv, _p in sup.spawned] == ["controller_2.1", "controller_2.2"]
    assert sup.must_finish == [True, True]  # a restarted node is a node like the others


def test_an_action_not_due_or_not_the_supervisors_does_not_hold_back_the_next(sup, tmp_path):
    pf = _faults(
        sup,
        tmp_path,
        [{"controller": 2, "freeze_s": 5.0, "from_s": 5.0}, {"controller": 1, "kill": True, "from_s": 1.0}],
    )
    pf.act(1.5, 0)  # the freeze is listed first and not due: the kill still happens
    sup.children["controller_1"].proc.wait(timeout=5)
    assert sup.dead("controller_1") and not pf.frozen("controller_2")
    (tmp_path / "l").mkdir()
    lock = _faults(
        sup,
        tmp_path / "l",
        [{"controller": 3, "kill": True, "from_s": 1.0}, {"controller": 2, "freeze_s": 0.01, "from_s": 2.0}],
        lockstep=True,
    )
    lock.act(0.0, tick_of(2.0, DT))  # the kill is the node's own; the freeze after it is due
    assert lock.frozen("controller_2") and sup.children["controller_3"].proc.poll() is None
    time.sleep(0.05)
    lock.act(0.0, tick_of(2.0, DT))
    lock.close()


def test_every_event_names_its_process_and_source_at_the_run_second_in_milliseconds(sup, tmp_path):
    pf = _faults(
        sup,
        tmp_path,
        [{"controller": 2, "freeze_s": 0.01, "from_s": 2.0}, {"vehicle": 3, "kill": True, "from_s": 2.0}],
    )
    pf.act(2.3456, 0)  # real time: when it happened, not when it was planned
    time.sleep(0.05)
    pf.act(2.4, 0)
    events = _all_events(pf, tmp_path)
    assert {e["source"] for e in events} == {"supervisor"}
    byk = {e["kind"]: e for e in events}
    assert byk["process_frozen"] == {
        "t_s": 2.346,
        "kind": "process_frozen",
        "source": "supervisor",
        "process": "controller_2",
        "freeze_s": 0.01,
    }
    assert (byk["process_thawed"]["process"], byk["process_thawed"]["t_s"]) == ("controller_2", 2.4)
    assert (byk["vehicle_lost"]["process"], byk["vehicle_lost"]["vehicle"]) == ("vehicle_3", 3)


def test_an_exit_the_plan_made_is_planned_and_an_unplanned_sigkill_in_real_time_is_not(sup, tmp_path):
    pf = _faults(sup, tmp_path, [{"controller": 2, "kill": True, "from_s": 5.0}])
    c2 = sup.children["controller_2"]
    assert not pf.planned_exit(c2, -signal.SIGKILL)  # killed by someone else before the plan's time
    c2.retired = True
    assert pf.planned_exit(c2, -signal.SIGKILL) and pf.planned_exit(c2, 1)


def test_acting_on_a_process_that_already_died_is_no_error(sup, tmp_path):
    for name in ("controller_1", "controller_2"):
        sup.children[name].proc.kill()
        sup.children[name].proc.wait()
    pf = _faults(
        sup,
        tmp_path,
        [{"controller": 1, "kill": True, "from_s": 1.0}, {"controller": 2, "freeze_s": 0.01, "from_s": 1.0}],
    )
    pf.act(1.0, 0)  # its process group is gone: nothing to signal
    assert pf.down == {1}
    pf.close()
