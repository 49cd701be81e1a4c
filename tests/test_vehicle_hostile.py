"""Hostile input at a vehicle's MAVLink endpoint: nothing crashes it, moves it or takes its link.

The fuzz tests drive the endpoint's datagram handler in process (the socket only adds the kernel),
one datagram per input, and check after each: no exception, nothing the vehicle flies or streams
changed, and the input counted among what it refused. ``SWARM_SITL_FUZZ_EXAMPLES`` sets the
number of inputs per test (the default run uses a few hundred; the closing figures used 100,000:
``SWARM_SITL_FUZZ_EXAMPLES=100000 python -m pytest tests/test_vehicle_hostile.py -k fuzz``).
"""

import math
import socket
import time

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from pymavlink.dialects.v20 import common as mav

from sim_vehicles.common.state import make_state
from sim_vehicles.mavlink.enu_ned import q_enu_flu_to_ned_frd, q_ned_frd_to_enu_flu
from sim_vehicles.plant.autopilot import Autopilot
from sim_vehicles.plant.params import AttitudeGains, VehicleParams
from sim_vehicles.vehicle import services
from sim_vehicles.vehicle.endpoint import VehicleEndpoint
from sim_vehicles.vehicle.modes import MODE_OFFBOARD
from sim_vehicles.vehicle.port import PEER_SILENT_S
from sim_vehicles.vehicle.services import COMMAND_PARAMS
from tests.strategies import FUZZ, FUZZ_TIMEOUT, unit_quaternions
from tests.support import raw_frame, start_vehicle

SYS = 3
PEER = ("127.0.0.1", 40001)
STRANGER = ("127.0.0.1", 40002)
PARAMS = VehicleParams(0.85, (0.05, 0.05, 0.09), 25.0)


def _link(sysid: int = SYS, compid: int = 191) -> mav.MAVLink:
    m = mav.MAVLink(None, srcSystem=sysid, srcComponent=compid)
    m.robust_parsing = True
    return m


def _frame(msg: mav.MAVLink_message, sysid: int = SYS) -> bytes:
    return bytes(msg.pack(_link(sysid)))


def _setpoint(q=(1.0, 0.0, 0.0, 0.0), rates=(0.0, 0.0, 0.0), thrust=0.4, target=SYS, component=1) -> bytes:
    return _frame(mav.MAVLink_set_attitude_target_message(0, target, component, 0, list(q), *rates, thrust))


def _command(command: int, *params: float, target=SYS) -> bytes:
    p = [*params, 0, 0, 0, 0, 0, 0, 0][:7]
    return _frame(mav.MAVLink_command_long_message(target, 1, command, 0, *p))


@pytest.fixture
def flying():
    """A vehicle armed in offboard, flying a valid setpoint from ``PEER``."""
    ap = Autopilot(PARAMS, AttitudeGains(16.0, 16.0), make_state([0.0, 0.0, 10.0]), 0.001)
    ep = VehicleEndpoint(ap, SYS)
    ep.port.sock.close()  # driven in process: what it sends goes nowhere
    ep.port.sock = _NullSocket()
    ep.datagram(_command(mav.MAV_CMD_COMPONENT_ARM_DISARM, 1), PEER)
    ep.datagram(_setpoint(thrust=0.35), PEER)  # PX4's rule: a stream before OFFBOARD
    ep.datagram(_command(mav.MAV_CMD_DO_SET_MODE, 29, 6, 0), PEER)
    ep.datagram(_setpoint(thrust=0.35), PEER)
    assert ep.armed and ep.mode == MODE_OFFBOARD and ep.stats.setpoints == 2
    yield ep
    ep.close()


class _NullSocket:
    def sendto(self, data: bytes, addr: object) -> int:
        return len(data)

    def close(self) -> None:
        pass


def _held(ep: VehicleEndpoint) -> tuple:
    """What the vehicle flies, streams and answers to: unchanged by anything it refuses."""
    c = ep.autopilot.command
    return (
        tuple(np.asarray(c.q_c).tolist()),
        float(c.thrust_N),
        tuple(np.asarray(c.omega_c_B).tolist()),
        tuple(ep.autopilot.state.tolist()),
        ep.armed,
        ep.mode,
        ep.port.peer,
        tuple(sorted(ep.params.items())),
        tuple(sorted(ep.port.streams.rate_hz.items())),
        tuple(ep.autopilot.max_rate_rps.tolist()),
    )


def _refused(ep: VehicleEndpoint) -> int:
    s = ep.stats
    return s.rx_bad + s.rx_refused + s.rx_invalid + s.rx_unhandled


def _assert_refused(ep: VehicleEndpoint, data: bytes, addr=PEER) -> None:
    before, n0 = _held(ep), _refused(ep)
    ep.datagram(data, addr)
    ep.flush()
    assert ep.stats.handler_errors == 0, ep.stats.last_handler_error
    assert _held(ep) == before
    assert _refused(ep) > n0


# -- what the issue found, one by one ------------------------------------------------------------

NAN, INF = math.nan, math.inf


@pytest.mark.parametrize(
    "data",
    [
        _command(mav.MAV_CMD_DO_SET_MODE, 1, NAN),
        _command(mav.MAV_CMD_DO_SET_MODE, 1, INF),
        _command(mav.MAV_CMD_SET_MESSAGE_INTERVAL, NAN, 1e4),
        _command(mav.MAV_CMD_SET_MESSAGE_INTERVAL, 32, NAN),
        _command(mav.MAV_CMD_SET_MESSAGE_INTERVAL, INF, -INF),
        _command(mav.MAV_CMD_REQUEST_MESSAGE, NAN),
        _command(mav.MAV_CMD_DO_SET_MODE, 1, 7),  # a mode it does not have
        _command(mav.MAV_CMD_COMPONENT_ARM_DISARM, 0),  # disarm in flight, not forced
        _setpoint(thrust=-1.0),
        _setpoint(thrust=2.0),
        _setpoint(thrust=NAN),
        _setpoint(rates=(NAN, 0, 0)),
        _setpoint(rates=(0, INF, 0)),
        _setpoint(q=(2.0, 0.0, 0.0, 0.0)),
        _setpoint(q=(0.0, 0.0, 0.0, 0.0)),
        _setpoint(q=(NAN, 0.0, 0.0, 0.0)),
        _setpoint(target=SYS + 1),
        _setpoint(component=2),
        _frame(mav.MAVLink_param_set_message(SYS, 1, b"MASS_KG", 100.0, mav.MAV_PARAM_TYPE_REAL32)),
        _frame(mav.MAVLink_param_set_message(SYS, 1, b"SP_TIMEOUT_S", NAN, mav.MAV_PARAM_TYPE_REAL32)),
        _frame(mav.MAVLink_param_set_message(SYS, 1, b"MC_ROLLRATE_MAX", 1e30, mav.MAV_PARAM_TYPE_REAL32)),
        _frame(mav.MAVLink_param_set_message(SYS, 1, b"NO_SUCH", 1.0, mav.MAV_PARAM_TYPE_REAL32)),
        _frame(mav.MAVLink_system_time_message(0, 0)),  # a message it does not handle
        _setpoint()[:-3],  # cut short
        b"\xfd\x09garbage-not-mavlink" * 5,
    ],
    ids=lambda d: d[:12].hex(),
)
@pytest.mark.integration
def test_each_bad_input_is_refused_counted_and_changes_nothing(flying, data):
    _assert_refused(flying, data)


@pytest.mark.integration
def test_a_stranger_is_refused_and_cannot_take_the_telemetry(flying):
    for data in (
        _command(mav.MAV_CMD_COMPONENT_ARM_DISARM, 0, 21196),  # even a forced disarm
        _command(mav.MAV_CMD_DO_SET_MODE, 1, 0),
        _setpoint(thrust=0.9),
        _frame(mav.MAVLink_heartbeat_message(6, 8, 0, 0, 0, 3)),
    ):
        _assert_refused(flying, data, STRANGER)
    assert flying.port.peer == PEER


@pytest.mark.integration
def test_a_silent_peer_gives_the_link_up(flying, monkeypatch):
    """Its controller died: after ``PEER_SILENT_S`` another address may take the link, with a
    message the vehicle knows (one it does not know claims nothing)."""
    now = time.monotonic()
    monkeypatch.setattr(time, "monotonic", lambda: now + PEER_SILENT_S + 0.1)
    flying.datagram(_frame(mav.MAVLink_system_time_message(0, 0)), STRANGER)  # one it does not use
    assert flying.port.peer == PEER and flying.stats.rx_unhandled == 1
    flying.datagram(_setpoint(thrust=0.5), STRANGER)
    assert flying.port.peer == STRANGER and flying.autopilot.command.thrust_N == pytest.approx(0.5 * 25.0)


@pytest.mark.integration
def test_a_forced_disarm_and_a_settable_parameter_are_taken(flying):
    flying.datagram(
        _frame(mav.MAVLink_param_set_message(SYS, 1, b"MC_PITCHRATE_MAX", 90.0, mav.MAV_PARAM_TYPE_REAL32)),
        PEER,
    )
    assert flying.autopilot.max_rate_rps[1] == pytest.approx(math.radians(90.0))
    flying.datagram(_command(mav.MAV_CMD_COMPONENT_ARM_DISARM, 0, 21196), PEER)
    assert not flying.armed


@pytest.mark.integration
def test_body_rates_are_clipped_to_the_rate_limits_and_the_state_stays_finite(flying):
    """1e30 rad/s (finite as float32) used to leave the state non-finite for good; 50 rad/s
    tumbled it. Clipped to MC_*RATE_MAX, the body rates stay near the limit."""
    limit = flying.autopilot.max_rate_rps
    for rates in ((1e30, -1e30, 1e30), (50.0, 50.0, -50.0)):
        flying.datagram(_setpoint(rates=rates, thrust=0.34), PEER)
        for _ in range(20):
            flying.step(50)
            w = flying.autopilot.state[10:13]
            assert np.all(np.isfinite(flying.autopilot.state))
            # the loop tracks the clipped rates (with its attitude term on top: the command
            # attitude stands still while its rates say it turns)
            assert np.all(np.abs(w) <= 2 * limit), w


@pytest.mark.integration
@settings(max_examples=80, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    unit_quaternions(),
    st.tuples(*[st.floats(-2.0, 2.0)] * 3),
    st.floats(0.05, 0.9),
    st.integers(0, 0b1100_0111).filter(lambda m: m & 0b0011_1000 == 0 and m != 0b1100_0111),
)
def test_px4_takes_each_field_its_mask_does_not_ignore_and_holds_or_zeroes_the_rest(
    flying, q, rates, thrust, mask
):
    """A SET_ATTITUDE_TARGET with any of PX4's ignore bits (not all: a clock-only one): the
    attitude held if ignored, else the one sent (NED/FRD to ENU/FLU); the thrust held if ignored,
    else the field of full thrust; each body rate whose bit is set not given (0), the others the
    sent ones (FRD to FLU). Counted as a setpoint either way."""
    held = flying.autopilot.command
    before = flying.stats.setpoints
    ned_q = q_enu_flu_to_ned_frd(np.array(q))
    flying.datagram(
        _frame(mav.MAVLink_set_attitude_target_message(0, SYS, 1, mask, list(ned_q), *rates, thrust)), PEER
    )
    cmd = flying.autopilot.command
    assert flying.stats.setpoints == before + 1
    f32 = np.float32
    if mask & 0b1000_0000:
        assert np.array_equal(cmd.q_c, held.q_c)
    else:
        sent = q_ned_frd_to_enu_flu(np.array([float(f32(x)) for x in ned_q]))
        assert np.allclose(cmd.q_c, sent, atol=1e-6) or np.allclose(cmd.q_c, -sent, atol=1e-6)
    want_T = held.thrust_N if mask & 0b0100_0000 else float(f32(thrust)) * PARAMS.max_thrust_N
    assert cmd.thrust_N == pytest.approx(want_T, rel=1e-12)
    frd = [0.0 if mask & (1 << axis) else float(f32(r)) for axis, r in enumerate(rates)]
    assert np.allclose(cmd.omega_c_B, [frd[0], -frd[1], -frd[2]], rtol=0, atol=1e-12)


# -- fuzzing ---------------------------------------------------------------------------------------

_MESSAGES = [cls for cls in mav.mavlink_map.values() if cls.id < 10000]
_floats = st.floats(allow_nan=True, allow_infinity=True, width=32)


@st.composite
def hostile_datagrams(draw) -> bytes:
    """Random bytes; a valid frame cut short or with bytes flipped; a valid setpoint or command
    with a value the vehicle must refuse; a frame for another system; an unhandled message."""
    kind = draw(st.sampled_from(["bytes", "cut", "flipped", "setpoint", "command", "elsewhere", "other"]))
    if kind == "bytes":
        return draw(st.binary(min_size=0, max_size=300))
    if kind in ("cut", "flipped"):
        good = _setpoint(thrust=draw(st.floats(0, 1)))
        if kind == "cut":
            return good[: draw(st.integers(0, len(good) - 1))]
        at = draw(st.integers(0, len(good) - 1))
        flip = draw(st.integers(1, 255))
        return good[:at] + bytes([good[at] ^ flip]) + good[at + 1 :]
    if kind == "setpoint":  # at least one refused value
        q = [draw(_floats) for _ in range(4)]
        rates = [draw(_floats) for _ in range(3)]
        thrust = draw(_floats)
        bad = draw(st.sampled_from(["q", "rate", "thrust"]))
        if bad == "q":
            q[0] = draw(st.sampled_from([NAN, INF, 2.0, 1e20]))  # 0.0 with a unit (x, y, z) is one
        elif bad == "rate":
            rates[draw(st.integers(0, 2))] = draw(st.sampled_from([NAN, INF, -INF]))
        else:
            thrust = draw(
                st.one_of(st.sampled_from([NAN, INF, -INF]), st.floats(1.0001, 1e30), st.floats(-1e30, -1e-6))
            )
        return _frame(mav.MAVLink_set_attitude_target_message(0, SYS, 1, 0, q, *rates, thrust))
    if kind == "command":  # a non-finite parameter, or a command it does not have
        command = draw(st.sampled_from([*COMMAND_PARAMS, draw(st.integers(0, 65535))]))
        params = [draw(_floats) for _ in range(7)]
        if command in COMMAND_PARAMS:  # a parameter it reads: non-finite (an optional one: infinite)
            used, optional = COMMAND_PARAMS[command]
            if not used:  # it reads none: an unhandled command instead
                command = 7
            else:
                j = draw(st.sampled_from([*used, *optional]))
                params[j] = draw(st.sampled_from([INF, -INF] if j in optional else [NAN, INF, -INF]))
        return _command(command, *params)
    if kind == "elsewhere":
        target = draw(st.integers(0, 255).filter(lambda t: t not in (0, SYS)))
        return _setpoint(target=target, thrust=0.5)
    cls = draw(st.sampled_from(_MESSAGES))
    if cls.id in _HANDLED:
        cls = mav.MAVLink_system_time_message
    # a frame of ``cls`` with a random payload and a good CRC: counted unhandled (or refused)
    payload = draw(st.binary(min_size=cls.unpacker.size, max_size=cls.unpacker.size))
    return raw_frame(cls, payload, sysid=SYS, compid=191)


_HANDLED = {  # what the vehicle acts on: the other strategies make those hostile
    mav.MAVLINK_MSG_ID_PING,
    mav.MAVLINK_MSG_ID_MISSION_REQUEST_LIST,
    mav.MAVLINK_MSG_ID_FILE_TRANSFER_PROTOCOL,
    mav.MAVLINK_MSG_ID_SET_ATTITUDE_TARGET,
    mav.MAVLINK_MSG_ID_COMMAND_LONG,
    mav.MAVLINK_MSG_ID_PARAM_REQUEST_LIST,
    mav.MAVLINK_MSG_ID_PARAM_REQUEST_READ,
    mav.MAVLINK_MSG_ID_PARAM_SET,
    mav.MAVLINK_MSG_ID_HEARTBEAT,
}


@pytest.mark.integration
@FUZZ_TIMEOUT
@FUZZ
@given(data=hostile_datagrams())
def test_fuzz_vehicle_refuses_and_counts_every_hostile_datagram(flying, data):
    _assert_refused(flying, data)


@pytest.mark.integration
@FUZZ_TIMEOUT
@FUZZ
@given(data=st.binary(min_size=0, max_size=600), sender=st.sampled_from([PEER, STRANGER]))
def test_fuzz_vehicle_survives_random_bytes_from_anyone(flying, data, sender):
    # the peer keeps speaking (a long run of this test would otherwise leave it silent for more
    # than PEER_SILENT_S, and a frame hidden in random bytes may then claim the link, as it should)
    flying.datagram(_frame(mav.MAVLink_heartbeat_message(18, 8, 0, 0, 0, 3)), PEER)
    _assert_refused(flying, data, sender)


@pytest.mark.system
@pytest.mark.light
def test_the_vehicle_process_keeps_flying_after_a_hostile_burst(tmp_path):
    """Across the real socket: a burst of the inputs above, then the vehicle still answers."""

    from pymavlink import mavutil

    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    proc = start_vehicle("--id", SYS, "--port", port, "--duration", "30")
    try:
        assert "listening" in proc.stdout.readline()
        conn = mavutil.mavlink_connection(f"udpout:127.0.0.1:{port}", source_system=SYS, source_component=191)
        conn.mav.heartbeat_send(18, 8, 0, 0, 0)
        assert conn.recv_match(type="HEARTBEAT", blocking=True, timeout=5) is not None
        rng = np.random.default_rng(1)
        for data in [
            _command(mav.MAV_CMD_DO_SET_MODE, 1, NAN),
            _command(mav.MAV_CMD_SET_MESSAGE_INTERVAL, NAN, NAN),
            _command(mav.MAV_CMD_REQUEST_MESSAGE, INF),
            _setpoint(rates=(1e30, 1e30, 1e30)),
        ] + [rng.bytes(int(n)) for n in rng.integers(1, 400, 500)]:
            conn.write(data)
        conn.mav.command_long_send(SYS, 1, mav.MAV_CMD_REQUEST_MESSAGE, 0, 32, 0, 0, 0, 0, 0, 0)
        m = conn.recv_match(type="LOCAL_POSITION_NED", blocking=True, timeout=5)
        assert m is not None and proc.poll() is None
    finally:
        proc.terminate()
        proc.wait(timeout=10)


@pytest.mark.integration
def test_a_handler_that_fails_is_counted_with_its_message_and_error_and_the_vehicle_flies_on(
    flying, monkeypatch
):
    """A bug a message finds in a handler (here: the command service raising) is counted in
    ``handler_errors`` with the message's type and the error kept, once per failure, and the
    vehicle goes on taking setpoints."""

    def broken(*_args) -> None:
        raise ZeroDivisionError("the handler's bug")

    monkeypatch.setattr(services, "on_command", broken)
    for n in (1, 2):
        flying.datagram(_command(mav.MAV_CMD_COMPONENT_ARM_DISARM, 1), PEER)
        assert flying.stats.handler_errors == n
    assert flying.stats.last_handler_error == "COMMAND_LONG: ZeroDivisionError: the handler's bug"
    flying.datagram(_setpoint(thrust=0.5), PEER)
    assert flying.stats.setpoints == 3 and flying.autopilot.command.thrust_N == pytest.approx(0.5 * 25.0)
