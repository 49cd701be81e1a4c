"""The vehicle as one config (``sim_vehicles.models``): it crosses a process boundary whole and bit
for bit, one function builds the same vehicle from it wherever it is flown, and what is not a
vehicle is one line naming the field."""

import dataclasses
import json
import math

import numpy as np
import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st

from sim_vehicles.models.build import build_vehicle, sensor_model
from sim_vehicles.models.vehicle_config import Gusts, SensorNoise, VehicleConfig, VehicleConfigError
from swarm_sitl.nodes.assembly import build_autopilot
from tests.support import CONFIGS, cli, config, vehicle

finite = st.floats(-1e6, 1e6, allow_nan=False)
positive = st.floats(1e-6, 1e6, allow_nan=False)


@pytest.mark.unit
@given(
    st.tuples(finite, finite, finite),
    st.tuples(positive, positive, positive),
    st.floats(0.1, 10.0),
    positive,
    st.integers(0, 2**63 - 1),
)
def test_a_spec_comes_back_from_its_json_equal_bit_for_bit(position, inertia, mass, drag, seed):
    spec = VehicleConfig(
        mass_kg=mass,
        max_thrust_N=mass * 9.81 * 3.0,
        inertia_kgm2=inertia,
        position_m=position,
        drag_Ns2pm2=drag,
        wind=Gusts((1.0 / 3.0, 0.1, -2.0), 0.7, 0.9, seed),
        sensors=SensorNoise(0.01, 0.02, 0.003, 0.04, seed),
    )
    back = VehicleConfig.from_json(spec.to_json())
    assert back == spec
    assert np.array(back.position_m).tobytes() == np.array(position).tobytes()


@pytest.mark.unit
def test_the_run_builds_the_vehicle_sim_builds_from_the_spec_its_process_reads():
    """The config's vehicle, through its JSON file, builds the same plant with the same wind and
    sensors, and flies the same bits (what makes lockstep equal ``sim``)."""
    data = yaml.safe_load((CONFIGS / "paper.yaml").read_text())
    data["wind"] = {"mean_mps": [1.0, 0.5, 0.0], "gust_mps": 0.8, "gust_time_s": 0.7, "seed": 4}
    data["vehicle"]["drag_Ns2pm2"] = 0.02
    data["vehicle"]["sensors"] = {"position_noise_m": 0.01, "seed": 9}
    from swarm_sitl.config.load import parse_config

    cfg = parse_config(data)
    for i in (1, 3):
        spec = VehicleConfig.from_json(cfg.vehicle_config(i).to_json())
        a, b = build_autopilot(cfg, i), build_vehicle(spec, i)
        assert a.params == b.params and a.gains == b.gains and a.dt_s == b.dt_s
        for ap in (a, b):
            for _ in range(20):
                ap.advance(10)
        assert a.state.tobytes() == b.state.tobytes()
        s1, s2 = sensor_model(spec, i), sensor_model(cfg.vehicle_config(i), i)
        assert s1 is not None and s2 is not None
        x = a.state
        assert s1.reported(120, x).tobytes() == s2.reported(120, x).tobytes()


@pytest.mark.unit
@pytest.mark.parametrize(
    ("change", "named"),
    [
        ({"mass_kg": -1.0}, "mass_kg: must be a finite number > 0, got -1.0"),
        ({"mass_kg": math.inf}, "mass_kg: must be a finite number > 0, got inf"),
        (
            {"inertia_kgm2": (1.0, 0.0, 1.0)},
            "inertia_kgm2: must be 3 finite numbers > 0, got (1.0, 0.0, 1.0)",
        ),
        (
            {"inertia_kgm2": (1.0, math.inf, 1.0)},
            "inertia_kgm2: must be 3 finite numbers > 0, got (1.0, inf, 1.0)",
        ),
        ({"max_rate_rps": (1.0, 2.0)}, "max_rate_rps: must be 3 finite numbers > 0, got (1.0, 2.0)"),
        (
            {"quaternion_wxyz": (1.0, 1.0, 0.0, 0.0)},
            "quaternion_wxyz: must be a unit quaternion, got (1.0, 1.0, 0.0, 0.0)",
        ),
        ({"failsafe_action": "explode"}, "failsafe_action: must be one of hold, land, got 'explode'"),
        ({"position_m": (0.0, math.nan, 0.0)}, "position_m: must be 3 finite numbers, got (0.0, nan, 0.0)"),
        (
            {"max_thrust_N": 1.0},
            "max_thrust_N: 1.0 must exceed the weight m g (8.338 N) or the vehicle cannot hover",
        ),
        (  # exactly the weight: it can hover, with nothing left to climb or steer by
            {"mass_kg": 1.0, "g_mps2": 9.81, "max_thrust_N": 9.81},
            "max_thrust_N: 9.81 must exceed the weight m g (9.810 N) or the vehicle cannot hover",
        ),
        ({"autopilot": "betaflight"}, "autopilot: must be one of px4, ardupilot, got 'betaflight'"),
        ({"drag_Ns2pm2": -0.5}, "drag_Ns2pm2: must be >= 0 and finite, got -0.5"),
        ({"drag_Ns2pm2": math.inf}, "drag_Ns2pm2: must be >= 0 and finite, got inf"),
        (
            {"wind": Gusts(gust_time_s=0.0)},
            "wind: gust_mps must be zero or positive and gust_time_s positive, both finite, got (0.0, 0.0)",
        ),
        (
            {"wind": Gusts(gust_mps=math.inf)},
            "wind: gust_mps must be zero or positive and gust_time_s positive, both finite, got (inf, 1.0)",
        ),
        ({"wind": Gusts(mean_mps=(1.0, 2.0))}, "wind: mean_mps must be 3 finite numbers, got (1.0, 2.0)"),
        (
            {"wind": Gusts(mean_mps=(1.0, 2.0, math.nan))},
            "wind: mean_mps must be 3 finite numbers, got (1.0, 2.0, nan)",
        ),
        ({"wind": Gusts(model="swirl")}, "wind: model must be independent or frozen, got 'swirl'"),
        ({"wind": Gusts(seed=-1)}, "wind: seed must be a whole number in 0..2**63 - 1, got -1"),
        ({"wind": Gusts(seed=1.5)}, "wind: seed must be a whole number in 0..2**63 - 1, got 1.5"),
        (
            {"sensors": SensorNoise(latency_s=-1.0)},
            "sensors: noise and latency are zero or positive, and finite, got (0.0, 0.0, 0.0, -1.0, 0.0)",
        ),
        (
            {"sensors": SensorNoise(position_noise_m=math.inf)},
            "sensors: noise and latency are zero or positive, and finite, got (inf, 0.0, 0.0, 0.0, 0.0)",
        ),
        (
            {"sensors": SensorNoise(seed=2**63)},
            f"sensors: seed must be a whole number in 0..2**63 - 1, got {2**63}",
        ),
        ({"params": {"T_TAU_S": True}}, "params: T_TAU_S: must be a finite number, got True"),
        ({"params": {"T_TAU_S": float("inf")}}, "params: T_TAU_S: must be a finite number, got inf"),
        ({"params": {"T_TAU_S": "fast"}}, "params: T_TAU_S: must be a finite number, got 'fast'"),
    ],
)
def test_what_is_not_a_vehicle_is_one_line_naming_the_field(change, named):
    """Each refusal names its field and says what it must be and what it got (read as a user
    reads it: the text, not a pattern of it)."""
    with pytest.raises(VehicleConfigError) as e:
        dataclasses.replace(VehicleConfig(), **change)
    assert str(e.value) == f"vehicle config: {named}"


@pytest.mark.unit
def test_a_config_file_that_is_not_one_is_refused_in_one_line():
    for text, named in [
        ("[1, 2]", "^vehicle config: must be a mapping of field names to values$"),
        ('{"mass": 1}', r"unknown field\(s\) mass"),
        ('{"mass": 1, "colour": 2}', r"^vehicle config: unknown field\(s\) colour, mass$"),
        ("{", "not JSON"),
        ('{"inertia_kgm2": 5}', "vehicle config:"),
    ]:
        with pytest.raises(VehicleConfigError, match=named):
            VehicleConfig.from_json(text)
    with pytest.raises(VehicleConfigError, match="model 'quad9' is not one of paper_vtol"):
        build_vehicle(VehicleConfig(model="quad9"), 1)


@pytest.mark.integration
def test_the_vehicle_process_refuses_a_bad_config_file_in_one_line_before_it_binds(tmp_path):
    bad = tmp_path / "v.json"
    bad.write_text(json.dumps({**json.loads(VehicleConfig().to_json()), "mass_kg": 0}))
    for args, named in [
        (["--config", str(bad)], "vehicle config: mass_kg: must be a finite number > 0, got 0"),
        (["--config", str(tmp_path / "none.json")], "--config"),
        (["--model", "nope"], "model 'nope' is not one of"),
        (["--spec", str(bad)], "vehicle config: mass_kg"),  # the flag's name before: read, with a notice
    ]:
        r = vehicle("--port", "0", *args, timeout=60)
        assert r.returncode == 2, r.stderr
        lines = r.stderr.strip().splitlines()
        if args[0] == "--spec":
            notice = "--spec is --config now (the vehicle's config file); read as --config"
            assert lines[0] == f"sim_vehicles: notice: {notice}"
            lines = lines[1:]
        assert len(lines) == 1 and named in lines[0], r.stderr


@pytest.mark.unit
def test_flags_set_fields_over_the_config_file(tmp_path):
    from sim_vehicles.__main__ import vehicle_config

    path = tmp_path / "v.json"
    path.write_text(VehicleConfig(mass_kg=1.2, max_thrust_N=30.0, wind=Gusts(gust_mps=0.5)).to_json())
    import argparse

    from sim_vehicles.__main__ import CONFIG_FLAGS, SENSOR_FLAGS, WIND_FLAGS

    none = {flag: None for flag in [*CONFIG_FLAGS, *WIND_FLAGS, *SENSOR_FLAGS]}
    a = argparse.Namespace(**{**none, "config": str(path), "position": [1.0, 2.0, 3.0], "wind_seed": 7})
    spec = vehicle_config(a)
    assert spec.mass_kg == 1.2 and spec.position_m == (1.0, 2.0, 3.0)
    assert spec.wind == Gusts(gust_mps=0.5, seed=7)  # the file's gusts, the flag's seed
    assert vehicle_config(argparse.Namespace(**{**none, "config": None})) == VehicleConfig()


@pytest.mark.unit
def test_the_paper_configs_vehicle_is_the_specs_default_airframe():
    """``VehicleConfig()``'s defaults are section 4's airframe, what ``python -m sim_vehicles``
    flies by hand without flags (as before the spec)."""
    cfg = config("paper")
    spec = cfg.vehicle_config(1)
    default = VehicleConfig()
    same = ("mass_kg", "inertia_kgm2", "max_thrust_N", "g_mps2", "l_q", "k_q", "attitude_hz")
    assert all(getattr(spec, f) == getattr(default, f) for f in same)


@pytest.mark.unit
def test_an_old_config_with_the_torque_law_under_gains_loads_with_one_notice():
    """``gains.l_q``, ``gains.k_q`` moved to ``vehicle``: read from the old place, the same
    vehicle, one line saying so; given twice with two values, refused."""
    from swarm_sitl.config.load import ConfigError, parse_config

    data = yaml.safe_load((CONFIGS / "paper.yaml").read_text())
    new = parse_config(data)
    assert new.notices == [] and new.vehicle.l_q == 16.0
    old = {**data, "gains": {**data["gains"], "l_q": 12.0, "k_q": 9.0}, "vehicle": dict(data["vehicle"])}
    del old["vehicle"]["l_q"], old["vehicle"]["k_q"]
    cfg = parse_config(old)
    assert (cfg.vehicle.l_q, cfg.vehicle.k_q) == (12.0, 9.0) and "l_q" not in cfg.gain_dict()
    assert cfg.vehicle_config(1).l_q == 12.0
    assert cfg.notices == [
        "gains.l_q, gains.k_q: the vehicle's attitude loop now, read as vehicle.l_q, vehicle.k_q "
        "(move them there)"
    ]
    clash = {**old, "vehicle": {**old["vehicle"], "l_q": 5.0}}
    with pytest.raises(
        ConfigError, match=r"gains\.l_q and vehicle\.l_q differ: give it once, as vehicle\.l_q"
    ):
        parse_config(clash)


@pytest.mark.integration
def test_the_cli_says_the_notice_in_one_line_and_carries_on(tmp_path):
    data = yaml.safe_load((CONFIGS / "paper.yaml").read_text())
    data["gains"]["l_q"] = data["vehicle"].pop("l_q")
    path = tmp_path / "old.yaml"
    path.write_text(yaml.safe_dump(data))
    r = cli("check", str(path), timeout=120)
    assert r.returncode == 0 and "all conditions hold" in r.stdout
    assert r.stderr.strip() == (
        f"swarm-sitl: notice: {path}: gains.l_q: the vehicle's attitude loop now, read as vehicle.l_q "
        "(move it there)"
    )


@pytest.mark.unit
def test_a_field_added_to_the_vehicle_config_is_a_config_key_with_no_change_to_the_schema(monkeypatch):
    """A parameter every model shares is one field of ``VehicleConfig`` (and its use in a model):
    the config's ``vehicle:`` takes it as it is and hands it on, here a spec with one field more
    (``motor_kv``); a key that is no field of either is still an unknown key, in one line."""
    from swarm_sitl.config.load import ConfigError, parse_config

    @dataclasses.dataclass(frozen=True)
    class Extended(VehicleConfig):
        motor_kv: float = 0.0
        props: tuple[float, float] = (0.0, 0.0)

    monkeypatch.setattr("sim_vehicles.models.vehicle_config.VehicleConfig", Extended)
    data = yaml.safe_load((CONFIGS / "paper.yaml").read_text())
    data["vehicle"].update(motor_kv=920.0, props=[5.0, 4.5])
    spec = parse_config(data).vehicle_config(2)
    assert isinstance(spec, Extended) and spec.motor_kv == 920.0 and spec.props == (5.0, 4.5)
    assert spec.mass_kg == 0.85  # (and everything else as before)
    data["vehicle"]["motor_kvv"] = 1.0
    with pytest.raises(ConfigError, match=r"^config: vehicle: motor_kvv: unknown key$"):
        parse_config(data)
    monkeypatch.undo()
    data["vehicle"].pop("motor_kvv")
    with pytest.raises(ConfigError, match="vehicle: motor_kv: unknown key"):  # the spec of today has none
        parse_config(data)
    for key in ("motor_kv", "props"):
        data["vehicle"].pop(key)
    for elsewhere in ("g_mps2", "position_m", "wind"):  # set from the config's other sections
        with pytest.raises(ConfigError, match=f"vehicle: {elsewhere}: unknown key"):
            parse_config({**data, "vehicle": {**data["vehicle"], elsewhere: 1.0}})


#: values the config may give a spec field that the generic rule below cannot make valid
SAMPLES = {
    "model": "px4_quad_x",
    "failsafe_action": "land",
    "autopilot": "ardupilot",
    "attitude_hz": 2000.0,  # (a multiple of the control rate)
    "quaternion_wxyz": (0.0, 0.0, 0.0, 1.0),
    "max_rate_rps": (5.0, 6.0, 7.0),
    "wind": {"mean_mps": (1.0, -2.0, 0.5), "gust_mps": 0.3, "gust_time_s": 2.0, "seed": 5, "model": "frozen"},
    "sensors": {
        "position_noise_m": 0.1,
        "velocity_noise_mps": 0.2,
        "attitude_noise_rad": 0.01,
        "latency_s": 0.02,
        "seed": 3,
        "position_bias_walk_m_per_sqrt_s": 0.05,
    },
}


def _sample(field: dataclasses.Field) -> object:
    """A valid value other than the field's default: ``SAMPLES``', or a number (or each number of
    a tuple) moved up from it."""
    if field.name in SAMPLES:
        return SAMPLES[field.name]
    default = field.default
    if isinstance(default, float):
        return default * 1.5 + 0.25
    if isinstance(default, tuple) and all(isinstance(x, float) for x in default):
        return tuple(x * 1.5 + 0.25 for x in default)
    raise AssertionError(f"VehicleConfig.{field.name}: give the test a sample value (SAMPLES)")


@pytest.mark.unit
@pytest.mark.parametrize("name", [f.name for f in dataclasses.fields(VehicleConfig) if f.name != "params"])
def test_every_field_of_the_spec_reaches_the_vehicle_from_where_the_config_sets_it(name):
    """Each field of ``VehicleConfig``, given a value of its own where the config sets it (its
    ``vehicle:`` key, or the section ``SET_ELSEWHERE`` names), is that value in every follower's
    spec: a field the mapping dropped would keep its default."""
    from swarm_sitl.config.load import parse_config
    from swarm_sitl.config.vehicle_section import SET_ELSEWHERE

    field = next(f for f in dataclasses.fields(VehicleConfig) if f.name == name)
    value = _sample(field)
    data = yaml.safe_load((CONFIGS / "paper.yaml").read_text())
    data["vehicle"]["drag_Ns2pm2"] = 0.01  # (wind acts through it)
    path = SET_ELSEWHERE.get(name, f"vehicle.{name}").split(".")
    for node in (
        [data["followers"][k] for k in range(len(data["followers"]))] if path[0] == "FOLLOWER" else [data]
    ):
        for part in path[1:-1] if path[0] == "FOLLOWER" else path[:-1]:
            node = node.setdefault(part, {})
        node[path[-1]] = list(value) if isinstance(value, tuple) else value
    cfg = parse_config(data)
    for f in cfg.followers:
        got = getattr(cfg.vehicle_config(f.id), name)
        if isinstance(value, dict):  # a nested spec, field by field
            assert dataclasses.asdict(got) == {
                k: tuple(v) if isinstance(v, list) else v for k, v in value.items()
            }
        else:
            assert got == value, (name, got, value)


@pytest.mark.unit
@pytest.mark.parametrize("at", [0, 5, len(dataclasses.fields(VehicleConfig))])
def test_a_field_added_to_the_vehicles_config_is_a_config_key_wherever_it_sits(monkeypatch, at):
    """A field added to ``VehicleConfig`` (at its start, among the others, at its end) is a
    ``vehicle:`` key with no other file edited: given, it reaches every follower's vehicle; not
    given, the vehicle keeps the field's default; and every other field reaches the vehicle as it
    did before the field was added."""
    from sim_vehicles.models import vehicle_config
    from swarm_sitl.config.load import parse_config

    data = yaml.safe_load((CONFIGS / "paper.yaml").read_text())
    data["vehicle"].update(drag_Ns2pm2=0.02, max_rate_rps=[4.0, 5.0, 6.0], failsafe_action="land")
    before = {
        f.id: dataclasses.asdict(parse_config(data).vehicle_config(f.id)) for f in config("paper").followers
    }
    fields = [
        (f.name, f.type, dataclasses.field(default=f.default, default_factory=f.default_factory))
        for f in dataclasses.fields(VehicleConfig)
    ]
    fields.insert(at, ("added_m", float, dataclasses.field(default=1.5)))
    monkeypatch.setattr(vehicle_config, "VehicleConfig", dataclasses.make_dataclass("VehicleConfig", fields))
    for value in (None, 2.5):
        cfg = parse_config(
            data if value is None else {**data, "vehicle": {**data["vehicle"], "added_m": value}}
        )
        for f in cfg.followers:
            got = cfg.vehicle_config(f.id)
            assert got.added_m == (1.5 if value is None else value)
            assert {k: v for k, v in dataclasses.asdict(got).items() if k != "added_m"} == before[f.id]


@pytest.mark.unit
@pytest.mark.parametrize("seed", [0, 7])
def test_still_air_and_true_reports_reach_the_vehicle_as_no_model_at_all(seed):
    """A wind or sensor section that is absent, or present with nothing in it (a seed, zeros), is
    no model in any follower's spec: the vehicle draws nothing and computes nothing for it."""
    from swarm_sitl.config.load import parse_config

    for wind, sensors in (None, None), ({"seed": seed, "gust_mps": 0.0}, {"seed": seed, "latency_s": 0.0}):
        data = yaml.safe_load((CONFIGS / "paper.yaml").read_text())
        if wind is not None:
            data["wind"], data["vehicle"]["sensors"] = wind, sensors
        cfg = parse_config(data)
        for f in cfg.followers:
            spec = cfg.vehicle_config(f.id)
            assert spec.wind is None and spec.sensors is None, (wind, sensors)


@pytest.mark.unit
def test_a_models_parameters_and_a_followers_autopilot_reach_its_vehicle():
    from swarm_sitl.config.load import parse_config

    data = yaml.safe_load((CONFIGS / "paper.yaml").read_text())
    data["vehicle"].update(model="px4_quad_x", params={"T_TAU_S": 0.05, "MC_ROLL_P": 5})
    data["followers"][1]["autopilot"] = "ardupilot"
    cfg = parse_config(data)
    specs = {f.id: cfg.vehicle_config(f.id) for f in cfg.followers}
    assert all(s.params == {"T_TAU_S": 0.05, "MC_ROLL_P": 5.0} for s in specs.values())
    assert all(type(x) is float for s in specs.values() for x in s.params.values())
    assert [s.autopilot for s in specs.values()] == ["px4", "ardupilot", "px4", "px4"]


@pytest.mark.unit
def test_a_model_written_against_the_names_before_still_imports_them():
    """``VehicleSpec`` and ``VehicleSpecError`` from ``sim_vehicles.models.spec`` (a user's model
    of before imports them) are the vehicle's config and its error under their names before."""
    from sim_vehicles.models import spec, vehicle_config

    assert spec.VehicleSpec is vehicle_config.VehicleConfig
    assert spec.VehicleSpecError is vehicle_config.VehicleConfigError


#: a refusal that names another field than the one changed, where the two are judged together
COUPLED = {"max_thrust_N": ("mass_kg", "g_mps2")}  # (the thrust must exceed the weight)

_json = st.recursive(
    st.none() | st.booleans() | st.integers(-10, 10) | st.floats(allow_nan=False) | st.text(max_size=5),
    lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=5), inner, max_size=4),
    max_leaves=8,
)


@pytest.mark.unit
@settings(max_examples=300, deadline=None)
@given(
    name=st.sampled_from([f.name for f in dataclasses.fields(VehicleConfig)]),
    value=_json,
    inner=st.sampled_from(["", "mean_mps", "gust_mps", "seed", "model", "latency_s", "T_TAU_S"]),
)
def test_any_json_value_of_any_field_is_a_vehicle_or_one_line_naming_the_field(name, value, inner):
    """A vehicle's JSON file written by hand: whatever JSON a field (or a section's field) holds,
    the vehicle reads it or refuses it in one line that names that field; never another error."""
    data = json.loads(VehicleConfig().to_json())
    data[name] = {inner: value} if inner and name in ("wind", "sensors", "params") else value
    try:
        VehicleConfig.from_json(json.dumps(data))
    except VehicleConfigError as e:
        said = str(e)
        assert "\n" not in said and said.startswith("vehicle config: "), said
        assert said.startswith(f"vehicle config: {name}") or name in COUPLED.get(
            said.split(":")[1].strip(), ()
        ), said


@pytest.mark.unit
@pytest.mark.parametrize(
    ("data", "said"),
    [
        ({"model": 3}, "model: must be a string, got 3"),
        ({"autopilot": None}, "autopilot: must be a string, got None"),
        ({"mass_kg": "heavy"}, "mass_kg: must be a number, got 'heavy'"),
        ({"mass_kg": True}, "mass_kg: must be a number, got True"),
        ({"position_m": 1.0}, "position_m: must be a list of 3 numbers, got 1.0"),
        ({"wind": {"gusty": 1, "calm": 2}}, "wind: unknown field(s) calm, gusty"),
        ({"sensors": {"latency_s": "x"}}, "sensors.latency_s: must be a number, got 'x'"),
        ({"wind": {"mean_mps": [1, 2, "a"]}}, "wind: mean_mps must be 3 finite numbers, got (1, 2, 'a')"),
        ({"fast": 1, "heavy": 2}, "unknown field(s) fast, heavy"),
        ({"wind": {"\n": None}}, "wind: unknown field(s) '\\n'"),  # a name that is no name: quoted
        ({"params": {"top speed": "x"}}, "params: 'top speed': must be a finite number, got 'x'"),
        ({"params": None}, "params: must be a mapping of parameter names to numbers, got None"),
        ({"position_m": [True, 0, 0]}, "position_m: must be 3 finite numbers, got (True, 0, 0)"),  # (no bool)
        ({"wind": None, "sensors": None, "max_rate_rps": None}, None),  # (these three may be null)
    ],
)
def test_a_json_value_of_another_kind_than_its_field_is_one_line_saying_what_it_must_be(data, said):
    """A vehicle's JSON written by hand: each refusal whole, as the user reads it."""
    if said is None:
        VehicleConfig.from_json(json.dumps(data))
        return
    with pytest.raises(VehicleConfigError) as e:
        VehicleConfig.from_json(json.dumps(data))
    assert str(e.value) == f"vehicle config: {said}"
