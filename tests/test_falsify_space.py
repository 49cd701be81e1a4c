"""What ``falsify`` may do to a swarm (``falsify.space``), over spaces drawn at random: every point a
sampler picks is a fault plan the runs take, each entry within its space entry's ranges and
window, made by that entry and by no other kind; an entry over every edge expands to the entries a
sweep writes; its cost is severity times duration summed, or the edges, links and controllers it
touches; and each malformed space entry is one line naming what is wrong."""

import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from pydantic import ValidationError

from swarm_sitl.falsify.space import (
    Space,
    SpaceEntry,
    cost,
    default_space,
    entries_relative_to,
    expand,
    flown_plan,
    items,
    plan_of,
)
from swarm_sitl.faults.plan import FaultPlan
from tests.support import FixedTrial, config

pytestmark = pytest.mark.unit

CFG = config("paper")  # 60 s, followers 1-4, edges 0->1, 0->2, 0->3, 1->4, 2->4
EDGES = [tuple(int(x) for x in e) for e in CFG.graph_edges()]


def _range(lo: float, hi: float) -> st.SearchStrategy:
    return st.tuples(st.floats(lo, hi), st.floats(lo, hi)).filter(lambda r: r[0] < r[1])


#: a probability's range a space takes (its high end above the least p searched, ``P_LOW``)
_P = st.tuples(st.floats(0.0, 1.0), st.floats(2e-6, 1.0)).filter(lambda r: r[0] < r[1])


def _subset(xs: list) -> st.SearchStrategy:
    return st.lists(st.sampled_from(xs), min_size=1, max_size=len(xs), unique=True)


@st.composite
def _entries(draw) -> dict:
    what = draw(st.sampled_from(["edges", "links", "controllers"]))
    e: dict = {}
    if what == "edges":
        e["edges"] = draw(
            st.one_of(st.sampled_from(["all", "each"]), _subset(EDGES).map(lambda x: [list(y) for y in x]))
        )
        how = draw(st.sampled_from(["loss", "delay_s", "drop", "corrupt", "bursty"]))
        if how == "loss":
            e["loss"] = list(draw(_P))
        elif how == "delay_s":
            e["delay_s"] = list(draw(_range(0.0, 2.0).filter(lambda r: r[1] > 1e-8)))
        elif how == "drop":
            e["drop"] = True
        elif how == "corrupt":
            e["corrupt"] = list(draw(_P))
        else:
            e["bursty"] = {"p": list(draw(_range(1e-3, 1.0))), "r": draw(st.floats(0.01, 1.0))}  # (p > 0)
    elif what == "links":
        e["links"] = draw(st.one_of(st.just("each"), _subset([1, 2, 3, 4])))
        e["direction"] = draw(st.sampled_from(["up", "down", "both"]))
        e.update(draw(st.sampled_from([{"drop": True}, {"loss": [0.0, 1.0]}, {"loss": [0.2, 0.6]}])))
    else:
        e["controllers"] = draw(st.one_of(st.just("each"), _subset([1, 2, 3, 4])))
        e["kill"] = True
        e["restart_after_s"] = list(draw(_range(0.1, 10.0)))
    if draw(st.booleans()):
        e["window_s"] = list(draw(_range(0.0, CFG.duration_s).filter(lambda r: r[1] - r[0] > 0.05)))
        if draw(st.booleans()):
            e["max_duration_s"] = draw(st.floats(0.01, 20.0))
    elif what == "edges" and e.get("drop") and draw(st.booleans()):
        e["max_duration_s"] = draw(st.floats(0.01, 60.0))
    return e


class _Drawn:
    """A sampler drawing each suggestion at random within its bounds, and keeping their names."""

    def __init__(self, draw):
        self.draw, self.names = draw, []

    def suggest_float(self, name: str, low: float, high: float) -> float:
        self.names.append(name)
        assert low <= high, (name, low, high)
        return self.draw(st.floats(low, high))

    def suggest_categorical(self, name: str, choices):
        self.names.append(name)
        return self.draw(st.sampled_from(list(choices)))


def _kind(f: dict) -> str:
    return "links" if "mavlink" in f else ("controllers" if "controller" in f else "edges")


def _within(e: SpaceEntry, f: dict) -> bool:
    """Whether plan entry ``f`` lies within space entry ``e``: each searched value in its range
    (a probability from ``P_LOW``), its window in ``e``'s (at most ``max_duration_s`` long, at
    least a period), a kill at an instant of it (of the run's first half without one)."""
    dt = CFG.control_dt_s
    for path, (mild, severe) in e.searched(f):
        v = f
        for part in path:
            v = v[part]
        if not min(mild, severe) <= v <= max(mild, severe):
            return False
    if "mavlink" in f and f["direction"] != e.direction:
        return False
    if f.get("kill"):
        a, b = e.window_s or (0.0, CFG.duration_s / 2)
        return "until_s" not in f and a <= f["from_s"] <= b
    if e.window_s is not None:
        a, b = e.window_s
        longest = min(b - a, e.max_duration_s or math.inf)
        return (
            "from_s" in f
            and "until_s" in f
            and a <= f["from_s"] <= b - dt + 1e-12
            and f["from_s"] < f["until_s"] <= b
            and f["until_s"] - f["from_s"] <= max(longest, 2 * dt) + 1e-9
        )
    if e.max_duration_s is not None:
        # (a plan entry another space entry made may have no end: not within this one)
        return "from_s" not in f and f.get("until_s") == min(CFG.duration_s, e.max_duration_s)
    return "from_s" not in f and "until_s" not in f


@settings(max_examples=100, deadline=None)
@given(
    st.lists(_entries(), min_size=1, max_size=4),
    st.lists(st.integers(0, 9), min_size=1, max_size=3, unique=True),
    st.data(),
)
def test_every_point_of_a_space_is_a_plan_within_its_entries(entries, seeds, data):
    space = Space.model_validate({"seeds": seeds, "entries": entries})
    space.check_against(CFG)
    its = items(space, CFG)
    trial = _Drawn(data.draw)
    plan = plan_of(trial, space, its, CFG)
    assert len(set(trial.names)) == len(trial.names)  # each suggestion named once, as Optuna needs
    assert ("seed" in trial.names) == (len(seeds) > 1) and plan["seed"] in seeds
    assert any(n.endswith(".on") for n in trial.names) == (len(its) > 1)
    assert len(plan["plan"]) <= len(its) and (len(its) > 1 or len(plan["plan"]) == 1)
    fault_plan = expand(plan, CFG)
    FaultPlan.model_validate(fault_plan)  # what the runs take
    for f in plan["plan"]:
        makers = [e for e in space.entries if e.makes(f)]
        assert makers, f
        assert all(e.what == _kind(f) for e in makers)
        assert any(_within(e, f) for e in makers), (f, makers)
    n_all = sum(1 for f in plan["plan"] if f.get("edges") == "all")
    assert len(fault_plan["plan"]) == len(plan["plan"]) + n_all * (CFG.n_followers - 1)
    assert [f["into"] for f in fault_plan["plan"] if "into" in f] == [x.id for x in CFG.followers] * n_all


@settings(max_examples=100, deadline=None)
@given(
    st.lists(
        st.one_of(
            st.builds(
                lambda e, p: {"edge": list(e), "loss": p}, st.sampled_from(EDGES), st.floats(0.01, 1.0)
            ),
            st.builds(lambda i, d: {"into": i, "delay_s": d}, st.integers(1, 4), st.floats(0.0, 2.0)),
            st.builds(lambda e: {"edge": list(e), "drop": True}, st.sampled_from(EDGES)),
            st.builds(lambda i: {"mavlink": i, "drop": True}, st.integers(1, 4)),
            st.builds(
                lambda i, at, down: {"controller": i, "kill": True, "from_s": at, "restart_after_s": down},
                st.integers(1, 4),
                st.floats(0.0, 39.0),
                st.floats(0.1, 60.0),
            ),
        ).flatmap(
            lambda f: st.one_of(
                st.just(f),
                st.tuples(st.floats(0.0, 30.0), st.floats(0.01, 20.0)).map(
                    lambda w, f=f: f if f.get("kill") else {**f, "from_s": w[0], "until_s": w[0] + w[1]}
                ),
            )
        ),
        min_size=1,
        max_size=6,
    )
)
def test_a_plans_cost_is_its_severities_times_durations_or_what_it_touches(entries):
    """Severity: loss p, a cut 1, a delay d / staleness (at most 1), each for its window (to the
    run's end at most); a controller down 1 for its downtime, to the run's end at most. Edges: the
    graph edges its entries act on (``into: i``: every edge into i), its links and controllers,
    each once."""
    plan = {"seed": 0, "plan": entries}
    run = CFG.duration_s
    want, touched, others = 0.0, set(), set()
    into = {d: {(s, dd) for s, dd in EDGES if dd == d} for d in range(1, 5)}
    for f in entries:
        if f.get("kill"):
            want += min(f["restart_after_s"], run - f["from_s"])
            others.add(("controller", f["controller"]))
            continue
        dur = min(f.get("until_s", run), run) - f.get("from_s", 0.0)
        if "mavlink" in f:
            others.add(("mavlink", f["mavlink"]))
            want += dur
        elif "delay_s" in f:
            want += min(1.0, f["delay_s"] / CFG.estimator.staleness_s) * dur
            touched |= into[f["into"]]
        else:
            want += f.get("loss", 1.0) * dur
            touched.add(tuple(f["edge"]))
    assert cost(plan, CFG) == pytest.approx(want, rel=1e-9, abs=1e-9)
    assert cost(plan, CFG, "edges") == len(touched) + len(others)


@pytest.mark.parametrize(
    ("entry", "says"),
    [
        ({"edges": "each"}, "needs exactly one of loss, delay_s, drop, kill, or a link model (got none)"),
        ({"loss": [0, 1]}, "needs exactly one of edges, links, controllers (got none)"),
        (
            {"edges": "each", "links": "each", "drop": True},
            "needs exactly one of edges, links, controllers (got edges, links)",
        ),
        ({"edges": "each", "loss": [0, 1], "drop": True}, "(got loss, drop)"),
        ({"edges": "each", "loss": [0, 1], "corrupt": [0, 1]}, "(got loss, corrupt)"),
        ({"links": "each", "delay_s": [0, 1]}, "links fail by loss or drop, not delay_s"),
        ({"links": "each", "corrupt": [0, 1]}, "links fail by loss or drop, not corrupt"),
        ({"controllers": "each", "drop": True}, "controllers fail by kill, not drop"),
        (
            {"controllers": "each", "kill": True},
            "kill: give restart_after_s: [low, high] (how long it stays down)",
        ),
        ({"edges": "each", "loss": [0.5, 0.5]}, "loss: an empty range [0.5, 0.5] (needs low < high)"),
        (
            {"edges": "each", "drop": True, "window_s": [3, 1]},
            "window_s: an empty range [3, 1] (needs low < high)",
        ),
        ({"edges": "each", "loss": [0.5, 1.5]}, "loss: [0.5, 1.5] is not within [0, 1]"),
        ({"edges": "each", "loss": [-0.5, 0.5]}, "loss: [-0.5, 0.5] is not within [0, 1]"),
        ({"edges": "each", "delay_s": [-1, 1]}, "delay_s: a delay is at least 0 s"),
        (
            {"edges": "each", "loss": [0, 1e-9]},
            "loss: [0, 1e-09] ends at or below 1e-06, the least p searched",
        ),
        (
            {"edges": "each", "corrupt": [0, 1e-6]},
            "corrupt.p: [0, 1e-06] ends at or below 1e-06, the least p searched",
        ),
        (
            {"edges": "each", "delay_s": [0, 1e-10]},
            "delay_s: [0, 1e-10] ends at or below 1e-09 s, the least delay searched",
        ),
        ({"controllers": "each", "kill": True, "restart_after_s": [0, 1]}, "restart_after_s: more than 0 s"),
        ({"edges": "each", "drop": True, "window_s": [-1, 1]}, "window_s: starts at 0 s or later"),
        (
            {"edges": "each", "bursty": {"r": 0.5}},
            "bursty: give at least one parameter a range [lo, hi] to search",
        ),
        (
            {"edges": "each", "bursty": {"q": [0, 1]}},
            "bursty: no parameter 'q' (it has p, r, loss_bad, loss_good)",
        ),
        (
            {"edges": "each", "bursty": {"p": [0.5, 0.2]}},
            "bursty.p: an empty range [0.5, 0.2] (needs low < high)",
        ),
        ({"edges": "each", "corrupt": [0, 2]}, "corrupt.p: 2 is out of its range"),
        ({"edges": "each", "range": {"range_m": [1, 100]}}, "range: its effect is not a message's own fate"),
        (
            {"edges": "each", "bandwidth": {"rate_bps": [1, 100]}},
            "bandwidth: its effect is not a message's own fate",
        ),
        ({"edges": "each", "stall": {"until_s": [1, 2]}}, "stall: not searched by a space"),
        (
            {"edges": "each", "model": "x.py:M"},
            "model: {entry: 'my_link.py:Name', params: {PARAM: [lo, hi] or a value}}",
        ),
    ],
)
def test_a_malformed_space_entry_is_one_line_saying_what_is_wrong(entry, says):
    with pytest.raises(ValidationError) as e:
        SpaceEntry.model_validate(entry)
    msg = e.value.errors()[0]["msg"]
    assert says in msg and "\n" not in msg, msg


@pytest.mark.parametrize(
    ("space", "says"),
    [
        (
            {"entries": [{"edges": [[0, 4]], "loss": [0, 1]}]},
            "entries.0: edge [0, 4] is not an edge of the graph",
        ),
        (
            {
                "entries": [
                    {"edges": "each", "drop": True},
                    {"edges": "each", "drop": True, "window_s": [1, 61]},
                ]
            },
            "entries.1: window_s ends at 61 s, after the run (60 s)",
        ),
        ({"entries": [{"links": [5], "drop": True}]}, "entries.0: no follower 5 (followers 1..4)"),
        (
            {
                "entries": [
                    {"edges": "each", "drop": True},
                    {"controllers": [2, 7], "kill": True, "restart_after_s": [1, 2]},
                ]
            },
            "entries.1: no follower 7 (followers 1..4)",
        ),
        ({"seeds": [], "entries": [{"edges": "each", "drop": True}]}, "seeds: at least one"),
    ],
)
def test_a_space_that_does_not_fit_the_swarm_is_one_line_naming_the_entry(space, says):
    with pytest.raises(ValueError) as e:
        Space.model_validate(space).check_against(CFG)
    assert str(e.value) == says


#: what each own how searches in a plan entry (the rest: a registry model's key, its p or params)
_SEARCHED_AT = {"loss": ("loss",), "delay_s": ("delay_s",), "kill": ("restart_after_s",), "drop": None}


@settings(max_examples=100, deadline=None)
@given(_entries(), st.data())
def test_what_shrinking_may_lower_is_each_searched_value_its_range_mild_end_first(entry, data):
    """``searched``: the place of each searched value in a plan entry and its range, the end at
    which the plan costs less first: a loss, a delay, a downtime, a model's p or its searched
    parameters; nothing for a cut."""
    space = Space.model_validate({"entries": [entry]})
    e = space.entries[0]
    f = plan_of(_Drawn(data.draw), space, items(space, CFG)[:1], CFG)["plan"][0]
    got = e.searched(f)
    if e.how in _SEARCHED_AT:
        want = _SEARCHED_AT[e.how]
        rng = {"loss": e.loss, "delay_s": e.delay_s, "kill": e.restart_after_s}.get(e.how)
        assert got == ([] if want is None else [(want, tuple(rng))])
    elif e.how == "corrupt":
        assert got == [(("corrupt",), tuple(entry["corrupt"]))]
    else:
        assert [p for p, _ in got] == [("bursty", "p")]
        assert set(got[0][1]) == set(entry["bursty"]["p"])
    for path, (mild, severe) in got:  # (the plan at the mild end costs no more than at the severe)
        at_end = []
        for v in (mild + (severe - mild) * 1e-3, severe):  # (just inside: a plan's p and delay are > 0)
            g = {**f, path[0]: {**f[path[0]], path[1]: v}} if len(path) == 2 else {**f, path[0]: v}
            at_end.append(cost(expand({"seed": 0, "plan": [g]}, CFG), CFG))
        assert at_end[0] <= at_end[1] + 1e-12, (path, mild, severe, at_end)


def test_the_default_space_is_loss_cuts_and_delays_on_every_edge():
    d = default_space(CFG)
    assert d.seeds == [0] and [e.how for e in d.entries] == ["loss", "drop", "delay_s"]
    assert all(e.edges == "each" for e in d.entries)
    assert d.entries[0].loss == (0.0, 1.0)
    assert (
        d.entries[1].window_s == (0.0, CFG.duration_s) and d.entries[1].max_duration_s == CFG.duration_s / 4
    )
    assert d.entries[2].delay_s == (0.0, CFG.estimator.staleness_s * 1.2)
    d.check_against(CFG)


def test_a_plan_flies_under_the_configs_own_faults_first_its_defaults_left_out():
    base = [{"edge": [0, 1], "loss": 0.25, "from_s": 3.0}, {"controller": 2, "kill": True, "from_s": 9.0}]
    cfg = CFG.model_copy(update={"faults": FaultPlan.model_validate({"seed": 7, "plan": base})})
    plan = {"seed": 4, "plan": [{"edges": "all", "drop": True, "from_s": 1.0, "until_s": 2.0}]}
    got = flown_plan(plan, cfg)
    assert got["seed"] == 4
    assert got["plan"][:2] == base  # (each field given, none of a FaultEntry's defaults)
    assert got["plan"][2:] == expand(plan, cfg)["plan"]
    assert flown_plan(plan, CFG)["plan"] == expand(plan, CFG)["plan"]  # no faults of its own


#: a user's link model: a share ``p`` of the messages lost, or (``invert``) all but that share
USER_LINK = """
from pydantic import BaseModel, Field

from swarm_sitl.faults.link_model import Effect


class Lossy:
    class Params(BaseModel):
        p: float = Field(ge=0, le=1)
        invert: bool = False

    def fate(self, p, m):
        return Effect(lost=True) if ((m.step % 100) < 100 * p.p) != p.invert else None
"""


def test_a_users_link_model_is_searched_by_its_file_wherever_the_space_file_names_it(tmp_path):
    """A space names a user's model by its file, relative to the space file: the entry is made
    absolute, the space ships that file once, each point writes ``model: {entry, params}`` with the
    searched parameter in range and the held one as given, shrinking finds it under
    ``model.params`` with its mild end first as the held parameter makes it (``invert``: a larger
    p loses less), its cost is the share it loses over the run, and only an entry of that file is
    the space entry's."""
    (tmp_path / "links").mkdir()
    (tmp_path / "links" / "lossy.py").write_text(USER_LINK)
    entry = {
        "edges": "each",
        "model": {"entry": "links/lossy.py:Lossy", "params": {"p": [0.1, 0.4], "invert": True}},
    }
    data = {"entries": [entry, {**entry, "edges": [[0, 1]]}, {"edges": "all", "loss": [0, 1]}]}
    absolute = entries_relative_to(data, tmp_path)
    file_entry = f"{tmp_path / 'links' / 'lossy.py'}:Lossy"
    assert [e.get("model", {}).get("entry") for e in absolute["entries"]] == [file_entry, file_entry, None]
    assert absolute["entries"][2] == data["entries"][2]
    for other in ([1, 2], {"x": 1}, {"entries": ["x", {"model": "y"}]}):  # (refused later, as they are)
        assert entries_relative_to(other, tmp_path) == other
    space = Space.model_validate(absolute)
    assert space.user_models() == [file_entry]
    e = space.entries[0]
    f = plan_of(FixedTrial({"p": 0.3}), space, items(space, CFG)[:1], CFG)["plan"][0]
    assert f == {"edge": [0, 1], "model": {"entry": file_entry, "params": {"invert": True, "p": 0.3}}}
    assert e.searched(f) == [(("model", "params", "p"), (0.4, 0.1))]
    assert cost(expand({"seed": 0, "plan": [f]}, CFG), CFG) == pytest.approx(0.7 * CFG.duration_s, rel=0.05)
    assert e.makes(f) and not space.entries[2].makes(f)
    other = {**f, "model": {**f["model"], "entry": f"{tmp_path}/other.py:Lossy"}}
    assert not e.makes(other)
    assert e.link_model is not None and e.link_model.params_at({}).p == pytest.approx(0.25)  # the middle
