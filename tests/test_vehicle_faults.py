"""``swarm-sitl vehicles CONFIG --faults FILE``: a fault plan's MAVLink faults at the vehicles' own
ports, for a controller the bench does not run (here plain pymavlink)."""

import json
import math
import signal
import subprocess
import time
from pathlib import Path

import pytest
import yaml
from pymavlink import mavutil
from pymavlink.dialects.v20 import common as mav

from tests.support import CONFIGS, cli, start_cli

pytestmark = pytest.mark.system
VEHICLES = ["vehicles", CONFIGS / "paper.yaml"]

DOWN_LOSS, UP_LOSS = 0.3, 0.5


def _start(tmp_path: Path, plan: dict) -> tuple[subprocess.Popen, dict[int, int]]:
    faults = tmp_path / "plan.yaml"
    faults.write_text(yaml.safe_dump(plan))
    out = tmp_path / "vehicles"
    proc = start_cli(*VEHICLES, "--faults", faults, "--out", out, start_new_session=False)
    ports: dict[int, int] = {}
    end = time.monotonic() + 120
    assert proc.stdout is not None
    while time.monotonic() < end:
        line = proc.stdout.readline()
        if not line:
            break
        if line.strip().startswith("vehicle "):
            i = int(line.split()[1].rstrip(":"))
            ports[i] = int(line.split("controller udpout:")[1].split()[0].rsplit(":", 1)[1].rstrip(","))
        if line.startswith("Ctrl-C"):
            return proc, ports
    proc.kill()
    raise AssertionError(f"vehicles did not come up: {proc.communicate()}")


def _binomial_bound(p: float, n: int) -> float:
    """Five standard deviations of a fraction of ``n`` independent draws with probability ``p``."""
    return 5 * math.sqrt(p * (1 - p) / n)


@pytest.mark.light
def test_a_pymavlink_controller_sees_the_planned_loss_on_its_link(tmp_path):
    plan = {
        "seed": 11,
        "plan": [
            {"mavlink": 1, "direction": "down", "loss": DOWN_LOSS},
            {"mavlink": 1, "direction": "up", "loss": UP_LOSS},
        ],
    }
    proc, ports = _start(tmp_path, plan)
    try:
        conn = mavutil.mavlink_connection(f"udpout:127.0.0.1:{ports[1]}", source_system=245, dialect="common")
        sent = 0
        end = time.monotonic() + 20
        acked = False
        while not acked:  # half the commands are lost on the way up, and answers on the way down
            assert time.monotonic() < end, "no answer to SET_MESSAGE_INTERVAL"
            conn.mav.command_long_send(1, 1, mav.MAV_CMD_SET_MESSAGE_INTERVAL, 0, 32, 10_000, 0, 0, 0, 0, 0)
            sent += 1
            ack = conn.recv_match(type="COMMAND_ACK", blocking=True, timeout=0.2)
            acked = ack is not None and ack.command == mav.MAV_CMD_SET_MESSAGE_INTERVAL
        # downlink: the vehicle's frames, counted by their sequence numbers (a gap is a loss)
        seqs = []
        t_end = time.monotonic() + 4.0
        while time.monotonic() < t_end:
            m = conn.recv_match(blocking=True, timeout=0.1)
            if m is not None and m.get_srcSystem() == 1:
                seqs.append(m.get_seq())
            if len(seqs) % 20 == 0:
                conn.mav.heartbeat_send(mav.MAV_TYPE_ONBOARD_CONTROLLER, mav.MAV_AUTOPILOT_INVALID, 0, 0, 0)
                sent += 1
        # quiet before the stop: a datagram the relay passes on as the vehicle exits is never read
        time.sleep(0.5)
    finally:
        proc.send_signal(signal.SIGINT)
        stdout, stderr = proc.communicate(timeout=30)
    assert proc.returncode == 0, stderr
    unwrapped = [seqs[0]]
    for s in seqs[1:]:
        unwrapped.append(unwrapped[-1] + (s - unwrapped[-1]) % 256)
    span = unwrapped[-1] - unwrapped[0] + 1
    seen = 1 - len(set(unwrapped)) / span  # what this controller saw of the plan
    # datagrams carry one frame or two: at least span / 2 independent draws
    assert abs(seen - DOWN_LOSS) < _binomial_bound(DOWN_LOSS, span // 2), (seen, span)
    links = json.loads((tmp_path / "vehicles" / "links.json").read_text())
    up, down = links["mavlink 1 up"], links["mavlink 1 down"]
    assert up["received"] == sent  # every datagram this controller sent met its fate
    assert abs(up["lost"] / up["received"] - UP_LOSS) < _binomial_bound(UP_LOSS, up["received"])
    assert abs(down["lost"] / down["received"] - DOWN_LOSS) < _binomial_bound(DOWN_LOSS, down["received"])
    stats = json.loads((tmp_path / "vehicles" / "procs" / "vehicle_1.stats.json").read_text())
    assert stats["rx_messages"] == up["delivered"]  # the vehicle got exactly what was passed on
    assert "mavlink 1 up" in stdout and 2 not in {int(k.split()[1]) for k in links}  # only 1 is relayed


@pytest.mark.lockstep  # (refused before anything flies)
def test_vehicles_faults_refuses_what_it_cannot_do(tmp_path):
    plan = tmp_path / "plan.yaml"
    plan.write_text(yaml.safe_dump({"plan": [{"edge": [0, 1], "loss": 0.5}]}))
    r = cli(*VEHICLES, "--faults", plan, timeout=60)
    assert r.returncode == 2 and "MAVLink links only" in r.stderr and "Traceback" not in r.stderr
    plan.write_text(yaml.safe_dump({"plan": [{"mavlink": 1, "loss": 0.5}]}))
    r = cli(*VEHICLES, "--faults", plan, "--lockstep", timeout=60)
    assert r.returncode == 2 and "real time only" in r.stderr and len(r.stderr.strip().splitlines()) == 1
