"""A ground station's own port on each vehicle: it watches without disturbing the controller.

Clients use only pymavlink's public API. The system test watches vehicle 1 through its
ground-station port during a lockstep run of the paper's scenario, which must still equal ``sim``
bit for bit.
"""

import hashlib
import math
import re
import subprocess
import time

import numpy as np
import pytest
import yaml
from pymavlink import mavutil

from swarm_sitl.running.sim import run_sim
from tests.support import CONFIGS, free_udp_port, spawn_vehicle, start_cli

pytestmark = pytest.mark.system
mav = mavutil.mavlink


def _stamp_ms(m) -> float | None:
    """When the vehicle sent ``m``, on its own clock (its time since boot) [ms], if it says."""
    if hasattr(m, "time_boot_ms"):
        return float(m.time_boot_ms)
    return m.time_usec / 1000.0 if hasattr(m, "time_usec") else None


def _counts(*conns, seconds: float) -> list[dict[str, int]]:
    """Messages of each kind the vehicle sent each connection within ``seconds`` of its own clock
    (from the first message stamped after what came before is read off), read side by side: what
    the reader's scheduling on a loaded machine does not change (a reader woken late reads more
    of what waits, not more of what was sent within the window). Unstamped messages count as they
    come within the window's wall time."""
    for c in conns:  # what came before does not count
        while c.recv_match(blocking=False) is not None:
            pass
    got: list[dict[str, int]] = [{} for _ in conns]
    start_ms: float | None = None
    done = [False] * len(conns)
    wall_end = time.monotonic() + seconds
    give_up = time.monotonic() + 3 * seconds + 5.0
    while not all(done) and time.monotonic() < give_up:
        for j, (c, counts) in enumerate(zip(conns, got, strict=True)):
            while (m := c.recv_match(blocking=False)) is not None:
                stamp = _stamp_ms(m)
                if stamp is None:
                    inside = time.monotonic() < wall_end
                else:
                    start_ms = stamp if start_ms is None else start_ms
                    inside = start_ms <= stamp < start_ms + 1000 * seconds
                    done[j] = done[j] or stamp >= start_ms + 1000 * seconds
                if inside:
                    counts[m.get_type()] = counts.get(m.get_type(), 0) + 1
        time.sleep(0.005)
    assert all(done), "the vehicle's clock did not pass the window's end"
    return got


def _most(rate_hz: float, seconds: float) -> int:
    """The most messages of a stream of ``rate_hz`` a window of ``seconds`` holds: the vehicle
    sends each stream at most once per period slot (``port.next_due``), and a window cuts at
    most ``rate * seconds + 1`` slots."""
    return math.floor(rate_hz * seconds + 1e-9) + 1


@pytest.mark.light
def test_a_ground_station_gets_its_own_streams_and_changes_only_them():
    port, gcs_port = free_udp_port(), free_udp_port()
    proc = spawn_vehicle(2, port, "--gcs-port", str(gcs_port), "--duration", "30")
    try:
        controller = mavutil.mavlink_connection(
            f"udpout:127.0.0.1:{port}", source_system=2, source_component=191
        )
        controller.mav.heartbeat_send(mav.MAV_TYPE_ONBOARD_CONTROLLER, mav.MAV_AUTOPILOT_INVALID, 0, 0, 0)
        assert controller.wait_heartbeat(timeout=5) is not None
        gcs = mavutil.mavlink_connection(f"udpout:127.0.0.1:{gcs_port}", source_system=255)
        gcs.mav.heartbeat_send(mav.MAV_TYPE_GCS, mav.MAV_AUTOPILOT_INVALID, 0, 0, 0)
        hb = gcs.wait_heartbeat(timeout=5)
        assert hb is not None and hb.autopilot == mav.MAV_AUTOPILOT_PX4 and gcs.flightmode == "LOITER"
        (seen,) = _counts(gcs, seconds=3.0)  # PX4's ground-station rates: 5 Hz position, 15 Hz attitude
        # (at least 60 %: a vehicle late on a shared machine skips a slot, never adds one)
        assert 0.6 * 5 * 3 <= seen.get("GLOBAL_POSITION_INT", 0) <= _most(5, 3), seen
        assert 0.6 * 15 * 3 <= seen.get("ATTITUDE", 0) <= _most(15, 3) and "HIGHRES_IMU" not in seen, seen
        # the ground station asks for 20 Hz of GLOBAL_POSITION_INT; the controller's port keeps 5 Hz
        gcs.mav.command_long_send(2, 1, mav.MAV_CMD_SET_MESSAGE_INTERVAL, 0, 33, 50_000, 0, 0, 0, 0, 0)
        ack = gcs.recv_match(type="COMMAND_ACK", blocking=True, timeout=3)
        assert ack is not None and ack.result == mav.MAV_RESULT_ACCEPTED and ack.target_system == 255
        # a setpoint on the ground station's port is refused: only the controller's port flies
        gcs.mav.set_attitude_target_send(0, 2, 1, 0, [1.0, 0, 0, 0], 0, 0, 0, 1.0)
        time.sleep(0.1)
        on_gcs, on_controller = _counts(gcs, controller, seconds=2.0)
        # a margin below for a late vehicle, none above: a rate changed on the wrong port (20 Hz
        # against 5) is far outside either
        assert 0.6 * 20 * 2 <= on_gcs.get("GLOBAL_POSITION_INT", 0) <= _most(20, 2), on_gcs
        assert 0.6 * 5 * 2 <= on_controller.get("GLOBAL_POSITION_INT", 0) <= _most(5, 2), on_controller
        assert on_controller.get("LOCAL_POSITION_NED", 0) >= 0.6 * 50 * 2  # the controller's 50 Hz goes on
    finally:
        proc.terminate()
        proc.wait(timeout=10)


@pytest.mark.lockstep
def test_a_watcher_on_the_ground_station_port_leaves_a_lockstep_run_unchanged(tmp_path, paper_cfg):
    cfg = yaml.safe_load((CONFIGS / "paper.yaml").read_text())
    cfg["duration_s"] = 6.0
    path = tmp_path / "paper.yaml"
    path.write_text(yaml.safe_dump(cfg))
    out = tmp_path / "run"
    run = start_cli(
        "run",
        str(path),
        "--out",
        str(out),
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        start_new_session=False,
    )
    try:
        assert run.stdout is not None
        line = ""
        while "vehicle 1:" not in line:
            line = run.stdout.readline()
            assert line, "run printed no ports"
        gcs_port = int(re.search(r"ground station udpout:127\.0\.0\.1:(\d+)", line).group(1))
        watcher = mavutil.mavlink_connection(f"udpout:127.0.0.1:{gcs_port}", source_system=255)
        # the run signs every link: a ground station signs with the run's key too, as with PX4
        passphrase = (out / "mavlink_signing.key").read_text().splitlines()[0]
        watcher.setup_signing(hashlib.sha256(passphrase.encode()).digest(), sign_outgoing=True)
        watcher.mav.heartbeat_send(mav.MAV_TYPE_GCS, mav.MAV_AUTOPILOT_INVALID, 0, 0, 0)
        heartbeats, position_ms = 0, []  # GLOBAL_POSITION_INT's time_boot_ms: simulated time
        while run.poll() is None:
            watcher.mav.heartbeat_send(mav.MAV_TYPE_GCS, mav.MAV_AUTOPILOT_INVALID, 0, 0, 0)
            end = time.monotonic() + 0.3
            while time.monotonic() < end:
                m = watcher.recv_match(type=["HEARTBEAT", "GLOBAL_POSITION_INT"], blocking=True, timeout=0.05)
                if m is not None and m.get_type() == "HEARTBEAT":
                    heartbeats += 1
                elif m is not None:
                    position_ms.append(m.time_boot_ms)
        # what came before the run ended and this loop did not read yet
        while (m := watcher.recv_match(type="GLOBAL_POSITION_INT", blocking=False)) is not None:
            position_ms.append(m.time_boot_ms)
        stdout, stderr = run.communicate(timeout=60)
    finally:
        if run.poll() is None:
            run.kill()
            run.wait()
    assert run.returncode == 0, stderr + stdout
    # Lockstep streams run on simulated time, from the watcher's first heartbeat to the run's end:
    # how many arrive depends on how soon the watcher is up on a loaded machine, not on the run.
    # What the run owes it is its stream at its rate (5 Hz: 200 ms apart in time_boot_ms), over
    # at least the last second, whatever a late wake-up of this loop let the socket drop.
    assert heartbeats >= 1 and len(position_ms) >= 2, (heartbeats, position_ms)
    assert np.median(np.diff(position_ms)) == 1000 / 5.0, position_ms
    assert position_ms[-1] >= 1000 * (cfg["duration_s"] - 1.0), position_ms
    sim = run_sim(paper_cfg.model_copy(update={"duration_s": 6.0}))
    for i in range(1, 5):
        got = np.load(out / f"follower_{i}.npz")
        assert np.array_equal(got["p_W"], sim.followers[i]["p_W"]), f"follower {i} changed"
