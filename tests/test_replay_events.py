"""A finished run's page document against its events and its records, for any events: a
follower's failsafe state in each frame is what its own events say at that time, each event is
listed as it was written, and a follower whose records end early is down from there on, shown
where it was last.

The rule stated here, on its own: a vehicle is in its failsafe at time ``t`` when the last of its
``failsafe_enter``/``failsafe_exit`` events at or before ``t`` (in the file's order) is an enter;
events of no vehicle (the leader's, the supervisor's) set no follower's state.
"""

import json
import shutil

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from swarm_sitl.rundir.events import write_events
from swarm_sitl.rundir.outputs import write_outputs
from swarm_sitl.running.sim import run_sim
from swarm_sitl.view.replay import DOWN, FAILSAFE, replay_document
from tests.strategies import EXAMPLES, FUZZ
from tests.support import config

pytestmark = pytest.mark.integration

DURATION_S = 2.0
SKIPPED = ("t_s", "kind", "source", "unix_s")  #: an event's fields the page shows apart from its text


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory):
    """``sim`` of the paper's swarm for 2 s, written as ``run`` writes it."""
    cfg = config("paper").model_copy(update={"duration_s": DURATION_S})
    out = tmp_path_factory.mktemp("run") / "run"
    out.mkdir()
    write_outputs(cfg, run_sim(cfg), out)
    return out


@st.composite
def event_lists(draw):
    """Events in time order: failsafe enters and exits of followers, and others of anyone."""
    on_frames = st.sampled_from(np.round(np.arange(0, 2.05, 0.05), 2).tolist())  # a frame's own time
    anywhen = st.floats(0, 2.05).map(lambda x: round(x, 5))
    times = sorted(draw(st.lists(st.one_of(on_frames, anywhen), max_size=14)))
    events = []
    for t in times:
        e = {
            "t_s": t,
            "kind": draw(st.sampled_from(["failsafe_enter", "failsafe_exit", "fault_start", "vehicle_lost"])),
            "unix_s": 1.8e9 + t,
        }
        who = draw(st.sampled_from([1, 2, 3, 4, "leader", None]))
        if who is not None:
            e["vehicle"] = who
        if draw(st.booleans()):
            e["source"] = draw(st.sampled_from(["supervisor", "vehicle_2"]))
        for k in draw(st.lists(st.sampled_from(["mode", "why", "edge"]), unique=True, max_size=2)):
            e[k] = draw(st.sampled_from(["land", 3, "1->4"]))
        events.append(e)
    return events


def _in_failsafe(events, vehicle: int, t: float) -> bool:
    last = None
    for e in events:
        if e.get("vehicle") == vehicle and e["t_s"] <= t and e["kind"] in ("failsafe_enter", "failsafe_exit"):
            last = e["kind"]
    return last == "failsafe_enter"


@settings(FUZZ, max_examples=min(60, EXAMPLES))  # each reads the run directory whole
@given(events=event_lists())
def test_each_frames_failsafe_state_is_what_the_vehicles_events_say_and_each_event_is_listed(run_dir, events):
    write_events(run_dir / "events.jsonl", events)
    doc = replay_document(run_dir)
    t = doc["frames"]["t_s"]
    for i, f in doc["frames"]["followers"].items():
        flags = [bool(s & FAILSAFE) for s in f["state"]]
        assert flags == [_in_failsafe(events, int(i), x) for x in t], i
    assert len(doc["events"]) == len(events)
    for line, e in zip(doc["events"], events, strict=True):
        assert line["t_s"] == round(e["t_s"], 3) and line["kind"] == e["kind"]  # (to the millisecond)
        assert line["source"] == e.get("source", "")
        rest = [f"{k} {v}" for k, v in sorted(e.items()) if k not in SKIPPED]  # (written with sorted keys)
        assert (line["text"].split(", ") if line["text"] else []) == rest


def test_a_follower_whose_records_end_early_is_down_from_there_where_it_was_last(run_dir, tmp_path):
    d = tmp_path / "run"
    shutil.copytree(run_dir, d)
    (d / "events.jsonl").unlink(missing_ok=True)
    a = dict(np.load(d / "follower_2.npz"))
    n = len(a["t_s"]) // 3  # its vehicle lost at a third of the run
    np.savez(
        d / "follower_2.npz",
        **{k: (v[:n] if v.ndim and len(v) == len(a["t_s"]) else v) for k, v in a.items()},
    )
    doc = replay_document(d)
    t = np.array(doc["frames"]["t_s"])
    f = doc["frames"]["followers"]["2"]
    down = np.array([bool(s & DOWN) for s in f["state"]])
    assert np.array_equal(down, t > a["t_s"][n - 1] + 1e-9)
    p = np.array(f["p"], dtype=float)
    np.testing.assert_allclose(p[down], np.repeat(a["p_W"][n - 1 : n], down.sum(), axis=0), atol=5e-4)
    for j, other in doc["frames"]["followers"].items():
        assert j == "2" or not any(s & DOWN for s in other["state"])
    json.dumps(doc, allow_nan=False)  # strict JSON, though a follower's last frames are not recorded
