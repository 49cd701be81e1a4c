"""What a vehicle answers whoever asks, as PX4 and ArduCopter do: a PING request echoed to its
sender, MAVLink FTP refused with a NAK (no file system), an empty mission list, a parameter read
by index or by name, all addressed to the system and component that asked. The endpoint is driven
in process (its datagram handler); what it sends is parsed back with pymavlink."""

import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from pymavlink.dialects.v20 import common as mav

from sim_vehicles.mavlink import px4_profile as px4
from sim_vehicles.vehicle.autopilots import PROFILES
from sim_vehicles.vehicle.endpoint import VehicleEndpoint
from sim_vehicles.vehicle.services import COMMAND_PARAMS
from tests.fakes import answers, recording_endpoint

pytestmark = pytest.mark.integration  # (an endpoint driven in process)
SYS = 3
PEER = ("127.0.0.1", 40001)
#: MAVLink FTP (https://mavlink.io/en/services/ftp.html): payload bytes of a request and a reply
FTP_SEQ, FTP_SESSION, FTP_OPCODE, FTP_SIZE, FTP_REQ_OPCODE, FTP_DATA = 0, 2, 3, 4, 5, 12
FTP_NAK, FTP_OPEN_FILE_RO, ERR_FILE_NOT_FOUND, ERR_UNKNOWN_COMMAND = 129, 4, 10, 7


@pytest.fixture(scope="module", params=sorted(PROFILES))  # (the answers change no state)
def vehicle(request):
    ep = recording_endpoint(SYS, profile=PROFILES[request.param])
    yield ep
    ep.close()


def _ask(ep: VehicleEndpoint, msg, sysid: int, compid: int) -> list:
    return answers(ep, msg, sysid, compid, PEER)


senders = st.tuples(st.integers(1, 255), st.integers(0, 255))


@settings(max_examples=40, deadline=None)
@given(senders, st.integers(0, 2**64 - 1), st.integers(0, 2**32 - 1), st.integers(1, 255))
def test_a_ping_request_is_echoed_to_its_sender_and_a_ping_reply_is_not_answered(
    vehicle, sender, time_usec, seq, target
):
    (answer,) = _ask(vehicle, mav.MAVLink_ping_message(time_usec, seq, 0, 0), *sender)
    assert answer.get_type() == "PING"
    assert (answer.time_usec, answer.seq) == (time_usec, seq)
    assert (answer.target_system, answer.target_component) == sender
    assert _ask(vehicle, mav.MAVLink_ping_message(time_usec, seq, target, 1), *sender) == []


@settings(max_examples=40, deadline=None)
@given(senders, st.integers(0, 255))
def test_a_mission_list_request_is_answered_with_no_items_of_its_type(vehicle, sender, mission_type):
    (answer,) = _ask(vehicle, mav.MAVLink_mission_request_list_message(SYS, 1, mission_type), *sender)
    assert answer.get_type() == "MISSION_COUNT" and answer.count == 0
    assert (answer.target_system, answer.target_component) == sender
    assert answer.mission_type == mission_type


@settings(max_examples=40, deadline=None)
@given(senders, st.integers(0, 0xFFFF), st.integers(0, 255), st.integers(0, 255))
def test_any_ftp_request_gets_a_nak_to_its_sender(vehicle, sender, seq, session, opcode):
    """A NAK with the request's sequence + 1, its session and opcode, one data byte:
    FileNotFound to an open, UnknownCommand to anything else."""
    payload = [seq & 0xFF, seq >> 8, session, opcode] + [0] * 247
    (answer,) = _ask(vehicle, mav.MAVLink_file_transfer_protocol_message(0, SYS, 1, payload), *sender)
    assert answer.get_type() == "FILE_TRANSFER_PROTOCOL"
    assert (answer.target_system, answer.target_component) == sender
    p = bytes(answer.payload)
    assert p[FTP_SEQ] | p[FTP_SEQ + 1] << 8 == (seq + 1) % 0x10000
    assert (p[FTP_SESSION], p[FTP_OPCODE], p[FTP_SIZE], p[FTP_REQ_OPCODE]) == (session, FTP_NAK, 1, opcode)
    assert p[FTP_DATA] == (ERR_FILE_NOT_FOUND if opcode == FTP_OPEN_FILE_RO else ERR_UNKNOWN_COMMAND)


@settings(max_examples=20, deadline=None)
@given(senders, st.data())
def test_a_parameter_is_read_by_its_index_or_its_name_as_the_list_gives_it(vehicle, sender, data):
    """PARAM_REQUEST_LIST gives every parameter with its index and the count; reading index i
    gives the i-th, by name (index -1) the same; an index past the end or an unknown name, nothing."""
    listed = _ask(vehicle, mav.MAVLink_param_request_list_message(SYS, 1), *sender)
    n = len(listed)
    assert n > 0 and [m.param_index for m in listed] == list(range(n))
    assert all(m.param_count == n for m in listed)
    i = data.draw(st.integers(0, n - 1))
    (by_index,) = _ask(vehicle, mav.MAVLink_param_request_read_message(SYS, 1, b"", i), *sender)
    assert (by_index.param_id, by_index.param_index) == (listed[i].param_id, i)
    name = listed[i].param_id.encode()
    (by_name,) = _ask(vehicle, mav.MAVLink_param_request_read_message(SYS, 1, name, -1), *sender)
    assert (by_name.param_id, by_name.param_value, by_name.param_index) == (
        listed[i].param_id,
        listed[i].param_value,
        i,
    )
    past = data.draw(st.integers(n, 0x7FFF))
    assert _ask(vehicle, mav.MAVLink_param_request_read_message(SYS, 1, b"", past), *sender) == []
    assert _ask(vehicle, mav.MAVLink_param_request_read_message(SYS, 1, b"NO_SUCH_PARAM", -1), *sender) == []


#: commands a ground station or a controller sends (the vehicle's, and one it does not have)
COMMANDS = [*COMMAND_PARAMS, mav.MAV_CMD_NAV_TAKEOFF]
param = st.one_of(st.floats(-300, 300), st.sampled_from([0.0, 1.0, 4.0, 6.0, 21196.0, 32.0]))


@settings(max_examples=60, deadline=None)
@given(senders, st.sampled_from(COMMANDS), st.lists(param, min_size=7, max_size=7), st.data())
def test_every_command_is_acknowledged_once_to_its_sender_and_each_refusal_counted_once(
    vehicle, sender, command, params, data
):
    """Whatever the command and its parameters (an optional one NaN, MAVLink's "unused"): one
    COMMAND_ACK of it to its sender (progress 0), before anything it asks for; a command it does
    not have counted unhandled, a refused one (DENIED, FAILED) invalid, once each."""
    for j in COMMAND_PARAMS.get(command, ((), ()))[1]:
        if data.draw(st.booleans()):
            params[j] = math.nan
    before = (vehicle.stats.rx_invalid, vehicle.stats.rx_unhandled)
    answers = _ask(vehicle, mav.MAVLink_command_long_message(SYS, 1, command, 0, *params), *sender)
    acks = [m for m in answers if m.get_type() == "COMMAND_ACK"]
    assert len(acks) == 1 and answers[0] is acks[0], [m.get_type() for m in answers]
    (ack,) = acks
    assert ack.command == command and (ack.target_system, ack.target_component) == sender
    assert ack.progress == 0 and ack.result_param2 == 0
    invalid = vehicle.stats.rx_invalid - before[0]
    unhandled = vehicle.stats.rx_unhandled - before[1]
    assert unhandled == (1 if ack.result == mav.MAV_RESULT_UNSUPPORTED else 0)
    assert invalid == (1 if ack.result in (mav.MAV_RESULT_DENIED, mav.MAV_RESULT_FAILED) else 0)


@settings(max_examples=20, deadline=None)
@given(senders)
def test_a_command_that_asks_for_a_message_gets_it_after_its_ack(vehicle, sender):
    asks = [
        (mav.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES, (1.0,), "AUTOPILOT_VERSION"),
        (mav.MAV_CMD_GET_HOME_POSITION, (), "HOME_POSITION"),
        (mav.MAV_CMD_REQUEST_MESSAGE, (float(mav.MAVLINK_MSG_ID_SYS_STATUS),), "SYS_STATUS"),
    ]
    for command, params, wanted in asks:
        p = [*params, 0, 0, 0, 0, 0, 0, 0][:7]
        answers = _ask(vehicle, mav.MAVLink_command_long_message(SYS, 1, command, 0, *p), *sender)
        assert [m.get_type() for m in answers] == ["COMMAND_ACK", wanted]
        assert answers[0].result == mav.MAV_RESULT_ACCEPTED


def test_px4_takes_its_auto_sub_modes_by_param3():
    """DO_SET_MODE with PX4's AUTO main mode and a sub mode in param3 (AUTO.LOITER): taken, and
    its HEARTBEAT says so."""
    ep = recording_endpoint(SYS, profile=PROFILES["px4"])
    try:
        custom = float(mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED)
        params = (custom, float(px4.MAIN_AUTO), float(px4.SUB_AUTO_LOITER), 0, 0, 0, 0)
        (ack,) = _ask(
            ep, mav.MAVLink_command_long_message(SYS, 1, mav.MAV_CMD_DO_SET_MODE, 0, *params), 255, 190
        )
        assert ack.result == mav.MAV_RESULT_ACCEPTED and ep.flight.number == px4.HOLD
    finally:
        ep.close()
