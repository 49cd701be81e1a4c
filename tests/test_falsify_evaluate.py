"""Which requirement ``falsify`` judges (``falsify/evaluate.py``), over random configs: with a
bound (given, or the run's own), exactly the requirement that the run's bound judges, from
``settle_s`` to the end; with a spec, exactly the one named (or its only one); each way there is
nothing to judge is one line saying what to give. And a plan flown by ``evaluate`` is judged as
the same run flown by ``sim`` and judged afterwards."""

import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from swarm_sitl.falsify.evaluate import BOUND, evaluate, requirement_config, robustness_of
from swarm_sitl.running.sim import run_sim
from swarm_sitl.specs.requirement import Requirement
from tests.support import config

pytestmark = pytest.mark.unit

CFG = config("paper")  # 60 s, no spec, no run bound of its own
_names = st.lists(st.from_regex(r"[a-z][a-z0-9_]{0,6}", fullmatch=True), min_size=1, max_size=4, unique=True)


def _with(cfg, spec=None, **run):
    update = {"run": cfg.run.model_copy(update=run)}
    if spec is not None:
        update["spec"] = [
            Requirement(name=n, formula=f"always (pos_err_m <= {k + 1})") for k, n in enumerate(spec)
        ]
    return cfg.model_copy(update=update)


@settings(max_examples=40, deadline=None)
@given(
    bound=st.floats(1e-3, 10.0),
    settle=st.floats(0.0, 59.0),
    own=st.one_of(st.none(), st.floats(1e-3, 10.0)),
    spec=st.one_of(st.none(), _names),
    given_name=st.sampled_from([None, BOUND]),
)
def test_a_bound_is_judged_from_settle_s_to_the_end_as_the_one_requirement(
    bound, settle, own, spec, given_name
):
    """``--bound`` over anything else, the run's own bound where no spec is, as one requirement
    named ``bound``: always, from ``settle_s`` to the end, every follower within it."""
    cfg = _with(CFG, spec, settle_s=settle, max_formation_error_m=own)
    for b in (bound, None):
        if b is None and (own is None or spec is not None):
            continue  # (no bound to use: below)
        got, name = requirement_config(cfg, given_name, b)
        want = b if b is not None else own
        assert name == BOUND and [r.name for r in got.spec] == [BOUND]
        assert got.spec[0].formula == f"always[{settle:g}, end] (pos_err_m <= {want!r})"
        assert got.spec[0].over == "followers"
        assert got.model_copy(update={"spec": cfg.spec}) == cfg  # nothing else changed


@settings(max_examples=40, deadline=None)
@given(names=_names, data=st.data())
def test_with_a_spec_the_requirement_named_or_its_only_one_is_judged_alone(names, data):
    cfg = _with(CFG, names)
    pick = data.draw(st.sampled_from(names))
    got, name = requirement_config(cfg, pick, None)
    assert name == pick and got.spec == [r for r in cfg.spec if r.name == pick]
    if len(names) == 1:
        assert requirement_config(cfg, None, None) == (got, pick)
    else:
        with pytest.raises(ValueError) as e:
            requirement_config(cfg, None, None)
        assert str(e.value) == (
            f"the spec has {len(names)} requirements ({', '.join(names)}): name one (--requirement)"
        )
    with pytest.raises(ValueError) as e:
        requirement_config(cfg, "zz-none", None)
    assert str(e.value) == f"--requirement zz-none: not in the spec (it has {', '.join(names)})"


def test_each_way_to_have_nothing_to_judge_is_one_line_saying_what_to_give():
    cases = [
        (
            _with(CFG),
            None,
            None,
            "nothing to falsify: the config has no spec: and no run.max_formation_error_m "
            "(give --spec or --bound)",
        ),
        (
            _with(CFG, settle_s=60.0),
            None,
            0.1,
            "the bound is judged from run.settle_s = 60 s, not before the run's end (60 s): "
            "a longer --duration, or a spec",
        ),
        (
            _with(CFG, max_formation_error_m=0.1),
            "formation",
            None,
            "--requirement formation: with a bound the requirement is 'bound'",
        ),
    ]
    for cfg, name, bound, said in cases:
        with pytest.raises(ValueError) as e:
            requirement_config(cfg, name, bound)
        assert str(e.value) == said


def test_a_plan_flown_by_evaluate_is_judged_as_sim_flies_and_judges_it():
    """A short run with a loss on one edge: the robustness ``evaluate`` gives is the one the same
    config and plan give when ``sim`` flies them and the run is judged afterwards, bit for bit."""
    short = CFG.model_copy(update={"duration_s": 2.0})
    cfg, name = requirement_config(_with(short, settle_s=1.0), None, 0.5)
    plan = {"seed": 3, "plan": [{"edge": [0, 1], "loss": 0.5}]}
    flown = cfg.model_copy(update={"faults": type(cfg.faults).model_validate(plan)})
    rec = run_sim(flown)
    r = evaluate(cfg, name, plan)
    assert r == robustness_of(flown, rec, name) and math.isfinite(r)


RAISING_LAW = """
import numpy as np

from sim_vehicles.common.command import AttitudeCommand
from swarm_sitl.laws.contract import LawOutput


class RaisesLate:
    message_length = 3
    record_fields = {}

    def __init__(self, ctx):
        self.weight = ctx.mass_kg * ctx.gravity_mps2
        self.id = ctx.follower_id

    def step(self, t, sample, inbox):
        if self.id == 2 and t >= 0.5:
            raise ValueError("gave up")
        return LawOutput(AttitudeCommand(np.array([1.0, 0.0, 0.0, 0.0]), self.weight), np.zeros(3), {})
"""


def test_a_plan_under_which_the_law_fails_is_a_violation_judged_on_what_was_recorded(tmp_path):
    """Follower 2's law raises at 0.5 s: the run is judged on what it recorded before (nothing
    after: not a number), which has no robustness, and so is minus infinity: a violation, however
    loose the requirement."""
    import yaml

    from swarm_sitl.config.load import load_config
    from tests.support import config_data

    (tmp_path / "raising.py").write_text(RAISING_LAW)
    data = config_data("paper") | {
        "duration_s": 1.0,
        "law": {"entry": f"{tmp_path / 'raising.py'}:RaisesLate"},
    }
    data["spec"] = [{"name": "up", "formula": "always (altitude_m >= -1000)"}]
    (tmp_path / "c.yaml").write_text(yaml.safe_dump(data))
    cfg, name = requirement_config(load_config(tmp_path / "c.yaml"), None, None)
    assert evaluate(cfg, name, {"seed": 0, "plan": []}) == -math.inf
