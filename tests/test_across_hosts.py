"""One swarm over two "hosts": two network namespaces joined by a veth pair.

Namespace ``veh`` (10.77.0.1) runs the vehicles (``swarm-sitl vehicles --host 10.77.0.1``) and the
zenoh router (``swarm-sitl router``); namespace ``ctl`` (10.77.0.2) runs the leader and the
controllers (``swarm-sitl controllers``, ``zenoh.mode: client``), so every MAVLink datagram and
every zenoh message crosses the link. The vehicles' own relays (``vehicles --faults``) lose a
tenth of the datagrams each way on every vehicle's link, on the wire, in real time. The swarm must
still converge, and the relays' counts must match the plan.

Needs root and iproute2 (``ip netns``), as on a fresh Debian machine or CI runner; where network
namespaces are not allowed the test is skipped saying why.
"""

import json
import math
import os
import re
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import yaml

from swarm_sitl.running.children import child_env, module_argv

pytestmark = pytest.mark.system
ROOT = Path(__file__).resolve().parents[1]
NS_VEH, NS_CTL = "swsitl_veh", "swsitl_ctl"
VEH_IP, CTL_IP = "10.77.0.1", "10.77.0.2"


def _why_not() -> str | None:
    if not sys.platform.startswith("linux"):
        return "network namespaces are Linux only"
    if os.geteuid() != 0:
        return "creating network namespaces needs root"
    if shutil.which("ip") is None:
        return "`ip` is not installed (apt-get install iproute2)"
    probe = subprocess.run(["ip", "netns", "add", "swsitl_probe"], capture_output=True, text=True)
    if probe.returncode != 0:
        return f"this machine does not allow network namespaces: {probe.stderr.strip()}"
    subprocess.run(["ip", "netns", "del", "swsitl_probe"], capture_output=True)
    return None


def _sh(*cmd: str) -> None:
    subprocess.run(cmd, check=True, capture_output=True, text=True)


@pytest.fixture
def two_hosts():
    why = _why_not()
    if why:
        pytest.skip(why)
    for ns in (NS_VEH, NS_CTL):
        subprocess.run(["ip", "netns", "del", ns], capture_output=True)
    try:
        _sh("ip", "netns", "add", NS_VEH)
        _sh("ip", "netns", "add", NS_CTL)
        _sh("ip", "link", "add", "swsitl0", "type", "veth", "peer", "name", "swsitl1")
        _sh("ip", "link", "set", "swsitl0", "netns", NS_VEH)
        _sh("ip", "link", "set", "swsitl1", "netns", NS_CTL)
        for ns, dev, ip in ((NS_VEH, "swsitl0", VEH_IP), (NS_CTL, "swsitl1", CTL_IP)):
            _sh("ip", "-n", ns, "addr", "add", f"{ip}/24", "dev", dev)
            _sh("ip", "-n", ns, "link", "set", dev, "up")
            _sh("ip", "-n", ns, "link", "set", "lo", "up")
        yield
    finally:
        for ns in (NS_VEH, NS_CTL):
            subprocess.run(["ip", "netns", "del", ns], capture_output=True)


def _in(ns: str, *argv: str, **kw) -> subprocess.Popen:
    return subprocess.Popen(
        ["ip", "netns", "exec", ns, *module_argv("swarm_sitl"), *argv],
        env=child_env(),
        cwd=ROOT,
        text=True,
        **kw,
    )


def _wait_for(proc: subprocess.Popen, pattern: str, timeout_s: float) -> list[str]:
    """Lines of ``proc``'s stdout up to one matching ``pattern``."""
    lines: list[str] = []
    end = time.monotonic() + timeout_s
    assert proc.stdout is not None
    while time.monotonic() < end:
        line = proc.stdout.readline()
        if not line:
            break
        lines.append(line)
        if re.search(pattern, line):
            return lines
    raise AssertionError(f"no line matching {pattern!r}: {''.join(lines)}")


LOSS = 0.1  # each way, on every vehicle's link
DURATION_S = 12.0


def test_a_swarm_over_two_hosts_converges_through_a_lossy_link(two_hosts, tmp_path):
    cfg = yaml.safe_load((ROOT / "configs" / "paper.yaml").read_text())
    cfg["duration_s"] = DURATION_S
    cfg["zenoh"] = {"mode": "client", "connect": [f"tcp/{VEH_IP}:7447"]}
    cfg["signing"] = {"enabled": False}  # the key would have to be copied between the hosts
    for f in cfg["followers"]:  # two PX4 and two ArduCopters: each controller speaks its vehicle's
        if f["id"] in (2, 4):
            f["autopilot"] = "ardupilot"
    path = tmp_path / "two_hosts.yaml"
    path.write_text(yaml.safe_dump(cfg))
    plan = tmp_path / "lossy_link.yaml"
    entries = [{"mavlink": i, "direction": d, "loss": LOSS} for i in range(1, 5) for d in ("up", "down")]
    plan.write_text(yaml.safe_dump({"seed": 5, "plan": entries}))
    router = _in(NS_VEH, "router", "--listen", f"tcp/{VEH_IP}:7447", stdout=subprocess.PIPE)
    vehicles = _in(
        NS_VEH,
        "vehicles", str(path), "--faults", str(plan), "--host", VEH_IP, "--out", str(tmp_path / "veh"),
        stdout=subprocess.PIPE,
    )  # fmt: skip
    try:
        _wait_for(router, "router listening", 60)
        lines = _wait_for(vehicles, "Ctrl-C stops them", 120)
        urls = re.findall(r"controller (udpout:[0-9.]+:[0-9]+)", "".join(lines))
        assert len(urls) == 4 and all(VEH_IP in u for u in urls)
        out = tmp_path / "ctl"
        ctl = _in(NS_CTL, "controllers", str(path), "--quiet", "--out", str(out), "--mavlink", *urls)
        assert ctl.wait(timeout=120) == 0
        for i in range(1, 5):
            a = np.load(out / f"follower_{i}.npz")
            err = np.linalg.norm(a["pos_err_m"], axis=1)
            err = err[np.isfinite(err)]  # real time: the rows before the vehicle's first sample are NaN
            t_s = a["t_s"][np.isfinite(np.linalg.norm(a["pos_err_m"], axis=1))]
            # from metres to the real-time bound the single-host run holds (test_swarm_processes),
            # judged over the last 4 s, not one sample
            assert err[0] > 1.0 and err[t_s >= DURATION_S - 4.0].max() < 0.05, (i, err[-20:])
    finally:
        for p in (vehicles, router):
            p.send_signal(signal.SIGINT)
            try:
                p.wait(timeout=20)
            except subprocess.TimeoutExpired:
                p.kill()
    links = json.loads((tmp_path / "veh" / "links.json").read_text())
    for name, st in links.items():
        # every datagram met its fate on the wire: the lost fraction is the plan's, within five
        # standard deviations of a binomial count
        n = st["received"]
        assert n > 400, (name, st)  # 12 s of 100 Hz setpoints up (less what lost time skips), more down
        assert abs(st["lost"] / n - LOSS) < 5 * math.sqrt(LOSS * (1 - LOSS) / n), (name, st)
