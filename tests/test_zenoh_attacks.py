"""Attacks on a running swarm's zenoh bus, from sessions that use only zenoh's public API.

The run is the paper's scenario in lockstep, so "the formation stayed where it was" is exact:
every follower's recording equals ``sim``'s, bit for bit.
"""

import json
import struct
import subprocess
import threading
import time
import zlib

import numpy as np
import pytest
import yaml
import zenoh

from swarm_sitl.bus import keys as zenoh_keys
from swarm_sitl.rundir.layout import zenoh_users_path
from swarm_sitl.running.hub import free_tcp_port
from swarm_sitl.running.sim import run_sim
from tests.support import CONFIGS, start_cli
from tests.zenoh_client import client_session, client_session_once_up

#: its system tests run in lockstep or ``sim`` only (no wall clock): free to run beside others
pytestmark = [pytest.mark.system, pytest.mark.lockstep]


def _estimate(src: int, step: int, value: float) -> bytes:
    """An estimate as the bus's documented layout has it (``docs/bus.md``), written out here."""
    body = struct.pack("<BHId3dH12d", 4, src, step, step * 0.01, 0.0, 0.0, 0.0, 12, *[value] * 12)
    return body + struct.pack("<I", zlib.crc32(body))


def test_strangers_and_a_node_out_of_its_rights_leave_the_formation_where_it_was(tmp_path, paper_cfg):
    """While the run goes: a session without credentials is refused; one with follower 1's
    credentials puts false estimates on the leader's edge 0->1, a start signal 30 s late, and on
    its own edge 1->4 estimates of tick 2^32-1 and of a tick past the run; it subscribes to a
    wildcard and to follower 2's in-edge. Zenoh refuses the first ones, follower 4's bus the last
    ones (counted), the subscriptions stay empty, and every follower flies exactly as in ``sim``."""
    endpoint = f"tcp/127.0.0.1:{free_tcp_port()}"
    cfg = yaml.safe_load((CONFIGS / "paper.yaml").read_text())
    cfg["zenoh"] = {"listen": [endpoint]}
    cfg["duration_s"] = 8.0
    path = tmp_path / "paper.yaml"
    path.write_text(yaml.safe_dump(cfg))
    out = tmp_path / "run"
    run = start_cli(
        "run",
        str(path),
        "--out",
        str(out),
        "--quiet",
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        start_new_session=False,
    )
    try:
        users = zenoh_users_path(out)
        end = time.monotonic() + 120
        while not (users.exists() and users.stat().st_size > 0):
            assert run.poll() is None and time.monotonic() < end, "the run did not start"
            time.sleep(0.05)
        creds = dict(line.split(":", 1) for line in users.read_text().splitlines())
        # the router opens after it writes its users' file: once it admits node 1, it is listening,
        # and a refusal of the session without credentials is zenoh's, not an unbound port's
        insider = client_session_once_up(endpoint, ("node_1", creds["node_1"]), within_s=60.0)
        with pytest.raises(zenoh.ZError):
            client_session(endpoint, None)
        watcher = client_session(endpoint, ("node_1", creds["node_1"]))
        seen: dict[str, list[str]] = {"own in-edge": [], "wildcard": [], "2's in-edge": []}

        def keep(what: str):
            return lambda s: seen[what].append(str(s.key_expr))

        subs = [
            insider.declare_subscriber(zenoh_keys.edge("paper", 0, 1), keep("own in-edge")),
            watcher.declare_subscriber("swarm/paper/**", keep("wildcard")),
            insider.declare_subscriber(zenoh_keys.edge("paper", 0, 2), keep("2's in-edge")),
        ]
        n = 0
        stop = threading.Event()

        def attack() -> None:
            nonlocal n
            while not stop.is_set():
                insider.put(zenoh_keys.edge("paper", 0, 1), _estimate(0, n, 50.0))
                insider.put(zenoh_keys.start("paper"), struct.pack("<Bd", 3, time.time() + 30))
                insider.put(zenoh_keys.edge("paper", 1, 4), _estimate(1, 2**32 - 1, 50.0))
                insider.put(zenoh_keys.edge("paper", 1, 4), _estimate(1, 801, 50.0))
                n += 1
                time.sleep(0.02)  # 200 false messages a second: the point is their refusal, not load

        attacker = threading.Thread(target=attack)
        attacker.start()
        try:
            stdout, stderr = run.communicate(timeout=240)
        finally:
            stop.set()
            attacker.join()
            for s in subs:
                s.undeclare()
            insider.close()
            watcher.close()
    finally:
        if run.poll() is None:
            run.kill()
            run.wait()
    assert run.returncode == 0, stderr + stdout
    assert seen["own in-edge"], "the insider was not connected while the swarm ran"
    assert n > 100 and seen["wildcard"] == [] and seen["2's in-edge"] == []
    summary = json.loads((out / "summary.json").read_text())
    assert summary["links"]["1->4"]["refused"] > 0
    assert "refused" not in summary["links"].get("0->1", {})
    sim = run_sim(paper_cfg.model_copy(update={"duration_s": 8.0}))
    for i in range(1, 5):
        got = np.load(out / f"follower_{i}.npz")
        assert np.array_equal(got["p_W"], sim.followers[i]["p_W"]), f"follower {i} was moved"
        assert np.array_equal(got["p_hat"], sim.followers[i]["p_hat"])
