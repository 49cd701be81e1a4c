"""The rules of a campaign that no lockstep run is needed to check, each one a plausible bug away:
the direction every harsher-when-smaller key is read in, a swept jitter that flies a fault, a list
index past the list's end, the campaign a directory holds, when a run recovered and how long a
failsafe lasted, a point that outlasts its wall budget, and a range's values up to its limit."""

import math
import re
import sys
import time

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from swarm_sitl.campaigns.breaking import breaking_point, harsher_smaller, toward
from swarm_sitl.campaigns.grid import (
    MAX_POINTS,
    SweepSpecError,
    check_key,
    grid,
    link_model_key,
    parse_values,
    point_data,
)
from swarm_sitl.campaigns.point import failsafe_s, recovered_after, run_point
from swarm_sitl.campaigns.sweep import _open_campaign
from swarm_sitl.config.load import parse_config
from tests.support import BLACKOUT_MODEL, config

pytestmark = pytest.mark.unit


#: the swept keys whose smaller values are the harsher: a radio's range, rate and queue, a bursty
#: link's way back to good
SMALLER_IS_HARSHER = [
    "link.range.range_m",
    "link.bandwidth.rate_bps",
    "link.bandwidth.queue",
    "link.bursty.r",
]


@pytest.mark.parametrize("key", SMALLER_IS_HARSHER)
def test_each_key_harsher_when_smaller_is_read_from_its_largest_value_down(key):
    """Held at the large values, broken below: the break is where it shrank too far."""
    assert harsher_smaller(key)
    rows = [{key: v, "passed": int(v >= 0.4)} for v in (0.1, 0.2, 0.4, 0.8) for _ in range(2)]
    assert breaking_point(rows, key) == (0.4, 0.2) and toward(key) == "down to"
    rows[-1]["passed"] = 0  # the gentlest value broke: nothing held
    assert breaking_point(rows, key) == (None, 0.8)


def test_a_key_harsher_when_larger_is_read_from_its_smallest_value_up():
    rows = [{"link.bursty.p": v, "passed": int(v <= 0.2)} for v in (0.1, 0.2, 0.4)]
    assert breaking_point(rows, "link.bursty.p") == (0.2, 0.4) and toward("link.bursty.p") == "up to"


def test_a_jitter_swept_alone_flies_a_delay_with_that_jitter_on_every_edge_into_a_follower(paper_cfg):
    base = paper_cfg.data()
    ids = [f.id for f in paper_cfg.followers]
    data = point_data(base, {"link.jitter_s": 0.02}, 0)
    entries = data["faults"]["plan"]
    assert [e["into"] for e in entries] == ids
    assert all(e["jitter_s"] == 0.02 and 0 < e["delay_s"] < 1e-6 for e in entries)
    cfg = parse_config(data, "sweep")
    assert all(f.jitter_s == 0.02 for f in cfg.faults.plan)
    assert point_data(base, {"link.jitter_s": 0.0}, 0)["faults"]["plan"] == []  # none: no fault


def test_a_list_index_at_or_past_the_lists_end_is_one_line(paper_cfg):
    base = paper_cfg.data()
    n = len(base["followers"])
    for index in (n, n + 3):
        with pytest.raises(SweepSpecError, match=rf"no item {index} \(the list has {n}\)"):
            point_data(base, {f"followers.{index}.offset_m.0": 1.0}, 0)
    assert (
        point_data(base, {f"followers.{n - 1}.offset_m.0": 1.0}, 0)["followers"][n - 1]["offset_m"][0] == 1.0
    )


def test_a_directory_holds_one_campaign_its_base_and_its_keys_both(tmp_path):
    spec = {"base_sha256": "a" * 64, "keys": ["link.loss"], "values": {"link.loss": [0.1]}, "seeds": [0]}
    _open_campaign(tmp_path, spec)
    _open_campaign(tmp_path, {**spec, "values": {"link.loss": [0.2]}, "seeds": [1]})  # grown: the same
    for other in ({**spec, "base_sha256": "b" * 64}, {**spec, "keys": ["link.delay_s"]}):
        with pytest.raises(SweepSpecError, match="holds another campaign"):
            _open_campaign(tmp_path, other)


def test_a_run_recovered_at_the_first_sample_from_which_it_stays_in_the_bound():
    """Out of the bound until t = 3.0 s (inclusive), in from 3.1 s on: recovered 3.1 - 2.0 s after
    the plan's last window; out again at the end: never; never out: at once."""
    t = np.round(np.arange(0, 5.0001, 0.1), 10)
    err = np.where(t <= 3.0, 1.0, 0.01)
    assert recovered_after(t, err, 0.05, 2.0) == pytest.approx(1.1, abs=1e-12)
    err[-1] = 1.0
    assert math.isnan(recovered_after(t, err, 0.05, 2.0))
    assert recovered_after(t, np.full_like(t, 0.01), 0.05, 2.0) == 0.0


def test_a_failsafe_still_on_at_the_end_counts_to_the_end():
    events = [
        {"t_s": 1.0, "kind": "failsafe_enter", "vehicle": 1},
        {"t_s": 1.5, "kind": "failsafe_exit", "vehicle": 1},
        {"t_s": 4.0, "kind": "failsafe_enter", "vehicle": 2},
        {"t_s": 4.5, "kind": "failsafe_enter", "vehicle": 2},  # (said twice: counted from the first)
    ]
    assert failsafe_s(events, 10.0) == pytest.approx(0.5 + 6.0)
    assert failsafe_s(events[:2], 10.0) == pytest.approx(0.5)


def test_a_point_past_its_wall_budget_is_a_failed_row_timed_out_and_nothing_is_left(tmp_path, monkeypatch):
    """``swarm-sitl run`` stood in for by a process that never ends: the row fails ``timed out``
    within the budget and the grace of an interrupt, and the process is gone."""
    import swarm_sitl.campaigns.point as point

    monkeypatch.setattr(point, "run_command", lambda cfg, run_dir: [sys.executable, "-c", "while True: pass"])
    t0 = time.monotonic()
    row = run_point("name: x\n", "hangs", None, None, 1.0)
    wall = time.monotonic() - t0
    assert row["passed"] == 0 and row["failure"] == "timed out after 1 s (the point's wall budget)"
    assert 1.0 <= wall < 1.0 + point.INTERRUPT_GRACE_S + 2.0
    assert not point.RUNNING


def test_a_requirement_is_a_column_and_a_run_passes_only_if_every_one_holds():
    from swarm_sitl.campaigns.sweep import judge
    from swarm_sitl.campaigns.table import columns

    assert columns(["link.loss"], ["apart", "tight"])[-3:] == ["spec.apart", "spec.tight", "config"]
    rows = [
        {"failure": "", "max_error_m": 0.01, "spec.apart": 2.0, "spec.tight": 1e-4},
        {"failure": "", "max_error_m": 0.01, "spec.apart": 2.0, "spec.tight": -1e-4},
        {"failure": "", "max_error_m": 0.01, "spec.apart": math.nan, "spec.tight": 1e-4},
        {"failure": "", "max_error_m": 0.01, "spec.apart": 0.0, "spec.tight": 0.0},  # at the edge: holds
        {"failure": "", "max_error_m": 0.5, "spec.apart": 2.0, "spec.tight": 1e-4},
    ]
    judge(rows, 0.05)
    assert [r["passed"] for r in rows] == [1, 0, 0, 1, 0]


@settings(max_examples=30, deadline=None)  # (half of them build lists of about MAX_POINTS)
@given(
    start=st.integers(-2000, 2000),
    step=st.integers(1, 64),
    n=st.one_of(st.integers(1, 40), st.sampled_from([MAX_POINTS - 1, MAX_POINTS, MAX_POINTS + 1])),
    short=st.integers(0, 7),
)
def test_a_range_is_every_step_from_its_start_to_its_stop_and_at_most_max_points_of_them(
    start, step, n, short
):
    """``START:STOP:STEP`` (in eighths: exact in binary, so the count is the arithmetic's) is
    ``START + k STEP`` for each k whose value is at most STOP, a stop short of the next step
    included (one value when STOP is START); more than ``MAX_POINTS`` values is one line naming the
    key and the count."""
    a, d = start / 8, step / 8
    stop = a + (n - 1) * d + short / 8 * d  # (short < 8: short of the next value)
    text = f"{a!r}:{stop!r}:{d!r}"
    if n > MAX_POINTS:
        with pytest.raises(SweepSpecError, match=rf"^sweep k\.x: '{re.escape(text)}' has {n} values, more "):
            parse_values("k.x", text)
        return
    got = parse_values("k.x", text)
    assert len(got) == n and got[0] == a and got[-1] <= stop
    assert np.array_equal(np.diff(got), np.full(n - 1, d))


_LEVEL = st.sampled_from([0.0, 0.25, 0.5])  #: a swept value, 0 among them (no entry)


@settings(max_examples=40, deadline=None)
@given(
    link=st.fixed_dictionaries({h: _LEVEL for h in ("loss", "corrupt", "duplicate", "reorder")}),
    mavlink=st.fixed_dictionaries({h: _LEVEL for h in ("loss", "corrupt")}),
    bursty_p=st.sampled_from([None, 0.0, 0.05]),
    range_m=st.sampled_from([None, 30.0]),
    dark=st.sampled_from([None, 0.4]),
    shipped=st.booleans(),
    kept=st.lists(st.sampled_from([{"into": 2, "loss": 0.1}, {"mavlink": 3, "corrupt": 0.2}]), max_size=2),
)
def test_a_points_plan_is_the_bases_then_one_entry_per_follower_or_edge_for_each_swept_fault(
    tmp_path_factory, link, mavlink, bursty_p, range_m, dark, shipped, kept
):
    """``point_data``: the base config's own plan entries first, unchanged; then for each of
    ``link.{loss,corrupt,duplicate,reorder}`` swept above 0 an entry into every follower; each
    link model swept (a bursty link with ``p`` 0 puts none, and the models after it still do),
    one entry on every edge, a user's model by its entry (the copy shipped beside the run, else
    its file from where the campaign runs); then each ``mavlink.*`` above 0 on every follower's
    MAVLink link."""
    where = tmp_path_factory.mktemp("campaign")
    (where / "blackout.py").write_text(BLACKOUT_MODEL)
    base = _base_with_plan(kept)
    ids = [f["id"] for f in base["followers"]]
    point: dict[str, float] = {f"link.{h}": v for h, v in link.items()}
    want = [*kept]
    want += [
        {"into": i, h: link[h]} for h in ("loss", "corrupt", "duplicate", "reorder") if link[h] for i in ids
    ]
    if bursty_p is not None:
        point |= {"link.bursty.p": bursty_p, "link.bursty.r": 0.3}
        want += [{"all_edges": True, "bursty": {"p": bursty_p, "r": 0.3}}] if bursty_p else []
    if range_m is not None:
        point["link.range.range_m"] = range_m
        want.append({"all_edges": True, "range": {"range_m": range_m}})
    if dark is not None:
        point[f"link.{where / 'blackout.py'}:Blackout.dark"] = dark
        entry = "plugins/blackout.py:Blackout" if shipped else f"{(where / 'blackout.py').resolve()}:Blackout"
        want.append({"all_edges": True, "model": {"entry": entry, "params": {"dark": dark}}})
    point |= {f"mavlink.{h}": v for h, v in mavlink.items()}
    want += [{"mavlink": i, h: mavlink[h]} for h in ("loss", "corrupt") if mavlink[h] for i in ids]
    ships = {f"{where / 'blackout.py'}:Blackout": "plugins/blackout.py:Blackout"} if shipped else None
    data = point_data(base, point, 11, ships)
    assert data["faults"]["plan"] == want and data["seed"] == 11
    assert base["faults"]["plan"] == kept  # the base is not changed


def _base_with_plan(kept: list[dict]) -> dict:
    """The paper config's data with ``kept`` as its own fault plan."""
    data = config("paper").data()
    data.setdefault("faults", {})["plan"] = [dict(e) for e in kept]
    return data


@pytest.mark.parametrize(
    ("key", "says"),
    [
        (
            "mavlink.reorder",
            r"sweep mavlink\.reorder: mavlink\.\* is one of mavlink\.loss, mavlink\.corrupt$",
        ),
        (
            "mavlink.delay_s",
            r"sweep mavlink\.delay_s: mavlink\.\* is one of mavlink\.loss, mavlink\.corrupt$",
        ),
        ("link.loss.extra", r"sweep link\.loss\.extra: link\.MODEL\.PARAM is a model of bursty, range, "),
        ("link.lost", r"sweep link\.lost: link\.\* is one of link\.loss, "),
        ("mavlink.loss.x", r"sweep mavlink\.loss\.x: mavlink\.\* is one of mavlink\.loss, mavlink\.corrupt$"),
    ],
)
def test_a_shorthand_key_of_no_fault_a_run_can_fly_is_one_line_naming_those_it_can(key, says):
    """``mavlink.*`` takes the MAVLink faults a lockstep run flies (``loss``, ``corrupt``: a
    duplicate or a delay of a setpoint would not be one tick's), ``link.*`` the link's; any other
    is refused naming what may be swept."""
    with pytest.raises(SweepSpecError, match=says):
        check_key(key)


def test_a_grid_is_every_combination_up_to_max_points_and_one_more_is_one_line():
    """``grid``: the product of the swept values, the first key slowest, up to ``MAX_POINTS``
    points (100 x 1000 of them taken), one more refused naming the count."""
    a, b = [float(i) for i in range(100)], [float(j) for j in range(MAX_POINTS // 100)]
    points = grid([("a", a), ("b", b)])
    assert (
        len(points) == MAX_POINTS and points[0] == {"a": 0.0, "b": 0.0} and points[1] == {"a": 0.0, "b": 1.0}
    )
    assert points[-1] == {"a": 99.0, "b": b[-1]}
    with pytest.raises(SweepSpecError, match=rf"^sweep: {MAX_POINTS + 100} points, more than {MAX_POINTS}$"):
        grid([("a", a), ("b", [*b, -1.0])])


_name = st.from_regex(r"[a-z_][a-z0-9_]{0,8}", fullmatch=True)


@settings(max_examples=60)
@given(
    folders=st.lists(_name, max_size=2), stem=_name, cls=st.lists(_name, min_size=1, max_size=2), param=_name
)
def test_a_users_link_model_key_is_its_entry_then_the_parameter_after_the_class_names_last_dot(
    folders, stem, cls, param
):
    """``link.FILE.py:CLASS.PARAM`` (a file in folders, a nested class): the entry and the
    parameter; without a parameter, the entry alone (its file's dot is no parameter's); a built-in
    model's key splits at its first dot; any other key is not a link model's."""
    entry = "/".join([*folders, f"{stem}.py"]) + ":" + ".".join(cls)
    if len(cls) == 1:  # (a nested class without a parameter reads as its outer class's)
        assert link_model_key(f"link.{entry}") == (entry, "")
    assert link_model_key(f"link.{entry}.{param}") == (entry, param)
    assert link_model_key(f"link.{stem}.{param}") == (stem, param)
    assert link_model_key(f"link.{stem}") is None and link_model_key(f"gains.{stem}.{param}") is None
