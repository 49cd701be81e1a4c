"""The law contract from outside: what a config may name, what the bench refuses (each a one-line
error naming the law, and the follower once it runs), and what a run keeps when a law fails."""

import dataclasses
import math
from pathlib import Path
from typing import ClassVar, NamedTuple

import numpy as np
import pydantic
import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st

from swarm_sitl.config.law_entry import LawEntryError, check_contract, validate_params
from swarm_sitl.config.load import ConfigError, load_config
from swarm_sitl.laws.contract import MAX_MESSAGE_LENGTH, AttitudeCommand, LawOutput, Received, VehicleSample
from swarm_sitl.nodes.assembly import build_law
from swarm_sitl.nodes.law_guard import LawExit, LawStopped
from swarm_sitl.nodes.law_host import HostedLaw, LawError
from swarm_sitl.running.sim import SimFailedError, run_sim
from tests.support import CONFIGS, cli

#: its system tests run in lockstep or ``sim`` only (no wall clock): free to run beside others
pytestmark = pytest.mark.lockstep

LEVEL = np.array([1.0, 0.0, 0.0, 0.0])

LAWS = """
import numpy as np
from pydantic import BaseModel, ConfigDict, Field
from swarm_sitl.laws.contract import AttitudeCommand, LawOutput

class Hover:
    message_length = 3
    record_fields = {"n_heard": 1}
    def __init__(self, ctx):
        self.weight = ctx.mass_kg * ctx.gravity_mps2
        self.id = ctx.follower_id
    def out(self, message):
        return LawOutput(AttitudeCommand(np.array([1.0, 0, 0, 0]), self.weight), message, {"n_heard": 0})
    def step(self, t, sample, inbox):
        return self.out(np.zeros(3))

class RaisesLater(Hover):
    def step(self, t, sample, inbox):
        if self.id == 2 and t > 0.5:
            raise ZeroDivisionError("my bug")
        return self.out(np.zeros(3))

class NoStep:
    message_length = 3
    record_fields = {}

class BadLength(Hover):
    message_length = 0

class Shadows(Hover):
    record_fields = {"p_W": 3}

class Gains(BaseModel):
    model_config = ConfigDict(extra="forbid")
    k: float = Field(1.0, gt=0)

class WithParams(Hover):
    Params = Gains

class BuildFails(Hover):
    def __init__(self, ctx):
        raise KeyError("gain_that_is_not_there")

not_a_class = 3
"""


@pytest.fixture(scope="module")
def laws_file(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("laws") / "user_laws.py"
    path.write_text(LAWS)
    return path


def _config(tmp_path: Path, entry: str, params: dict | None = None, **more) -> Path:
    cfg = yaml.safe_load((CONFIGS / "paper.yaml").read_text())
    cfg["law"] = {"entry": entry, **({"params": params} if params is not None else {})}
    cfg.update(more)
    path = tmp_path / "cfg.yaml"
    path.write_text(yaml.safe_dump(cfg))
    return path


@pytest.mark.unit
@pytest.mark.parametrize(
    ("entry", "params", "says"),
    [
        ("no_such_package_xyz.laws:Law", None, "no module named 'no_such_package_xyz'"),
        ("missing_file.py:Law", None, "no such file"),
        ("{laws}:Nope", None, "has no 'Nope'"),
        ("{laws}:not_a_class", None, "is a int, not a class"),
        ("{laws}:NoStep", None, "does not meet the law contract: no step(t_s, sample, inbox) method"),
        ("{laws}:BadLength", None, "message_length must be an int from 1 to 4096, got 0"),
        ("{laws}:Shadows", None, "record field 'p_W' is one the bench records itself"),
        ("{laws}:WithParams", {"k": -1.0}, "params.k: Input should be greater than 0"),
        ("{laws}:WithParams", {"kk": 1.0}, "params: it has no parameter kk (it has k)"),
        ("swarm_sitl.laws.zou_meng:ZouMengLaw", {"k_p": 1.0}, "leave law.params empty"),
        ("just_a_name", None, "must be 'package.module:ClassName' or 'path/file.py:ClassName'"),
    ],
)
def test_a_law_entry_that_cannot_fly_is_one_line_naming_it(tmp_path, laws_file, entry, params, says):
    entry = entry.format(laws=laws_file)
    with pytest.raises(ConfigError) as e:
        load_config(_config(tmp_path, entry, params))
    text = str(e.value)
    assert says in text and "\n" not in text, text
    assert text.startswith(f"{tmp_path / 'cfg.yaml'}: law")


@pytest.mark.unit
def test_a_file_entry_is_found_from_the_config_file_and_its_params_validated(tmp_path, laws_file):
    (tmp_path / "sub").mkdir()
    (tmp_path / "sub" / "mine.py").write_text(LAWS)
    cfg = load_config(_config(tmp_path, "sub/mine.py:WithParams", {"k": 2.5}))
    assert (
        cfg.law.entry == f"{tmp_path / 'sub' / 'mine.py'}:WithParams"
    )  # absolute, as the run's copy names it
    assert cfg.law_params().k == 2.5
    assert load_config(_config(tmp_path, f"{laws_file}:Hover")).law_params() == {}  # no Params: as written


def _hosted(laws_file: Path, tmp_path: Path, name: str) -> HostedLaw:
    return build_law(load_config(_config(tmp_path, f"{laws_file}:{name}")), 2)


class _Scripted:
    """A law whose every tick returns what the test gives it."""

    message_length = 3
    record_fields: ClassVar[dict[str, int]] = {"x": 2}

    def __init__(self, out):
        self.out = out

    def step(self, t, sample, inbox):
        if isinstance(self.out, BaseException):
            raise self.out
        return self.out


def _out(q=LEVEL, thrust=5.0, message=None, record=None) -> LawOutput:
    message = np.zeros(3) if message is None else message
    return LawOutput(AttitudeCommand(q, thrust), message, {"x": [1.0, 2.0]} if record is None else record)


@pytest.mark.unit
@pytest.mark.parametrize(
    ("out", "says"),
    [
        (_out(message=np.zeros(4)), "message has shape (4,), it declares message_length 3"),
        (_out(thrust=math.nan), "command is not finite"),
        (_out(message=np.array([0.0, math.inf, 0.0])), "message is not finite"),
        (_out(q=2 * LEVEL), "not a unit quaternion (norm 2)"),
        (_out(q=[1, 0, 0, 0]), "must be arrays of 4, 3, 3"),
        (_out(record={"y": [1.0, 2.0]}), "fields ['y'] it does not declare"),
        (_out(record={"x": [1.0, 2.0], "y": [0.0]}), "fields ['y'] it does not declare, lacks []"),
        (_out(record={"x": [1.0]}), "record field 'x' is not 2 number(s)"),
        (None, "step returned NoneType, not a LawOutput"),
        ((LEVEL, 5.0, np.zeros(3)), "its command is ndarray, not an AttitudeCommand"),
        (ZeroDivisionError("division by zero"), "ZeroDivisionError: division by zero"),
        (SystemExit(3), "it called sys.exit(3), which ends nothing here"),
        (LawExit(4), "it called os._exit(4), which ends nothing here"),
        (LawStopped("its step outlasted 0.5 s"), "its step outlasted 0.5 s"),
        (_out(message=["a", "b", "c"]), "its message is not numbers (list)"),
        (_out(record=np.zeros(5)), "its record is (5,), not a mapping or an array of 2"),
        (_out(record=[1.0, 2.0]), "its record is list, not a mapping or an array of 2"),
    ],
)
def test_a_tick_that_breaks_the_contract_is_one_line_naming_the_law_the_follower_and_the_time(out, says):
    host = HostedLaw(_Scripted(out), 7, "my_laws.py:Scripted")
    sample = VehicleSample(0.25, np.zeros(3), np.zeros(3), LEVEL)
    with pytest.raises(LawError) as e:
        host.step(0.25, sample, {0: Received(np.zeros(12), 0.24, 0.01)})
    text = str(e.value)
    assert text.startswith("law my_laws.py:Scripted, follower 7 at t=0.250 s: ") and says in text, text
    assert "\n" not in text


@pytest.mark.unit
def test_a_law_file_whose_import_failed_is_forgotten_so_the_fixed_file_loads(tmp_path):
    from swarm_sitl.config.law_entry import LawEntryError, resolve

    path = tmp_path / "fixed_later.py"
    path.write_text("raise RuntimeError('not yet')\n" + LAWS)
    with pytest.raises(LawEntryError, match=r"importing .*fixed_later.py failed: RuntimeError: not yet"):
        resolve(f"{path}:Hover")
    path.write_text(LAWS)
    assert resolve(f"{path}:Hover").message_length == 3


@pytest.mark.unit
def test_a_law_that_fails_to_build_names_itself_and_the_follower(tmp_path, laws_file):
    with pytest.raises(LawError, match=r"law .*:BuildFails, follower 2: building it raised KeyError"):
        _hosted(laws_file, tmp_path, "BuildFails")


@pytest.mark.integration
def test_the_template_law_hovers_where_it_starts(paper_cfg):
    """thrust = weight, level: every vehicle's equilibrium; 3 s of the paper's scenario leave each
    within a millimetre of its start (the attitude loop only holds level)."""
    law = paper_cfg.law.model_copy(update={"entry": "swarm_sitl.laws.template:HoverLaw"})
    cfg = paper_cfg.model_copy(update={"law": law})
    rec = run_sim(cfg.model_copy(update={"duration_s": 3.0}))
    for i, s in rec.followers.items():
        start = np.asarray(cfg.follower(i).initial_position_m)
        assert np.abs(s["p_W"] - start).max() < 1e-3
        assert s["heard"][0] == 0 and s["heard"][1:].min() == len(cfg.build_graph().in_neighbours(i))
        np.testing.assert_allclose(s["thrust_N"], cfg.vehicle.mass_kg * cfg.gravity_mps2, rtol=1e-6)


@pytest.mark.integration
def test_sim_of_a_failing_law_keeps_what_it_recorded_and_exits_1_in_one_line(tmp_path, laws_file):
    cfg = load_config(_config(tmp_path, f"{laws_file}:RaisesLater", duration_s=2.0))
    with pytest.raises(SimFailedError) as e:
        run_sim(cfg)
    rec = e.value.recording
    t = rec.followers[2]["t_s"]
    f2 = rec.followers[2]
    assert np.isfinite(f2["p_W"][t <= 0.5]).all() and np.isnan(f2["thrust_N"][t > 0.51]).all()
    out = tmp_path / "sim"
    r = cli("sim", str(tmp_path / "cfg.yaml"), "--out", str(out), "--quiet", timeout=120)
    assert r.returncode == 1 and len(r.stderr.strip().splitlines()) == 1, r.stderr
    assert "follower 2 at t=0.510 s: ZeroDivisionError: my bug" in r.stderr and "Traceback" not in r.stderr
    f2 = np.load(out / "follower_2.npz")
    assert np.isfinite(f2["thrust_N"][f2["t_s"] <= 0.5]).all()


@pytest.mark.system
def test_run_of_a_failing_law_names_the_process_its_code_the_law_and_keeps_the_records(tmp_path, laws_file):
    out = tmp_path / "run"
    r = cli(
        "run",
        _config(tmp_path, f"{laws_file}:RaisesLater"),
        "--duration",
        3,
        "--out",
        out,
        "--quiet",
        timeout=240,
    )
    assert r.returncode == 1, r.stderr
    line = r.stderr.strip()
    assert "\n" not in line and "Traceback" not in line
    assert line.startswith(
        "swarm-sitl: error: controller_2 exited with code 1 (its last tick 50, t=0.500 s): "
        "controller 2: error: law "
    )
    assert ":RaisesLater, follower 2 at t=0.510 s: ZeroDivisionError: my bug" in line
    f2 = np.load(out / "follower_2.npz")
    t = f2["t_s"]
    assert np.isfinite(f2["p_W"][t <= 0.5]).all() and np.isnan(f2["p_W"][t > 0.6]).all()


@pytest.mark.system
def test_a_silent_neighbours_message_reaches_the_law_with_its_growing_age_then_leaves_the_inbox(
    tmp_path, swarm
):
    """Across processes, lockstep, the template law (it records how many it heard and the oldest
    message's age): the edge 0 -> 1 cut from 1 s, follower 1 still gets the leader's last message,
    one period older each tick, until it is past estimator.staleness_s (0.305 s); then nothing until the edge
    returns at 2 s, and the message of 1.99 s at 2.00 s is again one period old."""
    cfg = yaml.safe_load((CONFIGS / "paper.yaml").read_text())
    cfg["law"] = {"entry": "swarm_sitl.laws.template:HoverLaw"}
    cfg["estimator"]["staleness_s"] = 0.305  # off the grid of ages: 0.30 in, 0.31 out
    path = tmp_path / "hover.yaml"
    path.write_text(yaml.safe_dump(cfg))
    r = swarm(path, duration_s=3.0, faults=[{"edge": [0, 1], "drop": True, "from_s": 1.0, "until_s": 2.0}])
    assert r.ok, r.failure
    f1 = r.followers[1].arrays
    k = np.round(f1["t_s"] / 0.01).astype(int)
    heard, age = f1["heard"], f1["oldest_age_s"]
    last = 100  # the leader's last message before the cut is of tick 99 (0.99 s)
    carried = (k >= last) & (k <= 99 + 30)  # at most 0.3 s old
    np.testing.assert_allclose(age[carried], (k[carried] - 99) * 0.01, atol=1e-9)
    assert (heard[carried] == 1).all()
    gone = (k > 99 + 30) & (k <= 200)
    assert (heard[gone] == 0).all() and (age[gone] == 0).all()
    back = k > 200
    assert (heard[back] == 1).all() and np.allclose(age[back], 0.01)
    lost = r.events_of("neighbour_lost")
    assert [(e["follower"], e["neighbour"], round(e["t_s"], 2)) for e in lost] == [(1, 0, 1.30)]


def _law_class(n) -> type:
    """A class that meets the law contract but for its ``message_length`` ``n``."""
    return type("L", (), {"message_length": n, "record_fields": {}, "step": lambda self, t, s, i: None})


@pytest.mark.unit
@settings(max_examples=60, deadline=None)
@given(
    n=st.one_of(
        st.integers(-3, 3),
        st.integers(MAX_MESSAGE_LENGTH - 3, MAX_MESSAGE_LENGTH + 3),
        st.sampled_from([1.0, True, "3", None]),
    )
)
def test_a_message_length_is_taken_exactly_when_it_is_an_int_from_1_to_the_largest(n):
    if type(n) is int and 1 <= n <= MAX_MESSAGE_LENGTH:
        check_contract(_law_class(n), "e")
    else:
        with pytest.raises(LawEntryError, match=r"^entry 'e': message_length must be an int from 1 to "):
            check_contract(_law_class(n), "e")


@dataclasses.dataclass(frozen=True)
class _GainsData:
    k: float = 1.0

    def __post_init__(self) -> None:
        if not self.k > 0:
            raise ValueError(f"k must be positive, got {self.k}")


class _GainsTuple(NamedTuple):
    k: float = 1.0


@pytest.mark.unit
@pytest.mark.parametrize("schema", [_GainsData, _GainsTuple])
@settings(max_examples=20, deadline=None)
@given(k=st.floats(-10, 10))
def test_a_laws_params_of_any_class_taking_keywords_are_built_from_the_config_or_refused_in_one_line(
    schema, k
):
    """A law's ``Params`` need not be a pydantic model: a dataclass or a NamedTuple is built with
    the config's values as keywords, its defaults where none is given; what it raises is one line
    naming the law; a name it does not declare is refused whatever the class would take."""
    law = type("L", (), {"Params": schema})
    assert validate_params(law, {}, "e") == schema()
    if schema is _GainsData and not k > 0:
        with pytest.raises(
            LawEntryError, match=r"^params: ValueError: k must be positive, got .* \(law e\)$"
        ):
            validate_params(law, {"k": k}, "e")
    else:
        assert validate_params(law, {"k": k}, "e") == schema(k=k)
    with pytest.raises(LawEntryError, match=r"^params: it has no parameter gain \(it has k\) \(law e\)$"):
        validate_params(law, {"gain": k}, "e")


_SHAPES = st.sampled_from([(4,), (3,), (2,), (5,), (1, 3), (3, 1), (0,), ()])


@pytest.mark.unit
@settings(max_examples=40, deadline=None)
@given(q=_SHAPES, w=_SHAPES, wd=_SHAPES, thrust=st.sampled_from([5.0, np.float32(5.0), 5]))
def test_a_command_of_wrong_shapes_is_one_line_naming_each_fields_shape(q, w, wd, thrust):
    """A command whose q_c, omega_c_B and omegadot_c_B are not arrays of 4, 3 and 3 fails the
    tick in one line that gives the shape each of them had and the thrust's type, whichever are
    wrong; a command of the right shapes passes."""
    q_c = np.resize(LEVEL, q) if q != (4,) else LEVEL
    out = LawOutput(AttitudeCommand(q_c, thrust, np.zeros(w), np.zeros(wd)), np.zeros(3), {"x": [1.0, 2.0]})
    host = HostedLaw(_Scripted(out), 7, "my_laws.py:Scripted")
    sample = VehicleSample(0.25, np.zeros(3), np.zeros(3), LEVEL)
    if (q, w, wd) == ((4,), (3,), (3,)):
        assert host.step(0.25, sample, {}).command.q_c.shape == (4,)
        return
    with pytest.raises(LawError) as e:
        host.step(0.25, sample, {})
    said = f"(got q_c {q}, omega_c_B {w}, omegadot_c_B {wd}, thrust_N {type(thrust).__name__})"
    assert str(e.value).endswith(said) and "must be arrays of 4, 3, 3 floats" in str(e.value), str(e.value)


@pytest.mark.unit
@pytest.mark.parametrize(
    ("members", "says"),
    [
        ({"message_length": 3, "record_fields": {}}, "no step(t_s, sample, inbox) method"),
        ({"record_fields": {}, "step": lambda self, t, s, i: None}, "no message_length (an int)"),
        ({"message_length": 3, "step": lambda self, t, s, i: None}, "no record_fields"),
        ({"message_length": 3, "record_fields": {}, "step": 3}, "no step(t_s, sample, inbox) method"),
        (
            {"message_length": 3, "record_fields": {"a b": 1}, "step": lambda self, t, s, i: None},
            "'a b' is not a name",
        ),
        (
            {"message_length": 3, "record_fields": {1: 1}, "step": lambda self, t, s, i: None},
            "field 1 is not a name",
        ),
    ],
)
def test_a_class_missing_any_member_of_the_law_contract_is_one_line_naming_it(members, says):
    """Each member the law protocol declares (``laws.contract.Law``), removed or of the wrong kind
    (a step that is not a method, a record field that is not a name), is named in one line."""
    with pytest.raises(LawEntryError) as e:
        check_contract(type("L", (), members), "e")
    assert str(e.value).startswith("entry 'e': ") and says in str(e.value), str(e.value)


class _Checked(pydantic.BaseModel):
    k: float = 1.0

    @pydantic.field_validator("k")
    @classmethod
    def _positive(cls, v: float) -> float:
        if not v > 0:
            raise ValueError(f"k must be positive, got {v}")
        return v


@pytest.mark.unit
def test_a_laws_params_are_refused_in_one_line_naming_what_it_declares_and_its_own_reason():
    """A law that declares no ``Params`` takes no parameter (the line says it declares none); a
    pydantic ``Params``' own refusal is its reason, without pydantic's "Value error, " prefix."""
    bare = type("L", (), {})
    assert validate_params(bare, {}, "e") == {}
    with pytest.raises(
        LawEntryError, match=r"^params: it has no parameter x \(it declares none\) \(law e\)$"
    ):
        validate_params(bare, {"x": 1.0}, "e")
    with pytest.raises(LawEntryError, match=r"^params\.k: k must be positive, got -1\.0 \(law e\)$"):
        validate_params(type("L", (), {"Params": _Checked}), {"k": -1.0}, "e")


@pytest.mark.unit
@settings(max_examples=40, deadline=None)
@given(
    scale=st.floats(1e-3, 2.0),
    ages=st.lists(st.floats(0.0, 5.0), max_size=4),
    p=st.tuples(*[st.floats(-100.0, 100.0)] * 3),
    v=st.tuples(*[st.floats(-10.0, 10.0)] * 3),
)
def test_the_template_law_holds_level_at_its_share_of_the_weight_and_tells_what_it_heard(scale, ages, p, v):
    """The law users copy (``laws/template.py``), one tick at a time: level, no rates, thrust
    ``thrust_scale`` times the weight; its message its sample's position and velocity; its record
    how many it heard and the oldest age (0 with nobody); ``thrust_scale`` within (0, 2]."""
    from swarm_sitl.laws.template import HoverLaw, HoverParams
    from swarm_sitl.nodes.assembly import law_context, reported_vehicle_params
    from tests.support import config

    cfg = config("paper")
    ctx = dataclasses.replace(
        law_context(cfg, 1, *reported_vehicle_params(cfg)), params=HoverParams(thrust_scale=scale)
    )
    law = HoverLaw(ctx)
    inbox = {k: Received(np.zeros(6), 1.0 - a, a) for k, a in enumerate(ages)}
    out = law.step(1.0, VehicleSample(1.0, np.array(p), np.array(v), np.array([0.9, 0.1, 0.3, 0.3])), inbox)
    assert tuple(out.command.q_c) == (1.0, 0.0, 0.0, 0.0)
    assert out.command.thrust_N == pytest.approx(scale * ctx.mass_kg * ctx.gravity_mps2, rel=1e-15)
    assert not np.any(out.command.omega_c_B) and not np.any(out.command.omegadot_c_B)
    assert tuple(out.message) == (*p, *v)
    assert out.record == {"heard": len(ages), "oldest_age_s": max(ages, default=0.0)}
    for bad in (0.0, -1.0, 2.0 + 1e-9):
        with pytest.raises(pydantic.ValidationError):
            HoverParams(thrust_scale=bad)
    with pytest.raises(pydantic.ValidationError):
        HoverParams(thrust_scale=1.0, scale=2.0)
