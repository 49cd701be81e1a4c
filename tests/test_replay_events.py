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

from swarm_sitl.campaigns.point import failsafe_s
from swarm_sitl.rundir.events import write_events
from swarm_sitl.rundir.load import load_run
from swarm_sitl.rundir.outputs import write_outputs
from swarm_sitl.rundir.requirements import failsafe_signal
from swarm_sitl.running.sim import run_sim
from swarm_sitl.view.frames import FollowerAt, Frame, columns
from swarm_sitl.view.replay import DOWN, FAILSAFE, FRAME_HZ, frame_ticks, replay_document
from tests.strategies import EXAMPLES, FUZZ
from tests.support import config

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


@pytest.mark.integration
@settings(FUZZ, max_examples=min(60, EXAMPLES))  # each reads the run directory whole
@given(events=event_lists())
def test_each_frames_failsafe_state_is_what_the_vehicles_events_say_and_each_event_is_listed(run_dir, events):
    write_events(run_dir / "events.jsonl", events)
    doc = replay_document(run_dir)
    t = doc["frames"]["t_s"]
    for i, f in doc["frames"]["followers"].items():
        flags = [bool(s & FAILSAFE) for s in f["state"]]
        assert flags == [_in_failsafe(events, int(i), x) for x in t], i
        # a spec's failsafe signal reads the same windows (to within its 1e-9 s of a tick's edge)
        assert failsafe_signal(np.array(t), events, int(i)).astype(bool).tolist() == flags
    in_it = 0.0  # a campaign row's time in failsafe: between each of a vehicle's failsafe events
    for v in (1, 2, 3, 4):  # and the next (or the end), where the last one was an enter
        own = [e for e in events if e.get("vehicle") == v and e["kind"].startswith("failsafe_")]
        for e, after in zip(own, [*(x["t_s"] for x in own[1:]), DURATION_S][: len(own)], strict=True):
            in_it += (after - e["t_s"]) if _in_failsafe(events, v, e["t_s"]) else 0.0
    assert failsafe_s(events, DURATION_S) == pytest.approx(in_it, abs=1e-6)
    assert len(doc["events"]) == len(events)
    for line, e in zip(doc["events"], events, strict=True):
        assert line["t_s"] == round(e["t_s"], 3) and line["kind"] == e["kind"]  # (to the millisecond)
        assert line["source"] == e.get("source", "")
        rest = [f"{k} {v}" for k, v in sorted(e.items()) if k not in SKIPPED]  # (written with sorted keys)
        assert (line["text"].split(", ") if line["text"] else []) == rest


@pytest.mark.integration
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
    k = np.rint(t / 0.01).astype(int)  # (the paper's 100 Hz)
    np.testing.assert_allclose(doc["frames"]["leader"], load_run(run_dir).leader["p_r"][k], rtol=0, atol=5e-4)
    assert doc["live"] is False  # (a finished run: its page offers no pause)
    json.dumps(doc, allow_nan=False)  # strict JSON, though a follower's last frames are not recorded


@pytest.mark.unit
@FUZZ
@given(n_ticks=st.integers(1, 5000), period_s=st.sampled_from([0.001, 0.004, 0.01, 0.02, 0.05, 0.1, 0.25]))
def test_the_frames_are_the_first_tick_every_twentieth_of_a_second_and_the_last(n_ticks, period_s):
    ticks = frame_ticks(n_ticks, period_s)
    assert ticks.dtype.kind == "i" and ticks[0] == 0 and ticks[-1] == n_ticks - 1
    gaps = np.diff(ticks)
    assert np.all(gaps > 0)
    stride = max(1, round(1 / (FRAME_HZ * period_s)))  # the ticks nearest a frame's period
    assert np.all(gaps[:-1] == stride) and (len(gaps) == 0 or 1 <= gaps[-1] <= stride)


@pytest.mark.unit
@FUZZ
@given(
    n=st.integers(0, 6),
    ids=st.lists(st.integers(1, 9), unique=True, max_size=3),
    edges=st.lists(st.sampled_from(["0->1", "1->2", "2->1"]), unique=True),
    seed=st.integers(0, 2**16),
)
def test_frames_as_columns_give_each_frame_back_by_its_index(n, ids, edges, seed):
    rng = np.random.default_rng(seed)

    def value() -> float | None:
        return None if rng.random() < 0.2 else float(rng.normal())

    frames = [
        Frame(
            t_s=k * 0.05,
            leader=[value() for _ in range(3)],
            followers={
                str(i): FollowerAt([value() for _ in range(3)], value(), int(rng.integers(0, 4))) for i in ids
            },
            edge_age_s={e: value() for e in edges},
        )
        for k in range(n)
    ]
    c = columns(frames, ids)
    assert set(c["followers"]) == {str(i) for i in ids} and set(c["edge_age_s"]) == (
        set(edges) if n else set()
    )
    for k, fr in enumerate(frames):
        assert c["t_s"][k] == fr.t_s and c["leader"][k] == fr.leader
        for e, age in fr.edge_age_s.items():
            assert c["edge_age_s"][e][k] == age
        for i, f in fr.followers.items():
            assert (c["followers"][i]["p"][k], c["followers"][i]["err"][k]) == (f.p, f.err)
            assert c["followers"][i]["state"][k] == f.state
    assert all(len(col) == n for col in [c["t_s"], c["leader"], *c["edge_age_s"].values()])
