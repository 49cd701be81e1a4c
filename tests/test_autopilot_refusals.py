"""A vehicle that does not answer as a controller needs ends that controller in one line naming the
follower, the step and the autopilot's own answer (its COMMAND_ACK result, its last STATUSTEXT),
within the handshake's timeout, never a hang: a controller's link against a scripted PX4 or
ArduCopter (``tests.fake_autopilot``) that refuses a mode, never arms, lacks a parameter, says it
is neither autopilot, reboots once flying, or never answers a command. And against a real-time
swarm: the rest flies on."""

import re
import subprocess
import sys
import time

import numpy as np
import pytest
import yaml
from pymavlink.dialects.v20 import common as mav

from swarm_sitl.link.transport import LinkError
from swarm_sitl.link.vehicle_link import VehicleLink
from swarm_sitl.running.children import child_env
from tests.fake_autopilot import FakeAutopilot
from tests.support import CONFIGS, cli

TIMEOUT_S = 1.5
DURATION_S = 4.0  #: the real-time run's
CASES = [  # (the autopilot, its script, the line after "follower 3: <url>: ")
    (
        "ardupilot",
        {"refuse_mode": True},
        "GUIDED_NOGPS refused: MAV_CMD_DO_SET_MODE answered MAV_RESULT_FAILED"
        "; its last STATUSTEXT: 'Mode GUIDED_NOGPS failed: requires position'",
    ),
    (
        "ardupilot",
        {"never_arm": True},
        "arming refused: MAV_CMD_COMPONENT_ARM_DISARM answered "
        "MAV_RESULT_FAILED; its last STATUSTEXT: 'PreArm: Throttle below failsafe'",
    ),
    (
        "px4",
        {"never_arm": True},
        "arming refused: MAV_CMD_COMPONENT_ARM_DISARM answered MAV_RESULT_FAILED"
        "; its last STATUSTEXT: 'PreArm: Throttle below failsafe'",
    ),
    (
        "px4",
        {"params": {}},
        "no PARAM_VALUE for MPC_THR_HOVER (the autopilot does not have it, or does not answer) within 1.5 s",
    ),
    (
        "ardupilot",
        {"params": {"MOT_THST_HOVER": 0.35, "GUID_OPTIONS": 0.0}},
        "no PARAM_VALUE for ATC_ANGLE_BOOST (the autopilot does not have it, or does not answer)"
        " within 1.5 s",
    ),
    ("ardupilot", {"read_only": frozenset({"GUID_OPTIONS"})}, "PARAM_SET GUID_OPTIONS 8 refused: it keeps 0"),
    (
        "px4",
        {"busy_mode": -1},
        "OFFBOARD refused: MAV_CMD_DO_SET_MODE answered MAV_RESULT_TEMPORARILY_REJECTED for 1.5 s",
    ),
    ("ardupilot", {"reboot_after_s": 0.3}, "mid-run, it rebooted (its time_boot_ms went from "),
    (
        "px4",
        {"deaf": frozenset({mav.MAV_CMD_COMPONENT_ARM_DISARM})},
        "no COMMAND_ACK for MAV_CMD_COMPONENT_ARM_DISARM (arming) within 1.5 s",
    ),
]


@pytest.mark.integration
@pytest.mark.parametrize(("kind", "script", "says"), CASES)
def test_a_vehicle_that_will_not_fly_ends_its_controller_in_one_line_within_the_timeout(kind, script, says):
    with FakeAutopilot(kind, 3, **script) as fake:
        link = VehicleLink(f"udpout:127.0.0.1:{fake.port}", 3, stamp_arrivals=False)
        t0 = time.monotonic()
        try:
            with pytest.raises(LinkError) as e:
                link.connect(TIMEOUT_S, 1.0, 9.81)
                link.request_rates(0.01, 0.0, TIMEOUT_S)
                link.engage(TIMEOUT_S, lockstep=False)
                end = time.monotonic() + 2.0  # flying: a controller asks at every tick
                while time.monotonic() < end:
                    link.conn.select(0.01)
                    link.poll()
                    link.check_vehicle()
            waited = time.monotonic() - t0
        finally:
            link.close()
    line = str(e.value)
    head = f"follower 3: udpout:127.0.0.1:{fake.port}: "
    assert "\n" not in line and line.startswith(head), line
    tail = line[len(head) :]  # what it says, and nothing else (no STATUSTEXT where none came)
    if says.endswith("from "):  # (a reboot: the times it saw)
        assert re.fullmatch(re.escape(says) + r"\d+ to \d+\)", tail), line
    else:
        assert tail == says, line
    assert waited < 3 * TIMEOUT_S + 2.5  # each step within its timeout: never a hang


@pytest.mark.integration
def test_an_autopilot_that_is_neither_px4_nor_ardupilot_is_named_by_its_heartbeat():
    with FakeAutopilot("generic", 2, params={}) as fake:
        link = VehicleLink(f"udpout:127.0.0.1:{fake.port}", 2, stamp_arrivals=False)
        try:
            with pytest.raises(LinkError) as e:
                link.connect(TIMEOUT_S, 1.0, 9.81)
        finally:
            link.close()
    assert str(e.value).startswith("follower 2: ")
    assert "its HEARTBEAT says MAV_AUTOPILOT_GENERIC, neither PX4 nor ArduPilot" in str(e.value)


@pytest.mark.system
def test_in_real_time_a_refusal_or_a_reboot_ends_one_follower_and_the_rest_fly_on(tmp_path):
    """The paper's swarm in real time, followers 3 and 4 (leaves of the graph) on vehicles
    outside the run (``followers[i].mavlink``): 3 an ArduCopter that refuses GUIDED_NOGPS, 4 one
    that reboots 0.5 s after it armed. Each controller ends with its line, the run goes on to its end
    with followers 1 and 2 in formation, and says what was lost."""
    fakes = {
        3: ["--kind", "ardupilot", "--id", "3", "--refuse-mode"],
        4: ["--kind", "ardupilot", "--id", "4", "--reboot-after-s", "0.5"],
    }
    procs = {}
    try:
        urls = {}
        for i, args in fakes.items():
            p = subprocess.Popen(
                [sys.executable, "-m", "tests.fake_autopilot", *args],
                stdout=subprocess.PIPE,
                text=True,
                env=child_env(),
            )
            procs[i] = p
            line = p.stdout.readline() if p.stdout else ""
            urls[i] = "udpout:" + re.search(r"udp:(\S+)", line).group(1)  # type: ignore[union-attr]
        data = yaml.safe_load((CONFIGS / "paper.yaml").read_text())
        data["duration_s"] = DURATION_S
        data["run"] = {**data.get("run", {}), "start_timeout_s": 10.0}
        for f in data["followers"]:
            if f["id"] in urls:
                f["mavlink"], f["autopilot"] = urls[f["id"]], "ardupilot"
        path = tmp_path / "mixed.yaml"
        path.write_text(yaml.safe_dump(data))
        out = tmp_path / "run"
        r = cli("run", path, "--realtime", "--out", out, "--quiet", timeout=120)
    finally:
        for p in procs.values():
            p.kill()
            p.wait()
    logs = {i: (out / "logs" / f"controller_{i}.log").read_text() for i in (3, 4)}
    assert "follower 3: " in logs[3] and "GUIDED_NOGPS refused" in logs[3] and "requires position" in logs[3]
    assert "follower 4: " in logs[4] and "mid-run, it " in logs[4]
    # (a real-time run rides through a lost controller and names it at its end: exit 1)
    assert r.returncode == 1 and "controller_3" in r.stderr and "controller_4" in r.stderr, r.stderr
    for i in (1, 2):  # the rest flew on to the end, in formation
        rec = np.load(out / f"follower_{i}.npz")
        assert rec["t_s"][-1] == pytest.approx(DURATION_S, abs=0.01)  # (its tick's phase: a period)
        assert np.linalg.norm(rec["pos_err_m"][-1]) < 0.05
