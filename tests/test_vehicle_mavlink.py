"""A vehicle process driven by a client that uses only pymavlink's public API (no project code)."""

import math
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest
from pymavlink import mavutil

from tests.support import free_udp_port, spawn_vehicle

pytestmark = pytest.mark.system


@pytest.fixture
def vehicle(tmp_path):
    port = free_udp_port()
    tlog = tmp_path / "vehicle.tlog"
    proc = spawn_vehicle(3, port, "--tlog", str(tlog), "--duration", "60")
    yield port, tlog, proc
    proc.terminate()
    proc.wait(timeout=10)


def _wait(conn, kind, timeout=5.0, cond=lambda m: True):
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        m = conn.recv_match(type=kind, blocking=True, timeout=0.2)
        if m is not None and cond(m):
            return m
    raise AssertionError(f"no {kind} within {timeout} s")


def _latest(conn, kind):
    """Drain what has arrived and return the newest message of ``kind``."""
    time.sleep(0.1)
    while conn.recv_match(blocking=False) is not None:
        pass
    return conn.messages[kind]


@pytest.mark.light
def test_pymavlink_client_arms_tilts_north_and_sees_it(vehicle):
    port, tlog, proc = vehicle
    conn = mavutil.mavlink_connection(f"udpout:127.0.0.1:{port}", source_system=250)
    conn.mav.heartbeat_send(mavutil.mavlink.MAV_TYPE_GCS, mavutil.mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0)
    hb = conn.wait_heartbeat(timeout=5)
    assert hb is not None and conn.target_system == 3
    assert hb.type == mavutil.mavlink.MAV_TYPE_QUADROTOR
    assert not hb.base_mode & mavutil.mavlink.MAV_MODE_FLAG_SAFETY_ARMED

    conn.mav.param_request_list_send(3, 1)
    params = {}
    end = time.monotonic() + 5
    while len(params) < 6 and time.monotonic() < end:
        m = conn.recv_match(type="PARAM_VALUE", blocking=True, timeout=0.2)
        if m:
            params[m.param_id] = m.param_value
    # PX4's own parameters only (no MASS_KG: no autopilot has it); the hover thrust is m g / T_max
    assert params["MPC_THR_HOVER"] == pytest.approx(0.85 * 9.81 / 25.0, rel=2**-23)
    assert params["COM_OF_LOSS_T"] == pytest.approx(0.5) and "MASS_KG" not in params

    conn.mav.command_long_send(3, 1, mavutil.mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0, 0, 0, 0)
    assert _wait(conn, "COMMAND_ACK").result == mavutil.mavlink.MAV_RESULT_ACCEPTED
    # pitch nose-down 10 deg in NED/FRD (rotation about body y by -10 deg): thrust tips toward north
    tilt = math.radians(10)
    q = [math.cos(-tilt / 2), 0.0, math.sin(-tilt / 2), 0.0]
    hover = 0.85 * 9.81 / 25.0 / math.cos(tilt)
    assert hb.autopilot == mavutil.mavlink.MAV_AUTOPILOT_PX4 and conn.flightmode == "LOITER"  # PX4's Hold
    conn.set_mode("OFFBOARD")  # pymavlink's own PX4 mode table: refused without a setpoint stream
    assert _wait(conn, "COMMAND_ACK").result == mavutil.mavlink.MAV_RESULT_TEMPORARILY_REJECTED
    conn.mav.set_attitude_target_send(0, 3, 1, 0b0000_0111, q, 0, 0, 0, hover)  # Hold ignores it
    conn.set_mode("OFFBOARD")  # a stream runs now: taken, as PX4 takes it
    assert _wait(conn, "COMMAND_ACK").result == mavutil.mavlink.MAV_RESULT_ACCEPTED
    start = _wait(conn, "LOCAL_POSITION_NED")
    modes = set()
    end = time.monotonic() + 2.5
    while time.monotonic() < end:
        conn.mav.set_attitude_target_send(0, 3, 1, 0b0000_0111, q, 0, 0, 0, hover)
        time.sleep(0.02)
        while (m := conn.recv_match(type="HEARTBEAT", blocking=False)) is not None:
            if m.get_srcSystem() == 3:
                armed = bool(m.base_mode & mavutil.mavlink.MAV_MODE_FLAG_SAFETY_ARMED)
                modes.add((armed, mavutil.mode_string_v10(m)))
    assert (True, "OFFBOARD") in modes  # armed, following external setpoints
    lp = _latest(conn, "LOCAL_POSITION_NED")
    att = conn.messages["ATTITUDE_QUATERNION"]
    assert lp.time_boot_ms > start.time_boot_ms
    north = lp.x - start.x
    assert north > 0.5  # moved north
    # the vehicle starts facing east (identity in ENU/FLU is yaw 90 deg in NED) and yaws to north while
    # tilting, which moves it a little east; altitude is held by the tilt-compensated thrust
    assert abs(lp.y - start.y) < 0.3 * north and abs(lp.z - start.z) < 0.3
    assert att.q1 == pytest.approx(q[0], abs=5e-3) and att.q3 == pytest.approx(q[2], abs=5e-3)

    # setpoint loss: the vehicle reports failsafe and holds where its setpoints stopped (its own
    # position loop), where the open-loop hover of old drifted on at the speed it had
    text = _wait(conn, "STATUSTEXT", timeout=4, cond=lambda m: "Failsafe" in m.text)
    assert "hold" in text.text
    lost_ms = conn.messages["LOCAL_POSITION_NED"].time_boot_ms  # the vehicle's clock at the loss
    hb = _wait(
        conn,
        "HEARTBEAT",
        timeout=4,
        cond=lambda m: m.get_srcSystem() == 3 and m.system_status == mavutil.mavlink.MAV_STATE_CRITICAL,
    )
    assert mavutil.mode_string_v10(hb) == "LOITER"  # what it flies: a hold
    # it was doing about 4 m/s north: stopped within its 30-degree tilt limit and settled 6 s into the
    # hold (0.1 m/s at 4 s, under 0.01 m/s at 6 s), read on the vehicle's clock, which a loaded machine
    # may leave behind the wall clock
    a = _wait(conn, "LOCAL_POSITION_NED", timeout=15, cond=lambda m: m.time_boot_ms >= lost_ms + 6000)
    b = _wait(conn, "LOCAL_POSITION_NED", timeout=5, cond=lambda m: m.time_boot_ms >= a.time_boot_ms + 1000)
    assert math.dist((a.x, a.y, a.z), (b.x, b.y, b.z)) < 0.05 and math.hypot(b.vx, b.vy, b.vz) < 0.05
    assert abs(b.z - start.z) < 0.5
    # a valid setpoint stream takes it back to offboard
    back = set()
    end = time.monotonic() + 2.5
    while time.monotonic() < end and "OFFBOARD" not in back:
        conn.mav.set_attitude_target_send(
            0, 3, 1, 0b0000_0111, [1.0, 0.0, 0.0, 0.0], 0, 0, 0, 0.85 * 9.81 / 25
        )
        time.sleep(0.02)
        while (m := conn.recv_match(type="HEARTBEAT", blocking=False)) is not None:
            back.add(mavutil.mode_string_v10(m))
    assert "OFFBOARD" in back
    conn.close()
    proc.terminate()  # SIGTERM: the vehicle closes its .tlog before exiting
    assert proc.wait(timeout=10) == 0

    log = mavutil.mavlink_connection(str(tlog))
    kinds = set()
    while (m := log.recv_match()) is not None:
        kinds.add(m.get_type())
    assert {
        "HEARTBEAT",
        "LOCAL_POSITION_NED",
        "ATTITUDE_QUATERNION",
        "SET_ATTITUDE_TARGET",
        "PARAM_VALUE",
    } <= kinds
    # pymavlink's own log tool reads it as it reads PX4's: the flight modes by name, the positions
    dump = subprocess.run(
        [
            str(Path(sys.executable).with_name("mavlogdump.py")),
            "--types",
            "HEARTBEAT,LOCAL_POSITION_NED",
            str(tlog),
        ],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert dump.returncode == 0, dump.stderr
    out = dump.stdout.splitlines()
    assert any("LOCAL_POSITION_NED {time_boot_ms" in line for line in out)
    assert any("HEARTBEAT" in line and "autopilot : 12" in line for line in out), out[:5]


@pytest.mark.light
def test_garbage_bytes_are_dropped_and_the_vehicle_keeps_talking(vehicle):
    port, _, _ = vehicle
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.sendto(b"\xfd\x09garbage-not-mavlink" * 5, ("127.0.0.1", port))
    conn = mavutil.mavlink_connection(f"udpout:127.0.0.1:{port}", source_system=250)
    conn.mav.heartbeat_send(mavutil.mavlink.MAV_TYPE_GCS, mavutil.mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0)
    assert conn.wait_heartbeat(timeout=5) is not None
    conn.close()


@pytest.mark.light
def test_offboard_refused_for_a_lost_setpoint_is_asked_again(vehicle):
    """On a lossy link the setpoint sent ahead of DO_SET_MODE can be lost while the command gets
    through: the vehicle answers TEMPORARILY_REJECTED (PX4's rule), and the controller's link asks
    again, with a setpoint ahead, rather than give up the run."""
    from swarm_sitl.link.vehicle_link import VehicleLink

    port, _, _ = vehicle
    link = VehicleLink(f"udpout:127.0.0.1:{port}", 3, stamp_arrivals=False)
    sent_clock, answers = [], []
    real_clock, real_handle = link.send_clock_only, link.downlink.handle

    def lossy_clock(ms):  # the first setpoint is lost on the way
        sent_clock.append(ms)
        if len(sent_clock) > 1:
            real_clock(ms)

    def handle(m, arrival):
        if m.get_type() == "COMMAND_ACK" and m.command == mavutil.mavlink.MAV_CMD_DO_SET_MODE:
            answers.append(m.result)
        real_handle(m, arrival)

    link.send_clock_only, link.downlink.handle = lossy_clock, handle
    try:
        link.connect(10.0, 0.85, 9.81)
        link.engage(10.0, lockstep=True)
    finally:
        link.close()
    assert answers[0] == mavutil.mavlink.MAV_RESULT_TEMPORARILY_REJECTED
    assert answers[-1] == mavutil.mavlink.MAV_RESULT_ACCEPTED and len(sent_clock) >= 2
