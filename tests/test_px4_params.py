"""``px4_quad_x``'s parameters have one declaration (``plant.px4_params``), and everything that
states one follows it: the table in ``docs/vehicles.md``, the model's defaults, the spec's and
PARAM_SET's ranges, the rate limits a spec without ``max_rate_rps`` gets, the parameters the
vehicle serves over MAVLink."""

import math
from pathlib import Path

import numpy as np
import pytest

from sim_vehicles.models.build import build_vehicle
from sim_vehicles.models.vehicle_config import VehicleConfig, VehicleConfigError
from sim_vehicles.plant import px4_params
from sim_vehicles.plant.px4_control import GAINS, RANGES

pytestmark = pytest.mark.unit

DOC = Path(__file__).resolve().parents[1] / "docs" / "vehicles.md"
START = "<!-- px4_params table: python -m sim_vehicles.plant.px4_params -->\n"
END = "<!-- end of the px4_params table -->"


def test_the_docs_table_is_the_declarations():
    text = DOC.read_text()
    assert START in text and END in text
    table = text.split(START, 1)[1].split(END, 1)[0]
    assert table == px4_params.markdown_table(), (
        "docs/vehicles.md's parameter table is out of date: python -m sim_vehicles.plant.px4_params"
    )
    assert px4_params.RELEASE in text and px4_params.changed_after_lines() in text


def _quad(params: dict | None = None, **fields):
    return build_vehicle(VehicleConfig(model="px4_quad_x", params=params or {}, **fields), 1)


def test_the_model_starts_at_the_declared_defaults_and_serves_them_by_name():
    q = _quad()
    assert q.tunables == {p.name: p.default for p in px4_params.PARAMS if p.name in GAINS}
    assert list(GAINS) == [
        p.name for p in px4_params.PARAMS if p.group != "airframe" and p.name not in px4_params.RATE_MAX
    ]
    rate_max = [px4_params.BY_NAME[n].default for n in px4_params.RATE_MAX]
    assert np.degrees(q.max_rate_rps) == pytest.approx(rate_max, rel=1e-12)  # 220, 220, 200
    assert q.tau_s == px4_params.BY_NAME["T_TAU_S"].default and q.motor_model == 0
    # the paper's vehicle keeps its own default: 1800 deg/s
    assert np.degrees(VehicleConfig().max_rate_rps) == pytest.approx([1800.0] * 3)


@pytest.mark.parametrize(
    "p", [p for p in px4_params.PARAMS if p.name not in px4_params.RATE_MAX], ids=lambda p: p.name
)
def test_each_declared_range_is_the_one_the_spec_and_param_set_hold_to(p):
    """Each end of a parameter's range is taken and a step past it refused, by the spec (before
    anything starts) and, for a gain, by PARAM_SET on a running model; a choice takes its values
    only."""
    step = max(abs(p.high - p.low) * 1e-6, 1e-9)
    for ok in (p.low, p.high, p.default):
        if p.choices and ok not in p.choices:
            continue
        _quad({p.name: ok})
    for bad in (p.low - step, p.high + step, *((0.5,) if p.choices else ())):
        with pytest.raises(VehicleConfigError, match=p.name):
            _quad({p.name: bad})
    if p.name in GAINS:
        assert RANGES[p.name] == (p.low, p.high)
        q = _quad()
        assert q.set_param(p.name, p.high) and not q.set_param(p.name, p.high + step)
        assert not q.set_param(p.name, p.low - step) and not q.set_param(p.name, math.nan)


def test_a_rate_limit_given_as_a_param_is_refused_with_where_it_goes():
    with pytest.raises(VehicleConfigError, match="MC_ROLLRATE_MAX is the vehicle's max_rate_rps"):
        _quad({"MC_ROLLRATE_MAX": 300.0})


def test_the_vehicle_serves_every_px4_parameter_at_its_declared_default_and_range():
    from types import SimpleNamespace

    from sim_vehicles.vehicle.autopilots import px4_params as served_params

    q = _quad()
    flight = SimpleNamespace(failsafe_action="hold", setpoint_timeout_s=0.5)
    served = {d.name: d for d in served_params(SimpleNamespace(autopilot=q), flight)}
    for p in px4_params.PARAMS:
        if p.group == "airframe":
            assert p.name not in served  # a vehicle's build is not changed in flight
            continue
        d = served[p.name]
        assert d.value == pytest.approx(p.default, rel=1e-12), p.name
        if p.name in px4_params.RATE_MAX:  # (a gain's range is the model's own: set_param above)
            assert (d.low, d.high) == (p.low, p.high)
