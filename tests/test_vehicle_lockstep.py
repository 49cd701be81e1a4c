"""The vehicle's clocks, driven over real UDP by a pymavlink client (endpoint in-process)."""

import copy
import operator
import os
import socket
import subprocess
import sys
import threading
import time

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from pymavlink import mavutil
from pymavlink.dialects.v20 import common as mavlink2

from sim_vehicles.common.state import make_state
from sim_vehicles.plant.autopilot import Autopilot
from sim_vehicles.plant.params import AttitudeGains, VehicleParams
from sim_vehicles.plant.sensors import SensorModel
from sim_vehicles.runtime import udp_arrival
from sim_vehicles.runtime.row_log import read_rows
from sim_vehicles.vehicle import lockstep_tick, loops
from sim_vehicles.vehicle.endpoint import VehicleEndpoint
from tests.fakes import ENDPOINT_PARAMS, answers, recording_endpoint
from tests.support import start_vehicle

pytestmark = pytest.mark.integration
mav = mavutil.mavlink


@pytest.fixture
def lockstep(tmp_path):
    params = VehicleParams(0.85, (0.05, 0.05, 0.09), 25.0)
    ap = Autopilot(params, AttitudeGains(16.0, 16.0), make_state([1.0, 2.0, 3.0]), 0.001)
    ep = VehicleEndpoint(ap, 7, lockstep_period_s=0.01, truth_path=tmp_path / "truth.rows")
    conn = mavutil.mavlink_connection(
        f"udpout:127.0.0.1:{ep.address[1]}", source_system=7, source_component=191
    )
    yield ep, conn
    conn.close()
    ep.close()


def _exchange(ep, conn, send, kind=None, n=1):
    """Send, let the vehicle serve it, and collect what comes back."""
    send()
    ep.poll()
    got = []
    while (m := conn.recv_match(blocking=True, timeout=0.5)) is not None:
        got.append(m)
        if kind is not None and sum(x.get_type() == kind for x in got) >= n:
            break
    return got


def _setpoint(conn, ms, thrust=0.85 * 9.81 / 25.0):
    return lambda: conn.mav.set_attitude_target_send(ms, 7, 1, 0, [1.0, 0, 0, 0], 0, 0, 0, thrust)


def test_time_moves_only_with_stamped_setpoints(lockstep):
    ep, conn = lockstep
    arm = lambda: conn.mav.command_long_send(7, 1, mav.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0, 0, 0, 0)  # noqa: E731
    assert any(m.get_type() == "COMMAND_ACK" for m in _exchange(ep, conn, arm, "COMMAND_ACK"))

    def offboard() -> None:  # PX4's rule: a setpoint stream first (clock-only at 0: no step), then OFFBOARD
        conn.mav.set_attitude_target_send(0, 7, 1, 0b1100_0111, [1.0, 0, 0, 0], 0, 0, 0, 0)
        conn.mav.command_long_send(7, 1, mav.MAV_CMD_DO_SET_MODE, 0, 29, 6, 0, 0, 0, 0, 0)

    acks = [m for m in _exchange(ep, conn, offboard, "COMMAND_ACK") if m.get_type() == "COMMAND_ACK"]
    assert acks[-1].result == mav.MAV_RESULT_ACCEPTED and ep.mode == 1
    assert ep.time_boot_ms == 0  # nothing moves without a setpoint
    resends = ep.stats.lockstep_resends

    got = _exchange(ep, conn, _setpoint(conn, 0), "ATTITUDE_QUATERNION")
    lp = [m for m in got if m.get_type() == "LOCAL_POSITION_NED"]
    assert ep.time_boot_ms == 10 and lp[-1].time_boot_ms == 10  # exactly one period

    got = _exchange(ep, conn, _setpoint(conn, 0), "ATTITUDE_QUATERNION")  # a retransmission
    assert ep.time_boot_ms == 10 and ep.stats.lockstep_resends == resends + 1  # answered, not stepped twice
    assert [m.time_boot_ms for m in got if m.get_type() == "LOCAL_POSITION_NED"] == [10]

    bad_before = ep.stats.rx_bad
    _exchange(ep, conn, _setpoint(conn, 500))  # from the future: refused
    assert ep.time_boot_ms == 10 and ep.stats.rx_bad == bad_before + 1


def test_same_setpoints_give_the_same_trajectory_bit_for_bit(tmp_path):
    def fly(path):
        params = VehicleParams(0.85, (0.05, 0.05, 0.09), 25.0)
        ap = Autopilot(params, AttitudeGains(16.0, 16.0), make_state([0.0, 0.0, 0.0]), 0.001)
        ep = VehicleEndpoint(ap, 7, lockstep_period_s=0.01, truth_path=path)
        ep.armed, ep.mode = True, 1
        conn = mavutil.mavlink_connection(f"udpout:127.0.0.1:{ep.address[1]}", source_system=7)
        tilt = np.radians(5)
        for k in range(50):
            conn.mav.set_attitude_target_send(
                10 * k, 7, 1, 0, [np.cos(tilt / 2), np.sin(tilt / 2), 0, 0], 0.1, 0, 0, 0.4
            )
            ep.poll()
        conn.close()
        ep.close()
        return read_rows(path)[1]

    a, b = fly(tmp_path / "a.rows"), fly(tmp_path / "b.rows")
    assert a.shape == (50, 14) and np.array_equal(a, b)
    assert np.allclose(a[:, 0], np.arange(1, 51) * 0.01)


def test_message_interval_and_request_message(lockstep):
    ep, conn = lockstep
    interval = lambda: conn.mav.command_long_send(  # noqa: E731
        7, 1, mav.MAV_CMD_SET_MESSAGE_INTERVAL, 0, mav.MAVLINK_MSG_ID_HIGHRES_IMU, -1, 0, 0, 0, 0, 0
    )
    acks = [m for m in _exchange(ep, conn, interval, "COMMAND_ACK") if m.get_type() == "COMMAND_ACK"]
    assert acks[0].result == mav.MAV_RESULT_ACCEPTED
    request = lambda: conn.mav.command_long_send(  # noqa: E731
        7, 1, mav.MAV_CMD_REQUEST_MESSAGE, 0, mav.MAVLINK_MSG_ID_LOCAL_POSITION_NED, 0, 0, 0, 0, 0, 0
    )
    got = _exchange(ep, conn, request, "LOCAL_POSITION_NED")
    lp = next(m for m in got if m.get_type() == "LOCAL_POSITION_NED")
    assert (lp.x, lp.y, lp.z) == pytest.approx((2.0, 1.0, -3.0))  # ENU (1, 2, 3) in NED
    for k in range(3):
        got = _exchange(ep, conn, _setpoint(conn, 10 * k), "ATTITUDE_QUATERNION")
        assert not any(m.get_type() == "HIGHRES_IMU" for m in got)  # switched off


@pytest.mark.realtime
@pytest.mark.parametrize("stamped", [True, False], ids=["kernel-stamps", "read-on-arrival"])
def test_real_time_setpoint_acts_from_its_arrival_though_read_later(tmp_path, stamped):
    """In offboard the real-time loop reads its socket only at its own instants (up to
    ``RX_EVERY_S`` late); the plant must still switch command at the setpoint's arrival. From
    hover, full thrust gives vz = (T_max/m - g)(t - t_switch): fit t_switch from the true state."""
    if stamped and not sys.platform.startswith("linux"):
        pytest.skip("kernel receive timestamps are Linux only")
    params = VehicleParams(0.85, (0.05, 0.05, 0.09), 25.0)
    ap = Autopilot(params, AttitudeGains(16.0, 16.0), make_state([0.0, 0.0, 50.0]), 0.001)
    ep = VehicleEndpoint(ap, 7, truth_path=tmp_path / "truth.rows")
    conn = mavutil.mavlink_connection(
        f"udpout:127.0.0.1:{ep.address[1]}", source_system=7, source_component=191
    )
    hover = params.hover_thrust_N / params.max_thrust_N
    ep.port.stamped = stamped  # without stamps (other systems) the loop wakes for each datagram
    try:
        conn.mav.command_long_send(7, 1, mav.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0, 0, 0, 0)
        conn.mav.set_attitude_target_send(0, 7, 1, 0b1100_0111, [1.0, 0, 0, 0], 0, 0, 0, 0)  # a stream
        conn.mav.command_long_send(7, 1, mav.MAV_CMD_DO_SET_MODE, 0, 29, 6, 0, 0, 0, 0, 0)  # OFFBOARD
        time.sleep(0.05)
        ep.poll()
        assert ep.armed and ep.mode == 1
        started = []  # the loop's own start, on its thread, right before its clock starts
        done = threading.Event()  # the loop runs until the last setpoint has had time to act
        loop = threading.Thread(
            target=lambda: (started.append(time.monotonic()), ep.run_realtime(stop=done.is_set))
        )
        loop.start()
        while not started:
            time.sleep(0.001)
        start = started[0]
        sent = []  # the full-thrust setpoint's send, bracketed: it arrives between the two
        for i in range(40):  # hover, then full thrust from the 21st setpoint on, every 10 ms
            time.sleep(0.01)
            before = time.monotonic() - start
            conn.mav.set_attitude_target_send(0, 7, 1, 0, [1.0, 0, 0, 0], 0, 0, 0, 1.0 if i >= 20 else hover)
            if i == 20:  # (loopback delivers within sendto; a loaded machine may pause us in it)
                sent = [before, time.monotonic() - start]
        time.sleep(0.2)
        done.set()
        loop.join(5)
        assert not loop.is_alive()
    finally:
        conn.close()
        ep.close()
    _, truth = read_rows(tmp_path / "truth.rows")
    t, vz = truth[:, 0], truth[:, 6]
    climbing = vz > 1e-3
    # before: hovering (to float32 rounding of the normalised hover thrust)
    assert climbing.sum() >= 5 and np.all(np.abs(vz[t < sent[0] - 0.002]) < 1e-5)
    a = params.max_thrust_N / params.mass_kg - params.g_mps2
    t_switch = np.median(t[climbing] - vz[climbing] / a)
    # it acts from the start of the attitude step (1 ms) it arrived in, after loopback delivery (and,
    # unstamped, a wake-up). Acting when read, at the loop's next instant, would be up to
    # RX_EVERY_S late; acting from where the plant last stood, up to a telemetry period early.
    assert sent[0] - 0.0012 <= t_switch <= sent[1] + 0.003, (t_switch, sent)


def test_waiting_says_whether_a_datagram_or_an_error_waits():
    rx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    gone = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        rx.bind(("127.0.0.1", 0))
        rx.setblocking(False)
        waiting = udp_arrival.Waiting(rx)
        assert not waiting()
        tx.sendto(b"one", rx.getsockname())
        tx.sendto(b"two", rx.getsockname())
        got = []
        while waiting():
            got.append(rx.recv(64))
        assert got == [b"one", b"two"] and not waiting()
        # an ICMP port-unreachable is 'waiting' too: the read that follows raises it
        gone.bind(("127.0.0.1", 0))
        port = gone.getsockname()[1]
        gone.close()
        rx.connect(("127.0.0.1", port))
        rx.send(b"nobody")
        deadline = time.monotonic() + 1.0
        while not waiting() and time.monotonic() < deadline:
            time.sleep(0.001)
        with pytest.raises(ConnectionRefusedError):
            rx.recv(64)
    finally:
        rx.close()
        tx.close()


@pytest.mark.skipif(not hasattr(os, "SCHED_BATCH"), reason="SCHED_BATCH is Linux's")
def test_a_lockstep_vehicle_asks_for_batch_scheduling_and_a_real_time_one_does_not():
    policies = {}
    for lockstep in (True, False):
        argv = ["--port", "0", "--duration", "30"]
        argv += ["--lockstep-period-s", "0.01"] if lockstep else []
        proc = start_vehicle(*argv)
        try:
            assert "listening" in proc.stdout.readline()
            policies[lockstep] = os.sched_getscheduler(proc.pid)
        finally:
            proc.terminate()
            proc.wait(timeout=10)
    assert policies == {True: os.SCHED_BATCH, False: os.sched_getscheduler(0)}  # real time: inherited


_NO_LOAD_AFTER_WARM_UP = """
import socket
import sys
import numba
from sim_vehicles.__main__ import warm_up
from sim_vehicles.plant.autopilot import Autopilot
from pymavlink.dialects.v20 import common as mav
from sim_vehicles.vehicle.endpoint import VehicleEndpoint
from sim_vehicles.vehicle.modes import MODE_OFFBOARD
from sim_vehicles.mavlink.signing import Signer
from sim_vehicles.plant.params import AttitudeGains, VehicleParams
from sim_vehicles.common.state import make_state

def loaded():
    return {
        f"{m}.{name}": len(obj.overloads)
        for m in list(sys.modules)
        if m.startswith(("sim_vehicles", "swarm_sitl"))
        for name, obj in list(vars(sys.modules[m]).items())
        if isinstance(obj, numba.core.registry.CPUDispatcher)
    }

from sim_vehicles.models.vehicle_config import VehicleConfig
params, gains = VehicleParams(0.85, (0.05, 0.05, 0.09), 25.0), AttitudeGains(16.0, 16.0)
warm_up(VehicleConfig(mass_kg=0.85, inertia_kgm2=(0.05, 0.05, 0.09), max_thrust_N=25.0))
gcs = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
gcs.bind(("127.0.0.1", 0))
ep = VehicleEndpoint(
    Autopilot(params, gains, make_state([1.0, 2.0, 3.0]), 0.001), 7, lockstep_period_s=0.01,
    gcs_bind=("127.0.0.1", 0), gcs_remote=gcs.getsockname(), signing_key=bytes(32),
)
before = loaded()
for armed in (False, True):  # every stream of both ports, on the ground and flying, signed
    ep.armed = armed
    for _ in range(150):
        ep.step(10)
ep.mode = MODE_OFFBOARD  # and the usual lockstep tick: a signed setpoint for now, in offboard
controller = mav.MAVLink(None, 7, 191)
for _ in range(3):
    sp = controller.set_attitude_target_encode(ep.time_boot_ms, 7, 1, 0, [1.0, 0, 0, 0], 0, 0, 0, 0.4)
    k = ep.autopilot.step_index
    ep.datagram(Signer(bytes(32)).seal(sp.pack(controller)), ("127.0.0.1", 9))
    assert ep.autopilot.step_index == k + 10, "the setpoint did not step the vehicle"
ep.datagram(Signer(bytes(32)).seal(bytes([253, 0, 0, 0, 0, 9, 1, 0, 0, 0, 0, 0])), ("127.0.0.1", 9))
after = loaded()
ep.close()
print({k: (before.get(k, 0), n) for k, n in after.items() if n != before.get(k, 0)})
"""


def test_a_warmed_vehicle_loads_no_kernel_in_flight():
    """``warm_up`` (run once in the fork server) loads every kernel a vehicle's streams use: a
    kernel loaded in flight costs each vehicle tens of milliseconds of CPU in its run."""
    out = subprocess.run(
        [sys.executable, "-c", _NO_LOAD_AFTER_WARM_UP], capture_output=True, text=True, timeout=120
    )
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "{}", f"kernels loaded after warm_up (before, after): {out.stdout}"


def test_a_ground_station_port_packs_nothing_until_someone_speaks_to_it(tmp_path):
    """No ``gcs_remote`` and no ground station yet: its streams are not packed (32 vehicles of a
    swarm each packed ~40 frames a second for nobody); the first heartbeat starts them."""
    params = VehicleParams(0.85, (0.05, 0.05, 0.09), 25.0)
    ap = Autopilot(params, AttitudeGains(16.0, 16.0), make_state([1.0, 2.0, 3.0]), 0.001)
    ep = VehicleEndpoint(
        ap, 7, lockstep_period_s=0.01, gcs_bind=("127.0.0.1", 0), tlog_path=tmp_path / "v.tlog"
    )
    gcs = mavutil.mavlink_connection(f"udpout:127.0.0.1:{ep.gcs_address[1]}", source_system=255)
    try:
        for _ in range(100):  # 1 s
            ep.step(10)
        assert ep.gcs.mav.total_packets_sent == 0
        gcs.mav.heartbeat_send(mav.MAV_TYPE_GCS, mav.MAV_AUTOPILOT_INVALID, 0, 0, 0)
        time.sleep(0.05)
        ep.poll_gcs()
        for _ in range(100):
            ep.step(10)
        got: dict[str, int] = {}
        while (m := gcs.recv_match(blocking=True, timeout=0.2)) is not None:
            got[m.get_type()] = got.get(m.get_type(), 0) + 1
        assert got.get("HEARTBEAT", 0) >= 1 and 10 <= got.get("ATTITUDE", 0) <= 20, got  # 15 Hz for 1 s
    finally:
        gcs.close()
        ep.close()


#: what an endpoint keeps besides its state and counters
_BOOKS = ("port.streams.next_send", "port.streams.next_any_s", "port.streams.next_other_s")
_BOOKS += ("flight.last_setpoint_s", "flight.offboard_signal_s", "flight.mode", "flight.armed")
_BOOKS += ("port.accepted", "port.accepted_from")


def _fly_setpoints(
    tmp_path, name: str, usual_tick: bool
) -> tuple[list[bytes], VehicleEndpoint, list[bool], list[dict]]:
    """A lockstep vehicle armed in offboard, served 120 setpoints from a pymavlink controller
    (varied commands; every 15th ignores the rates, so the general path takes it), with its other
    streams at their defaults (ATTITUDE and HIGHRES_IMU at 50 Hz: due every other tick). Returns
    what it sent, the endpoint (closed), for each setpoint whether the one-call tick took it
    (``usual_tick=False``: never), and its books (``_BOOKS``) after each."""
    params = VehicleParams(0.85, (0.05, 0.05, 0.09), 25.0)
    ap = Autopilot(params, AttitudeGains(16.0, 16.0), make_state([1.0, 2.0, 3.0]), 0.001)
    logs = {"truth_path": tmp_path / f"{name}.rows", "tlog_path": tmp_path / f"{name}.tlog"}
    ep = VehicleEndpoint(ap, 7, lockstep_period_s=0.01, **logs)
    taken: list[bool] = []
    one_call = lockstep_tick.usual_tick
    rx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    rx.bind(("127.0.0.1", 0))
    controller = mavlink2.MAVLink(None, 7, 191)
    rng = np.random.default_rng(5)
    ep.armed, ep.mode = True, 1
    sent: list[bytes] = []
    books = []

    def counted(ep_: VehicleEndpoint, r: np.ndarray) -> bool:
        taken.append(usual_tick and one_call(ep_, r))
        return taken[-1]

    lockstep_tick.usual_tick = counted  # what the endpoint calls (``lockstep_tick.usual_tick``)
    try:
        for k in range(120):
            q = rng.normal(size=4) * [0.05, 0.05, 0.05, 1.0]
            q /= np.linalg.norm(q)
            rates = rng.normal(scale=0.3, size=3)
            mask = 0b0000_0111 if k % 15 == 7 else 0
            sp = controller.set_attitude_target_encode(
                ep.time_boot_ms, 7, 1, mask, q.tolist(), *rates.tolist(), float(rng.uniform(0.2, 0.5))
            )
            ep.datagram(sp.pack(controller), rx.getsockname())
            ep.flush()
            books.append({b: copy.copy(operator.attrgetter(b)(ep)) for b in (*_BOOKS, "stats")})
        rx.setblocking(False)
        while True:
            try:
                sent.append(rx.recv(4096))
            except BlockingIOError:
                break
    finally:
        lockstep_tick.usual_tick = one_call
        rx.close()
        ep.close()
    return sent, ep, taken, books


def test_the_one_call_lockstep_tick_is_the_general_path_bit_for_bit(tmp_path):
    """``lockstep_tick``: the same state, bytes, counters, truth rows and ``.tlog`` frames as the
    setpoint handler, step and stream table it stands in for, interleaved with ticks that other
    streams make general."""
    fast_sent, fast, taken, fast_books = _fly_setpoints(tmp_path, "fast", usual_tick=True)
    slow_sent, slow, _, slow_books = _fly_setpoints(tmp_path, "slow", usual_tick=False)
    assert 40 <= sum(taken) < len(taken) == 120  # at 50 Hz, ATTITUDE and HIGHRES_IMU make every other general
    assert fast.time_boot_ms == slow.time_boot_ms == 1200
    assert fast.autopilot.state.tobytes() == slow.autopilot.state.tobytes()
    assert len(fast_sent) >= 120 and fast_sent == slow_sent
    assert fast.stats == slow.stats and fast.stats.setpoints == 120
    assert (fast.port.mav.seq, fast.port.mav.total_bytes_sent) == (
        slow.port.mav.seq,
        slow.port.mav.total_bytes_sent,
    )
    assert fast_books == slow_books  # after every setpoint
    (fast_columns, fast_rows), (slow_columns, slow_rows) = (
        read_rows(tmp_path / f"{n}.rows") for n in ("fast", "slow")
    )
    assert fast_columns == slow_columns and fast_rows.shape == (120, 14)
    assert fast_rows.tobytes() == slow_rows.tobytes()
    fast_log, slow_log = (_tlog(tmp_path / f"{n}.tlog") for n in ("fast", "slow"))
    assert [b for _, b in fast_log] == [b for _, b in slow_log]  # every frame in and out, in order
    assert len(fast_log) >= 120 + len(fast_sent)
    stamps = [t for t, _ in fast_log]
    assert stamps == sorted(stamps)


def _tlog(path) -> list[tuple[float, bytes]]:
    """A ``.tlog``'s messages as pymavlink reads them: (stamp [s], frame bytes)."""
    log = mavutil.mavlink_connection(str(path))
    got = []
    while (m := log.recv_match()) is not None:
        got.append((m._timestamp, bytes(m.get_msgbuf())))
    log.close()
    return got


@settings(max_examples=40, deadline=None)
@given(dt_ms=st.sampled_from([1, 2, 4, 5]), k=st.integers(1, 30), off=st.sampled_from([0.5, 0.001]))
def test_a_lockstep_period_of_any_whole_number_of_steps_steps_that_many_and_no_other_period_is_taken(
    dt_ms, k, off
):
    """A period of k attitude steps (k >= 1, one step included) that is a whole number of
    milliseconds is taken, and a setpoint stamped with the vehicle's time advances it exactly k
    steps and k dt of ``time_boot_ms``; a period between two multiples is refused in one line."""
    dt = dt_ms / 1000
    ap = Autopilot(ENDPOINT_PARAMS, AttitudeGains(16.0, 16.0), make_state([0.0, 0.0, 5.0]), dt)
    ep = recording_endpoint(7, ap, lockstep_period_s=k * dt)
    try:
        link = mavlink2.MAVLink(None, srcSystem=7, srcComponent=191)
        for n in range(1, 3):
            sp = mavlink2.MAVLink_set_attitude_target_message(
                ep.time_boot_ms, 7, 1, 0, [1, 0, 0, 0], 0, 0, 0, 0.3
            )
            ep.datagram(bytes(sp.pack(link)), ("127.0.0.1", 40007))
            assert (ep.autopilot.step_index, ep.time_boot_ms) == (n * k, n * k * dt_ms)
    finally:
        ep.close()
    with pytest.raises(ValueError, match=r"lockstep period .* whole number"):
        recording_endpoint(7, ap, lockstep_period_s=(k + off) * dt)


@settings(max_examples=30, deadline=None)
@given(stamp_ms=st.integers(1, 2**32 - 1), clock=st.sampled_from(["real time", "lockstep"]))
def test_a_setpoint_is_the_stream_offboard_needs_in_real_time_whatever_its_stamp_and_in_lockstep_only_on_time(
    stamp_ms, clock
):
    """PX4 takes OFFBOARD only while setpoints stream. In real time any setpoint is that signal,
    whatever its ``time_boot_ms`` (PX4 reads no stamp); in lockstep one stamped ahead of the
    vehicle's clock is refused (``rx_bad``) and is no signal: OFFBOARD is then rejected."""
    ep = recording_endpoint(7, lockstep_period_s=0.01 if clock == "lockstep" else None)
    try:
        sp = mavlink2.MAVLink_set_attitude_target_message(stamp_ms, 7, 1, 0, [1, 0, 0, 0], 0, 0, 0, 0.3)
        answers(ep, sp, 7, 191)
        mode = mavlink2.MAVLink_command_long_message(7, 1, mav.MAV_CMD_DO_SET_MODE, 0, 29, 6, 0, 0, 0, 0, 0)
        (ack,) = [m for m in answers(ep, mode, 7, 191) if m.get_type() == "COMMAND_ACK"]
        if clock == "real time":
            assert ack.result == mav.MAV_RESULT_ACCEPTED and ep.stats.rx_bad == 0
        else:
            assert ack.result == mav.MAV_RESULT_TEMPORARILY_REJECTED and ep.stats.rx_bad == 1
    finally:
        ep.close()


@pytest.mark.parametrize("k0", [0, 123_457])
def test_in_real_time_a_vehicle_goes_on_from_its_own_time_and_says_when_its_time_began(k0):
    """``loops.run_realtime`` of a vehicle that has already flown ``k0`` steps: its boot instant
    (``boot_unix_s``, what the run's merge puts its samples on the wall clock by) is the start
    less ``k0`` steps, and it steps on from ``k0``, never ahead of the wall clock (one step of
    the clock's reading between the two ends)."""
    ap = Autopilot(ENDPOINT_PARAMS, AttitudeGains(16.0, 16.0), make_state([0.0, 0.0, 5.0]), 0.001)
    ap.step_index = k0
    ep = VehicleEndpoint(ap, 7)
    try:
        before, start = time.time(), time.monotonic()
        loops.run_realtime(ep, duration_s=0.3)
        elapsed, after = time.monotonic() - start, time.time()
    finally:
        ep.close()
    assert before - k0 * ap.dt_s <= ep.boot_unix_s <= after - k0 * ap.dt_s
    assert k0 < ap.step_index <= k0 + elapsed / ap.dt_s + 1


@settings(max_examples=15, deadline=None)
@given(seed=st.integers(0, 2**31), ticks=st.integers(1, 4))
def test_in_lockstep_a_vehicle_with_sensors_sends_its_sensor_models_report_at_every_tick(seed, ticks):
    """Armed in offboard, a lockstep vehicle with sensor noise answers each setpoint with the
    LOCAL_POSITION_NED an identical sensor model reports of its true state at the new instant
    (the one-call tick, which sends the true state, is not for it), in NED as float32."""

    def model() -> SensorModel:
        return SensorModel(7, 0.3, 0.2, 0.05, seed=seed)

    ep, reference = recording_endpoint(7, lockstep_period_s=0.01, sensors=model()), model()
    ep.port.peer = ("127.0.0.1", 40007)
    ep.armed, ep.mode = True, 1
    link = mavlink2.MAVLink(None, 7, 191)
    try:
        for _ in range(ticks):
            ep.port.sock.sent.clear()
            sp = mavlink2.MAVLink_set_attitude_target_message(
                ep.time_boot_ms, 7, 1, 0, [1, 0, 0, 0], 0, 0, 0, 0.33
            )
            ep.datagram(bytes(sp.pack(link)), ep.port.peer)
            ep.flush()
            back = [m for d in ep.port.sock.sent for m in mavlink2.MAVLink(None).parse_buffer(d) or []]
            (lp,) = [m for m in back if m.get_type() == "LOCAL_POSITION_NED"]
            e, n, u, ve, vn, vu = reference.reported(ep.time_boot_ms, ep.autopilot.state)[:6]
            assert lp.time_boot_ms == ep.time_boot_ms
            got = [lp.x, lp.y, lp.z, lp.vx, lp.vy, lp.vz]
            assert got == np.float32([n, e, -u, vn, ve, -vu]).tolist(), (got, [n, e, -u])
    finally:
        ep.close()


def test_a_vehicle_closed_twice_raises_nothing_and_keeps_its_records(tmp_path):
    """A vehicle's shutdown path and a ``finally`` may both close it: the second close does
    nothing, and the truth rows written before stay readable."""
    paths = {
        "truth_path": tmp_path / "t.rows",
        "tlog_path": tmp_path / "t.tlog",
        "events_path": tmp_path / "e",
    }
    ep = recording_endpoint(7, lockstep_period_s=0.01, gcs_bind=("127.0.0.1", 0), **paths)
    ep.armed, ep.mode = True, 1
    link = mavlink2.MAVLink(None, 7, 191)
    for _ in range(3):
        sp = mavlink2.MAVLink_set_attitude_target_message(
            ep.time_boot_ms, 7, 1, 0, [1, 0, 0, 0], 0, 0, 0, 0.3
        )
        ep.datagram(bytes(sp.pack(link)), ("127.0.0.1", 40007))
    ep.close()
    ep.close()
    _, rows = read_rows(paths["truth_path"])
    assert rows[:, 0].tolist() == [0.01, 0.02, 0.03]
