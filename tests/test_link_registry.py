"""The link-model registry (``faults.link_models``) is the one source every consumer reads: the
plan (its hows, which act on a vehicle's MAVLink link and in lockstep, which is a node's radio),
``sweep`` (``link.KEY``, ``link.KEY.PARAM``, ``link.ENTRY.PARAM``) and ``falsify`` (a space's
hows, their severity, the way shrinking lowers them). Each test loops over every registered model,
and a model registered at run time, or a user's named by its entry, is swept and searched as a
built-in one is."""

import csv
import json
import math
import random
import re

import numpy as np
import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st
from pydantic import BaseModel, ConfigDict, Field

from swarm_sitl.campaigns.breaking import harsher_smaller
from swarm_sitl.campaigns.grid import LINK_HOW, SweepSpecError, check_key, point_data
from swarm_sitl.config.load import parse_config
from swarm_sitl.falsify.space import Space, cost, expand, items, plan_of
from swarm_sitl.faults import link_models
from swarm_sitl.faults.link_model import (
    CHECK_BLOCK_STEPS,
    RECORDED,
    SEVERITY_STEPS,
    Effect,
    Effects,
    declared,
    drawn_severity,
    harsher_when_smaller,
    severity_of,
)
from swarm_sitl.faults.link_models import LINK_MODELS, PLAN_FORMS, model_of
from swarm_sitl.faults.plan import LINK_HOW as PLAN_HOWS
from swarm_sitl.faults.plan import FaultEntry, FaultPlan
from tests import support


def _value(lo_hi, rng: random.Random) -> float:
    lo, hi = lo_hi
    return lo + (hi - lo) * rng.uniform(0.05, 0.95)


def example_params(params: type[BaseModel], rng: random.Random) -> dict:
    """Valid values of a model's required parameters, drawn inside each one's declared bounds."""
    out = {}
    for name, field in params.model_fields.items():
        if not field.is_required():
            continue
        lo, hi = 0.0, 1.0
        for m in field.metadata:
            lo = float(getattr(m, "gt", None) or getattr(m, "ge", None) or lo)
            top = getattr(m, "lt", None) or getattr(m, "le", None)
            hi = float(top) if top is not None else max(hi, lo + 100.0)
        out[name] = _value((lo, hi), rng)
    return out


def plan_value(key: str, rng: random.Random) -> tuple[object, dict]:
    """``(value, the entry's other keys)`` that names registered model ``key`` in a plan entry."""
    cls = LINK_MODELS[key]
    form = cls.plan_form
    if form == "flag":
        held = "until_s" in cls.Params.model_fields
        return True, ({"from_s": 1.0, "until_s": 2.0} if held else {})
    if form == "p":
        return _value((0.0, 1.0), rng), {}
    if form == "delay":
        return _value((0.0, 0.1), rng), {"jitter_s": _value((0.0, 0.05), rng)}
    return example_params(cls.Params, rng), {}


PAPER_EDGES = support.config("paper").graph_edges()


@pytest.mark.unit
@pytest.mark.parametrize("key", list(LINK_MODELS))
def test_every_registered_model_is_a_how_of_a_plan_acting_where_it_declares(key):
    cls = LINK_MODELS[key]
    assert cls.plan_form in PLAN_FORMS and key in PLAN_HOWS
    assert issubclass(cls.Params, BaseModel) and callable(cls.fate)
    rng = random.Random(key)
    for _ in range(5):
        value, extra = plan_value(key, rng)
        f = FaultEntry.model_validate({"all_edges": True, key: value, **extra})
        model, params = f.link_how
        assert type(model) is cls and model_of(f) is cls and isinstance(params, cls.Params)
    on_link = {"mavlink": 1, key: value, **extra}
    if not declared(cls, "on_mavlink"):
        with pytest.raises(ValueError, match="acts on bus edges"):
            FaultEntry.model_validate(on_link)
        return
    plan = FaultPlan.model_validate({"plan": [on_link]})
    if declared(cls, "mavlink_in_lockstep"):
        plan.check_lockstep()
    else:
        takes = ", ".join(k for k, m in LINK_MODELS.items() if declared(m, "mavlink_in_lockstep"))
        with pytest.raises(ValueError, match=f"in lockstep a MAVLink link fails by {takes} "):
            plan.check_lockstep()


@pytest.mark.unit
@pytest.mark.parametrize("key", [k for k, m in LINK_MODELS.items() if declared(m, "node_radio")])
def test_a_nodes_radio_is_named_by_its_sender(key):
    value, _ = plan_value(key, random.Random(0))
    with pytest.raises(ValueError, match="sending node's radio"):
        FaultEntry.model_validate({"edge": [0, 1], key: value})
    FaultEntry.model_validate({"out_of": 1, key: value})


@pytest.mark.unit
@pytest.mark.parametrize("key", list(LINK_MODELS))
def test_every_registered_model_is_swept_by_its_probability_or_each_parameter(key):
    cls = LINK_MODELS[key]
    base = support.config("paper").data()
    if cls.plan_form == "p":
        assert key in LINK_HOW
        check_key(f"link.{key}")
    if cls.plan_form != "params":
        with pytest.raises(SweepSpecError, match=r"link\.MODEL\.PARAM is a model of"):
            check_key(f"link.{key}.p")
        return
    rng = random.Random(key)
    point = {f"link.{key}.{n}": v for n, v in example_params(cls.Params, rng).items()}
    for name in cls.Params.model_fields:
        check_key(f"link.{key}.{name}")
        assert harsher_smaller(f"link.{key}.{name}") == harsher_when_smaller(cls.Params, name)
    with pytest.raises(SweepSpecError, match="has no parameter 'nope'"):
        check_key(f"link.{key}.nope")
    cfg = parse_config(point_data(base, point, 0), "sweep")
    assert [type(f.link_how[0]) for f in cfg.faults.plan] == [cls]


@pytest.mark.unit
def test_a_models_declared_severity_is_the_one_its_fate_draws():
    """For every registered model with a severity of its own and no memory (the ones whose
    messages are independent draws), what it declares equals what ``severity_of`` draws from its
    ``fate``: each message's severity lies in [0, 1], so the mean of ``SEVERITY_STEPS`` draws is
    within 5 x 0.5 / sqrt(N) of its expectation (Popoviciu's bound on the deviation)."""
    tol = 5 * 0.5 / math.sqrt(SEVERITY_STEPS)
    rng = random.Random(1)
    checked = []
    for key, cls in LINK_MODELS.items():
        memoryless = cls.plan_form in ("p", "delay") or key == "drop"
        if not callable(getattr(cls, "severity", None)) or not memoryless:
            continue
        for _ in range(20):
            value, extra = plan_value(key, rng)
            model, params = FaultEntry.model_validate({"edge": [0, 1], key: value, **extra}).link_how
            staleness_s = rng.uniform(0.02, 0.2)  # (below, within and above a delay and its jitter)
            own = severity_of(model, params, 0.02, staleness_s)
            assert abs(own - drawn_severity(model, params, 0.02, staleness_s)) <= tol, (key, params)
        checked.append(key)
    assert {"drop", "loss", "corrupt", "delay_s"} <= set(checked)


@pytest.mark.unit
@pytest.mark.parametrize("key", [k for k, m in LINK_MODELS.items() if callable(getattr(m, "severity", None))])
def test_a_models_own_severity_is_within_0_and_1_for_any_parameters(key):
    """The contract's range of a declared severity, held by the model itself, not only by
    ``severity_of``'s clamp: a model read by another consumer gives what it says."""
    cls, rng = LINK_MODELS[key], random.Random(key)
    for _ in range(50):
        value, extra = plan_value(key, rng)
        model, params = FaultEntry.model_validate({"out_of": 1, key: value, **extra}).link_how
        own = model.severity(params, rng.uniform(0.005, 0.1), rng.uniform(0.05, 2.0))
        assert type(model) is cls and 0.0 <= own <= 1.0, (key, params, own)


class _Staircase:
    """A model with no severity of its own whose fate reads each message's time and the control
    period: message k is late by ``(t_k mod 4 P)``, that is 0, P, 2P, 3P in turn, or lost where
    ``k`` is a multiple of 7."""

    class Params(BaseModel):
        pass

    def fate(self, p, m):
        if m.step % 7 == 0:
            return Effect(lost=True)
        return Effect(delay_s=round(m.t_s / m.period_s) % 4 * m.period_s)


class _Declares:
    """A model whose own severity is the period over the staleness."""

    Params = _Staircase.Params

    def fate(self, p, m):
        return None

    def severity(self, p, period_s, staleness_s):
        return period_s / staleness_s


@pytest.mark.unit
@given(period_s=st.floats(0.005, 0.1), ratio=st.floats(0.5, 4.0))
def test_a_drawn_severity_is_the_mean_over_consecutive_messages_of_one_link_from_time_0(period_s, ratio):
    """``drawn_severity``'s closed form on a model that reads the message's time and the period:
    over ``SEVERITY_STEPS`` messages k = 0, 1, ... sent at k P, each lost one counts 1 and each
    late one its delay over staleness, at most 1; ``severity_of`` gives a model's own severity the
    period and staleness it was asked with."""
    staleness_s = ratio * period_s
    want = 0.0
    for k in range(SEVERITY_STEPS):
        want += 1.0 if k % 7 == 0 else min(1.0, (k % 4) / ratio)
    got = drawn_severity(_Staircase(), _Staircase.Params(), period_s, staleness_s)
    assert got == pytest.approx(want / SEVERITY_STEPS, rel=1e-12)
    assert severity_of(_Staircase(), _Staircase.Params(), period_s, staleness_s) == got
    assert severity_of(_Declares(), None, period_s, staleness_s) == pytest.approx(
        min(1.0, 1 / ratio), rel=1e-12
    )


#: a user's link model (``support.BLACKOUT_MODEL``) that declares itself a node's radio, and one
#: that declares it may act on a vehicle's MAVLink link
DECLARING_MODELS = (
    support.BLACKOUT_MODEL
    + """

class Radio(Blackout):
    node_radio = True


class OnBoard(Blackout):
    on_mavlink = True
"""
)


@pytest.mark.unit
def test_a_users_model_is_held_to_what_it_declares_as_a_built_in_is(tmp_path):
    """What a user's model declares of itself (``link_model.DECLARED``) is read from its class,
    as a built-in's is: a radio is named by its sender, a model that does not say it acts on
    MAVLink is refused there; a run's record, which names the model without importing it, reads
    back whatever it was flown on."""
    (tmp_path / "models.py").write_text(DECLARING_MODELS)

    def entry(name: str, **where) -> dict:
        return {**where, "model": {"entry": f"{tmp_path / 'models.py'}:{name}", "params": {"dark": 0.5}}}

    with pytest.raises(ValueError, match="sending node's radio"):
        FaultEntry.model_validate(entry("Radio", edge=[0, 1]))
    FaultEntry.model_validate(entry("Radio", out_of=1))
    FaultEntry.model_validate(entry("Blackout", edge=[0, 1]))  # (declares nothing: any edge)
    with pytest.raises(ValueError, match="acts on bus edges"):
        FaultEntry.model_validate(entry("Blackout", mavlink=1))
    flown = FaultEntry.model_validate(entry("OnBoard", mavlink=1))
    assert model_of(flown).__name__ == "OnBoard"
    for data in (entry("OnBoard", mavlink=1), entry("Radio", out_of=1)):
        read = FaultEntry.model_validate(data, context=RECORDED)
        assert model_of(read) is None and read.model.model is None  # named, not imported


@pytest.mark.unit
def test_a_process_entry_has_no_link_model_and_says_so():
    f = FaultEntry.model_validate({"controller": 2, "kill": True, "from_s": 1.0})
    for ask in (model_of, link_models.how_of):
        with pytest.raises(ValueError, match="controller_2: no link model"):
            ask(f)


class Brownout:
    """A model registered at run time, with one parameter and nothing else: each message lost
    with probability ``level`` (it declares no severity: drawn from its fate)."""

    plan_form = "params"

    class Params(BaseModel):
        model_config = ConfigDict(extra="forbid", frozen=True)
        level: float = Field(ge=0, le=1)

    def fate(self, p, m):
        return Effect(lost=True) if m.uniform(3) < p.level else None


class _Trial:
    """A sampler's trial that answers every question with a fixed draw (``space.Trial``)."""

    def __init__(self, rng: random.Random):
        self.rng = rng

    def suggest_float(self, name, low, high):
        return self.rng.uniform(low, high)

    def suggest_categorical(self, name, choices):
        return choices[-1]


@pytest.mark.unit
def test_a_model_added_to_the_registry_alone_is_a_plan_how_a_sweep_key_and_a_search_space(monkeypatch):
    """One class and its line in ``LINK_MODELS``: no other file knows it, yet a plan names it by
    its key, a campaign varies its parameter and a space searches it, with its severity drawn
    from its fate."""
    monkeypatch.setitem(link_models.LINK_MODELS, "brownout", Brownout)
    cfg = support.config("paper")
    f = FaultEntry.model_validate({"all_edges": True, "brownout": {"level": 0.25}})
    assert type(f.link_how[0]) is Brownout and f.link_how[1].level == 0.25

    check_key("link.brownout.level")
    swept = parse_config(point_data(cfg.data(), {"link.brownout.level": 0.5}, 0), "sweep")
    assert [type(e.link_how[0]) for e in swept.faults.plan] == [Brownout]

    space = Space.model_validate({"entries": [{"edges": "all", "brownout": {"level": [0.0, 1.0]}}]})
    space.check_against(cfg)
    its = items(space, cfg)
    plan = plan_of(_Trial(random.Random(2)), space, its, cfg)
    level = plan["plan"][0]["brownout"]["level"]
    flown = expand(plan, cfg)
    parse_config({**cfg.data(), "faults": flown}, "falsify")
    tol = 5 * 0.5 / math.sqrt(SEVERITY_STEPS)
    assert cost(flown, cfg) == pytest.approx(len(cfg.followers) * level * cfg.duration_s, abs=tol * 4 * 60)
    assert space.entries[0].searched(plan["plan"][0]) == [(("brownout", "level"), (0.0, 1.0))]


@pytest.mark.unit
@pytest.mark.parametrize(
    ("entry", "said"),
    [
        ({"edges": "all", "range": {"range_m": [10, 50]}}, "not a message's own fate"),
        ({"edges": "all", "bandwidth": {"rate_bps": [1000, 9000]}}, "not a message's own fate"),
        ({"edges": "all", "bursty": {"p": [0.1, 0.5], "q": 1}}, "no parameter 'q'"),
        ({"edges": "all", "bursty": {"p": 0.1, "r": 0.5}}, "at least one parameter a range"),
        ({"edges": "all", "bursty": {"p": [0.1, 2.0], "r": 0.5}}, r"bursty.p: 2 is out of its range"),
        ({"edges": "all", "stall": True}, "not searched by a space"),
        ({"links": "each", "corrupt": [0.1, 0.5]}, "links fail by loss or drop, not corrupt"),
        ({"edges": "all", "loss": [0, 1], "corrupt": [0.1, 0.5]}, "exactly one of"),
    ],
)
def test_a_space_entry_a_model_cannot_take_is_one_line_naming_it(entry, said):
    with pytest.raises(ValueError, match=said):
        Space.model_validate({"entries": [entry]})


@pytest.mark.system
@pytest.mark.lockstep
def test_a_users_model_named_by_its_entry_is_swept_and_searched(tmp_path, monkeypatch):
    """``sweep --vary link.blackout.py:Blackout.dark=...`` (the file relative to where it runs)
    and a space over the same parameter: each run flies the model from the copy shipped beside
    its config, a longer blackout costs more formation, and the search's plans name it."""
    from swarm_sitl.campaigns.sweep import sweep
    from swarm_sitl.falsify.search import falsify

    (tmp_path / "blackout.py").write_text(support.BLACKOUT_MODEL)
    data = support.config_data("paper")
    data["duration_s"], data["run"] = 4.0, {**data.get("run", {}), "settle_s": 1.0}
    config = tmp_path / "short.yaml"
    config.write_text(yaml.safe_dump(data))
    monkeypatch.chdir(tmp_path)
    key = "link.blackout.py:Blackout.dark"
    campaign = sweep(config, [f"{key}=0,0.6"], out=tmp_path / "c", seeds=1, bound_m=50.0, jobs=2)
    rows = sorted(campaign.rows, key=lambda r: float(r[key]))
    assert [float(r[key]) for r in rows] == [0.0, 0.6] and all(r["failure"] == "" for r in rows)
    assert float(rows[1]["final_error_m"]) > float(rows[0]["final_error_m"])
    flown = yaml.safe_load((tmp_path / "c" / rows[1]["config"]).read_text())["faults"]["plan"]
    assert flown[-1]["model"]["entry"] == "plugins/blackout.py:Blackout"

    (tmp_path / "space.yaml").write_text(
        'entries:\n  - {edges: all, model: {entry: "blackout.py:Blackout", params: {dark: [0.0, 0.9]}}}\n'
    )
    space = tmp_path / "space.yaml"
    found = falsify(
        config, tmp_path / "f", space=space, bound_m=50.0, budget=2, jobs=1, batch=2, confirm=False
    )
    assert found.evaluations >= 3  # the baseline and the budget
    with open(tmp_path / "f" / "evaluations.csv") as f:
        plans = [json.loads(r["plan"]) for r in csv.DictReader(f)]
    entries = [e for p in plans for e in p["plan"]]
    assert len(plans) == 2 and entries  # each plan on every edge, or none (an item on or off)
    assert all(e["model"]["entry"] == f"{tmp_path / 'blackout.py'}:Blackout" for e in entries)
    assert all(0.0 <= e["model"]["params"]["dark"] <= 0.9 for e in entries)

    # a worker elsewhere (a Dask cluster's) has no blackout.py: it flies the shipped copy, to
    # the same robustness the search recorded
    from swarm_sitl.falsify.search import load_inputs
    from swarm_sitl.falsify.workers import Shipment, fly_shipped

    cfg, sp, name = load_inputs(config, space, None, None, 50.0, None, 2, "severity")
    with open(tmp_path / "f" / "evaluations.csv") as f:
        row = next(r for r in csv.DictReader(f) if json.loads(r["plan"])["plan"])
    ship = Shipment.of(cfg, name, sp.user_models())
    (tmp_path / "blackout.py").rename(tmp_path / "elsewhere.py")
    r, why = fly_shipped(ship, json.loads(row["plan"]))
    assert why == "" and r == pytest.approx(float(row["robustness"]), rel=1e-12, abs=1e-12)


@pytest.mark.unit
@pytest.mark.parametrize("key", list(LINK_MODELS))
def test_every_registered_model_is_in_the_guide_and_the_registrys_table_with_its_module(key):
    """A model added to the registry is listed where a user looks for the hows (``docs/links.md``)
    and in the registry's own table, each with the module it lives in."""
    module = LINK_MODELS[key].__module__.rpartition(".")[2]
    guide = (support.ROOT / "docs" / "links.md").read_text()
    table = [ln for ln in (link_models.__doc__ or "").splitlines() if ln.startswith(f"``{key}``")]
    assert f"`{key}`" in guide and f"`{module}.py`" in guide, (key, module)
    assert len(table) == 1 and table[0].rstrip().endswith(f"``{module}``"), (key, table)


@pytest.mark.unit
@settings(max_examples=30, deadline=None)
@given(delay_s=st.floats(0.0, 0.2), jitter_s=st.floats(1e-3, 0.2), staleness_s=st.floats(0.45, 1.0))
def test_a_delays_severity_is_its_mean_delay_to_the_spread_of_its_jitter(delay_s, jitter_s, staleness_s):
    """A delay with jitter ``J`` is ``d + J U`` late (``U`` uniform): below staleness, each
    message's severity has the spread ``J / sqrt(12) / staleness`` of a uniform's, so the mean of
    ``SEVERITY_STEPS`` draws is within five of its standard errors of the declared severity (the
    bound above is Popoviciu's, for any model, and far looser)."""
    model, params = FaultEntry.model_validate(
        {"edge": [0, 1], "delay_s": delay_s, "jitter_s": jitter_s}
    ).link_how
    own = severity_of(model, params, 0.02, staleness_s)
    tol = 5 * jitter_s / math.sqrt(12) / staleness_s / math.sqrt(SEVERITY_STEPS) + 1e-12
    assert abs(own - drawn_severity(model, params, 0.02, staleness_s)) <= tol


@pytest.mark.unit
@settings(max_examples=40, deadline=None)
@given(
    p=st.floats(0.01, 1.0),
    delay_s=st.floats(0.0, 2.0),
    jitter_s=st.floats(0.0, 1.0),
    staleness_s=st.floats(0.1, 1.0),
    br=st.tuples(st.floats(0.01, 1.0), st.floats(0.01, 1.0)),
)
def test_a_models_severity_is_its_closed_form_cut_at_1(p, delay_s, jitter_s, staleness_s, br):
    """Closed forms, no draw: every message lost, 1; a loss or a corruption of chance ``p``,
    ``p``; a bursty link, its chain's stationary loss ``p / (p + r)`` (all lost in the bad
    state); a delay, the mean of each message's delay over staleness, each cut at 1 (an estimate
    past staleness is lost)."""

    def sev(key: str, value: object, **extra: object) -> float:
        model, params = FaultEntry.model_validate({"edge": [0, 1], key: value, **extra}).link_how
        return severity_of(model, params, 0.02, staleness_s)

    gp, gr = br
    assert sev("drop", True) == 1.0
    assert sev("loss", p) == p and sev("corrupt", p) == p
    assert sev("bursty", {"p": gp, "r": gr}) == pytest.approx(gp / (gp + gr), rel=1e-12)
    # a delay: the mean over its jitter's draws of each one's delay over staleness, cut at 1 (by
    # the midpoint rule on N cells: exact where min(1, a + b u) is linear, off by at most b / N^2
    # in the one cell where it bends)
    a, b, n = delay_s / staleness_s, jitter_s / staleness_s, 100_000
    mean = float(np.minimum(1.0, a + b * (np.arange(n) + 0.5) / n).mean())
    assert sev("delay_s", delay_s, jitter_s=jitter_s) == pytest.approx(mean, abs=b / n**2 + 1e-12)
    # and drawn: every message lost is 1, every one on time 0, exactly
    for key, value, want in (("drop", True, 1.0), ("delay_s", 0.0, 0.0), ("duplicate", p, 0.0)):
        model, params = FaultEntry.model_validate({"edge": [0, 1], key: value}).link_how
        assert drawn_severity(model, params, 0.02, staleness_s) == want, key


@pytest.mark.unit
def test_the_parameters_harsher_when_smaller_are_a_radios_range_rate_and_queue_and_a_bursts_way_back():
    """Read from each registered model's declarations: exactly these parameters hurt more as they
    shrink (a sweep or a search reads them from the largest down); every other one as it grows."""
    declared = {
        (key, name)
        for key, cls in LINK_MODELS.items()
        for name in getattr(cls, "Params", BaseModel).model_fields
        if harsher_when_smaller(cls.Params, name)
    }
    assert declared == {
        ("range", "range_m"),
        ("bandwidth", "rate_bps"),
        ("bandwidth", "queue"),
        ("bursty", "r"),
    }


class _Timed:
    """An honest model whose effect reads each message's time: 1 ms late per 100 ms of run."""

    class Params(BaseModel):
        pass

    def fate(self, p, m):
        return Effect(delay_s=0.001 * int(m.t_s * 10 + 1e-9))

    def fates(self, p, ms):
        none = np.zeros(len(ms.steps), dtype=bool)
        return Effects(none, none, 0.001 * np.floor(ms.t_s * 10 + 1e-9), none)


class _Liar:
    """``fates`` says what ``fate`` says (every fifth step 2 ms late), but on the steps ``step %
    every == at`` it adds ``flaw``: corrupt, duplicated, 0.5 s more late, or (where ``fate`` says
    lost, which hides the rest) nothing a receiver would see."""

    class Params(BaseModel):
        flaw: str
        every: int
        at: int

    def _late(self, step):
        return np.where(np.asarray(step) % 5 == 0, 0.002, 0.0)

    def fate(self, p, m):
        lost = p.flaw == "hidden" and m.step % p.every == p.at
        return Effect(lost=bool(lost), delay_s=float(self._late(m.step)))

    def fates(self, p, ms):
        hit = ms.steps % p.every == p.at
        none = np.zeros(len(ms.steps), dtype=bool)
        late = self._late(ms.steps) + np.where(hit & (p.flaw == "late"), 0.5, 0.0)
        lost = hit if p.flaw == "hidden" else none
        corrupt = hit & (p.flaw in ("corrupt", "hidden"))
        return Effects(lost, corrupt, late, hit & (p.flaw == "duplicate"))


@pytest.mark.unit
@settings(max_examples=30, deadline=None)
@given(
    flaw=st.sampled_from(["corrupt", "duplicate", "late", "hidden"]),
    every=st.integers(7, 200),
    at=st.integers(0, 6),
    seed=st.integers(0, 2**32),
)
def test_the_fates_check_names_the_first_flawed_message_with_both_fates_and_passes_an_honest_model(
    flaw, every, at, seed
):
    """``fates_disagreement`` (what ``check`` runs on a user's model): a ``fates`` that differs
    from ``fate`` in any one field is named at a flawed step, each side's fate said as a receiver
    sees it, the same line for the same seed; a difference hidden by a loss, and an honest model
    that reads the messages' times, pass."""
    from swarm_sitl.faults.link_model import fates_disagreement

    assert fates_disagreement(_Timed(), _Timed.Params(), 0.02, seed) is None
    params = _Liar.Params(flaw=flaw, every=every, at=at)
    line = fates_disagreement(_Liar(), params, 0.02, seed)
    if flaw == "hidden":
        assert line is None
        return
    assert line is not None and line == fates_disagreement(_Liar(), params, 0.02, seed)
    step = int(re.search(r"at step (\d+) ", line).group(1))
    assert step % every == at, line
    late = step % 5 == 0  # (every fifth step 2 ms late on both sides)
    fate_says = "0.002 s late" if late else "on time"
    fates_says = {
        "corrupt": "corrupt" + (", 0.002 s late" if late else ""),
        "duplicate": "duplicated" + (", 0.002 s late" if late else ""),
        "late": f"{0.5 + (0.002 if late else 0.0):g} s late",
    }[flaw]
    assert line.endswith(f": fate() says {fate_says}, fates() {fates_says}"), line


class _Raises(_Timed):
    """A model whose ``fates`` or whose ``fate`` (from step ``at`` on) raises."""

    class Params(BaseModel):
        which: str
        at: int = 0

    def fate(self, p, m):
        if p.which == "fate" and m.step >= p.at:
            raise ValueError(f"no fate past {p.at}")
        return super().fate(p, m)

    def fates(self, p, ms):
        if p.which == "fates":
            raise KeyError("radio")
        return super().fates(p, ms)


@pytest.mark.unit
@given(at=st.integers(0, 100_000 + CHECK_BLOCK_STEPS), seed=st.integers(0, 2**32))
def test_the_fates_check_says_what_a_model_raised_and_where(at, seed):
    """A model that raises is a disagreement too, said in one line: what ``fates`` raised, or
    what ``fate`` raised at the first step it raised on (the first block's steps start below
    100 000; a model that raises only past every step checked passes)."""
    from swarm_sitl.faults.link_model import fates_disagreement

    assert (
        fates_disagreement(_Raises(), _Raises.Params(which="fates"), 0.02, seed)
        == "fates() raised KeyError: 'radio'"
    )
    first = fates_disagreement(_Raises(), _Raises.Params(which="fate", at=0), 0.02, seed)
    assert first is not None and re.fullmatch(
        r"fate\(\) raised ValueError: no fate past 0 at step \d+", first
    )
    line = fates_disagreement(_Raises(), _Raises.Params(which="fate", at=at), 0.02, seed)
    if line is not None:
        step = int(
            re.fullmatch(rf"fate\(\) raised ValueError: no fate past {at} at step (\d+)", line).group(1)
        )
        assert step >= at
