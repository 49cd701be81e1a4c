"""The three plug-in points state their contracts one way (a ``Protocol``: ``laws.contract.Law``,
``plant.contract.VehicleModel``, ``faults.link_model.LinkModel``) and hold a plug-in to what the
protocol itself declares (``sim_vehicles.common.contract``): every built-in meets its protocol,
and a plug-in lacking any one member is refused naming exactly that member."""

import math
import typing
from typing import ClassVar

import numpy as np
import pytest

from sim_vehicles.common.contract import missing_members, protocol_members
from sim_vehicles.models.build import MODELS, build_vehicle
from sim_vehicles.models.vehicle_config import VehicleConfig
from sim_vehicles.plant.contract import VehicleModel
from sim_vehicles.plant.px4_params import BY_NAME
from swarm_sitl.config.law_entry import LawEntryError, check_contract, resolve
from swarm_sitl.config.schema import PAPER_LAW
from swarm_sitl.faults.link_model import LinkModel
from swarm_sitl.faults.link_models import LINK_MODELS
from swarm_sitl.laws.contract import Law

pytestmark = pytest.mark.unit

PROTOCOLS = [Law, VehicleModel, LinkModel]


@pytest.mark.parametrize("protocol", PROTOCOLS, ids=lambda p: p.__name__)
def test_a_protocols_members_are_what_pythons_typing_finds_in_it(protocol):
    """An independent reference: ``typing``'s own reading of a protocol's members (what
    ``isinstance`` checks a runtime-checkable protocol by; private in Python 3.11, public as
    ``typing.get_protocol_members`` from 3.13)."""
    reference = getattr(typing, "get_protocol_members", None) or typing._get_protocol_attrs
    names = protocol_members(protocol)
    assert set(names) == set(reference(protocol)) and len(names) == len(set(names)) and names


@pytest.mark.parametrize("protocol", PROTOCOLS, ids=lambda p: p.__name__)
def test_a_plug_in_lacking_one_member_is_missing_exactly_that_one(protocol):
    names = protocol_members(protocol)
    for left_out in names:
        stub = type("Stub", (), {n: None for n in names if n != left_out})
        assert missing_members(stub, protocol) == [left_out]
    assert missing_members(type("Whole", (), dict.fromkeys(names)), protocol) == []


def test_every_built_in_meets_its_protocol():
    for key, model in LINK_MODELS.items():
        assert missing_members(model, LinkModel) == [], key
    for name in MODELS:
        vehicle = build_vehicle(VehicleConfig(model=name), 1)
        assert missing_members(vehicle, VehicleModel) == [], name
    assert missing_members(resolve(PAPER_LAW), Law) == []


def test_every_built_in_vehicle_takes_a_parameter_exactly_when_it_serves_it_and_the_value_is_in_range():
    """``set_param(name, value)`` is True exactly for a name among the model's ``tunables`` and a
    value within that parameter's range, ends included (``px4_params``: the built-in models'
    parameters are PX4's); then ``tunables`` holds the value, else nothing changes. Each built-in
    model, each name it serves and one it does not, values inside, at the ends, outside and nan."""
    rng = np.random.default_rng(7)
    for model in MODELS:
        vehicle = build_vehicle(VehicleConfig(model=model), 1)
        for name in [*vehicle.tunables, "NOT_A_PARAM", "MC_ROLLRATE_P_"]:
            p = BY_NAME.get(name)
            low, high = (p.low, p.high) if p is not None else (0.0, 1.0)
            span = high - low
            values = [low, high, rng.uniform(low, high), low - span - 1, high + span + 1, math.nan]
            for value in values:
                before = dict(vehicle.tunables)
                expected = name in before and low <= value <= high
                assert vehicle.set_param(name, value) is expected, (model, name, value)
                assert vehicle.tunables == ({**before, name: value} if expected else before), (model, name)


def test_a_law_lacking_its_step_is_one_line_naming_it():
    class NoStep:
        message_length = 3
        record_fields: ClassVar[dict] = {}

    with pytest.raises(LawEntryError, match=r"no step\(t_s, sample, inbox\) method$"):
        check_contract(NoStep, "mine.py:NoStep")
    NoStep.step = np.zeros  # (anything callable)
    check_contract(NoStep, "mine.py:NoStep")
