"""PARAM_SET on a vehicle as each autopilot answers it (``vehicle.services`` over
``vehicle.autopilots``' tables), for every parameter it serves and any value: one within the
parameter's range is taken (an integer parameter's rounded) and read back in the parameter's type,
and does what the parameter does (the setpoint timeout, PX4's offboard-loss action); one outside
it, not finite or of another type on PX4 is refused, counted once, and answered with the value
kept. PX4's own three are held to PX4's metadata, stated here: MPC_THR_HOVER 0.1..0.8
(``mc_pos_control``), COM_OBL_RC_ACT's Land (4) and Hold (5) of its values (``commander``), the
offboard-loss timeout up to PX4's 60 s (from 0.05 s: below it our vehicle's 1 kHz tick cannot
tell a loss from the gap between two setpoints; PX4 itself takes 0)."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from pymavlink.dialects.v20 import common as mav

from sim_vehicles.common.state import make_state
from sim_vehicles.mavlink import ardupilot_profile as ap
from sim_vehicles.plant.failsafe import ACTION_HOLD, ACTION_LAND
from sim_vehicles.plant.px4_params import BY_NAME
from sim_vehicles.plant.quad_x import QuadX
from sim_vehicles.vehicle.autopilots import PARAMS_OF, PROFILES
from sim_vehicles.vehicle.endpoint import VehicleEndpoint
from tests.fakes import ENDPOINT_PARAMS as PARAMS
from tests.fakes import answers, recording_endpoint
from tests.support import sih_quad

pytestmark = pytest.mark.integration  # (an endpoint driven in process)
SYS = 3
PEER = ("127.0.0.1", 40002)
PX4_METADATA = {"MPC_THR_HOVER": (0.1, 0.8), "COM_OF_LOSS_T": (0.05, 60.0), "COM_OBL_RC_ACT": (0.0, 5.0)}


def _vehicle(profile: str, action: int = ACTION_HOLD) -> VehicleEndpoint:
    return recording_endpoint(SYS, profile=PROFILES[profile], failsafe_action=action)


def _answers(ep: VehicleEndpoint, msg) -> list:
    """The PARAM_VALUEs a ground station (255, 190) gets back for ``msg``."""
    return [m for m in answers(ep, msg, 255, 190, PEER) if m.get_type() == "PARAM_VALUE"]


def _listed(ep: VehicleEndpoint) -> dict[str, tuple[float, int]]:
    return {
        m.param_id: (m.param_value, m.param_type)
        for m in _answers(ep, mav.MAVLink_param_request_list_message(SYS, 1))
    }


def _f32(x: float) -> float:
    return float(np.float32(x))


@pytest.mark.parametrize("action, served", [(ACTION_LAND, 4.0), (ACTION_HOLD, 5.0)])
def test_px4_serves_its_own_names_in_real32_with_what_the_vehicle_is(action, served):
    ep = _vehicle("px4", action)
    try:
        listed = _listed(ep)
        assert {"MPC_THR_HOVER", "COM_OF_LOSS_T", "COM_OBL_RC_ACT"} | {
            f"MC_{a}RATE_MAX" for a in ("ROLL", "PITCH", "YAW")
        } <= set(listed)
        assert {kind for _, kind in listed.values()} == {
            mav.MAV_PARAM_TYPE_REAL32
        }  # PX4's PARAM_FLOAT: every one
        assert listed["COM_OBL_RC_ACT"][0] == served
        hover = PARAMS.mass_kg * 9.81 / PARAMS.max_thrust_N  # the thrust fraction that holds it up
        assert listed["MPC_THR_HOVER"][0] == pytest.approx(hover, rel=1e-3)
        assert listed[PROFILES["px4"].timeout_param][0] == _f32(ep.flight.setpoint_timeout_s)
    finally:
        ep.close()


def test_ardupilot_serves_its_own_names_in_their_types():
    ep = _vehicle("ardupilot")
    try:
        listed = _listed(ep)
        for name, d in ap.PARAMS.items():
            assert listed[name][1] == d.kind, name
        assert listed["SYSID_THISMAV"][0] == SYS
    finally:
        ep.close()


@settings(max_examples=40, deadline=None)
@given(profile=st.sampled_from(sorted(PROFILES)), data=st.data())
def test_a_param_set_within_its_range_is_taken_and_outside_it_refused_with_the_value_kept(profile, data):
    ep = _vehicle(profile)
    try:
        listed = _listed(ep)
        defs = {d.name: d for d in PARAMS_OF[profile](ep, ep.flight)}
        assert set(defs) == set(listed)
        name = data.draw(st.sampled_from(sorted(listed)))
        kept, kind = listed[name]
        served = (defs[name].low, defs[name].high)
        low, high = PX4_METADATA.get(name, served) if profile == "px4" else served
        where = data.draw(st.sampled_from(["within", "below", "above", "not finite", "another type"]))
        if where == "within":
            lo, hi = max(low, kept - 100), min(high, kept + 100)
            value = data.draw(st.sampled_from([lo, hi]) | st.floats(lo, hi))
        elif where == "below":
            value = low - data.draw(st.floats(1e-3, 10)) if math.isfinite(low) else None
        elif where == "above":
            value = high + data.draw(st.floats(1e-3, 10)) if math.isfinite(high) else None
        elif where == "not finite":
            value = data.draw(st.sampled_from([math.nan, math.inf, -math.inf]))
        else:
            value = kept
        if value is None:  # (no bound on that side)
            return
        send_kind = (
            mav.MAV_PARAM_TYPE_INT32
            if where == "another type" and kind == mav.MAV_PARAM_TYPE_REAL32
            else kind
        )
        if where == "another type" and send_kind == kind:
            return
        sent = (
            value
            if kind == mav.MAV_PARAM_TYPE_REAL32
            else float(round(value))
            if math.isfinite(value)
            else value
        )
        refused_before = ep.stats.rx_invalid
        (answer,) = _answers(ep, mav.MAVLink_param_set_message(SYS, 1, name.encode(), value, send_kind))
        taken = (
            defs[name].writable
            and math.isfinite(sent)
            and low <= sent <= high
            and not (where == "another type" and profile == "px4")
        )
        assert (answer.param_id, answer.param_type) == (name, kind)
        if taken and answer.param_value == _f32(sent):
            assert ep.stats.rx_invalid == refused_before
            if name == PROFILES[profile].timeout_param:
                assert ep.flight.setpoint_timeout_s == pytest.approx(sent, rel=1e-6)
            if name == "COM_OBL_RC_ACT":
                assert ep.flight.failsafe_action == (ACTION_LAND if round(sent) == 4 else ACTION_HOLD)
        else:  # refused: by its range here, or by the model's own (a gain), or a mode it has no meaning for
            assert answer.param_value == kept and ep.stats.rx_invalid == refused_before + 1
            assert not taken or name not in PX4_METADATA or name == "COM_OBL_RC_ACT"
        assert _listed(ep)[name][0] == answer.param_value  # read back: what it answered
    finally:
        ep.close()


#: each autopilot's body-rate limits [deg/s] and their ranges (PX4: MC_*RATE_MAX up to 1800, from 1
#: as ``plant.px4_params`` declares them; ArduPilot: ATC_RATE_*_MAX 0..1080, 0 "no limit")
RATE_LIMITS = {
    "px4": (("MC_ROLLRATE_MAX", "MC_PITCHRATE_MAX", "MC_YAWRATE_MAX"), 1.0, 1800.0),
    "ardupilot": (ap.RATE_MAX, 0.0, 1080.0),
}


@pytest.mark.parametrize("profile", sorted(RATE_LIMITS))
def test_the_rate_limits_are_the_models_in_degrees_each_set_within_its_autopilots_range(profile):
    names, low, high = RATE_LIMITS[profile]
    ep = _vehicle(profile)
    try:
        listed = _listed(ep)
        model = ep.autopilot.max_rate_rps
        for axis, name in enumerate(names):
            shown = math.degrees(model[axis])  # past the range (no limit): ArduPilot's "disabled", 0
            assert listed[name][0] == _f32(shown if shown <= high else 0.0)
            kind = listed[name][1]
            for value, taken in ((high, True), (high + 1.0, False), (low - 1.0, False), (250.0, True)):
                (answer,) = _answers(ep, mav.MAVLink_param_set_message(SYS, 1, name.encode(), value, kind))
                if taken:
                    assert answer.param_value == value and model[axis] == pytest.approx(math.radians(value))
                else:
                    assert answer.param_value == 250.0 or answer.param_value == _f32(high)
        if profile == "ardupilot":  # 0: no limit, the vehicle's largest; served as 0 (past ArduPilot's range)
            (answer,) = _answers(ep, mav.MAVLink_param_set_message(SYS, 1, names[0].encode(), 0.0, kind))
            assert answer.param_value == 0.0 and math.degrees(model[0]) == pytest.approx(1800.0)
            assert _listed(ep)[names[0]][0] == 0.0
    finally:
        ep.close()


@pytest.mark.parametrize("name", sorted(PX4_METADATA))
def test_px4s_own_parameters_take_their_metadatas_range_and_nothing_past_it(name):
    low, high = PX4_METADATA[name]
    ep = _vehicle("px4")
    try:
        real = mav.MAV_PARAM_TYPE_REAL32
        for value in (low, high):
            (answer,) = _answers(ep, mav.MAVLink_param_set_message(SYS, 1, name.encode(), value, real))
            assert answer.param_value == _f32(value)
        for value in (low - 0.01, high + 0.01, high + 1.0):
            (answer,) = _answers(ep, mav.MAVLink_param_set_message(SYS, 1, name.encode(), value, real))
            assert answer.param_value == _f32(high)  # refused: the last taken kept
    finally:
        ep.close()


@settings(max_examples=40, deadline=None)
@given(profile=st.sampled_from(sorted(PROFILES)), data=st.data())
def test_a_models_own_gains_are_served_under_the_autopilots_names_and_set_within_their_ranges(profile, data):
    """``px4_quad_x``'s PX4 gains (the model's ``tunables``): PX4 serves each under its own name,
    ArduPilot under its ATC_ name where it has one (PX4's elsewhere), in REAL32, with the value in
    force; a PARAM_SET within the gain's range (PX4's metadata, ``px4_params``; its bounds as the
    float32 MAVLink carries them, as PX4 compares them) sets the model's gain, one outside it is
    refused, counted, and answered with the gain kept."""
    quad = QuadX(sih_quad(), make_state([0.0, 0.0, 10.0]), 0.001)
    renamed = ap.ATC_NAMES if profile == "ardupilot" else {}
    ep = recording_endpoint(SYS, autopilot=quad, profile=PROFILES[profile])
    try:
        listed = _listed(ep)
        for own, value in quad.tunables.items():
            assert listed[renamed.get(own, own)] == (_f32(value), mav.MAV_PARAM_TYPE_REAL32), own
        own = data.draw(st.sampled_from(sorted(quad.tunables)), label="gain")
        low, high = BY_NAME[own].low, BY_NAME[own].high
        width = high - low
        value = _f32(
            data.draw(
                st.sampled_from([low, high])
                | st.floats(low, high)
                | st.floats(low - width, high + width).filter(lambda v: not low <= v <= high),
                label="value",
            )
        )
        kept = quad.tunables[own]
        refused = ep.stats.rx_invalid
        name = renamed.get(own, own).encode()
        (answer,) = _answers(
            ep, mav.MAVLink_param_set_message(SYS, 1, name, value, mav.MAV_PARAM_TYPE_REAL32)
        )
        taken = _f32(low) <= value <= _f32(high)
        assert quad.tunables[own] == (value if taken else kept)
        assert answer.param_value == _f32(quad.tunables[own])
        assert ep.stats.rx_invalid == refused + (not taken)
        assert _listed(ep)[name.decode()][0] == _f32(quad.tunables[own])
    finally:
        ep.close()
