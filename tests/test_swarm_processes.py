"""The swarm as real processes on loopback, through the CLI a user types (``swarm-sitl run`` ...)."""

import json
import os
import re
import signal
import socket
import subprocess
import sys

import numpy as np
import pytest
import yaml
from pymavlink import mavutil

from sim_vehicles.runtime.row_log import read_rows
from swarm_sitl.config.load import parse_config
from swarm_sitl.running.sim import run_sim
from tests.support import (
    CONFIGS,
    cli,
    cmdline,
    processes_mentioning,
    start_cli,
    start_paper_run,
    udp_port_free,
    vehicle_ports,
    wait_running,
)

pytestmark = pytest.mark.system
# A shell that starts a job in the background ignores SIGINT in it, and an ignored signal stays
# ignored in every child: the Ctrl-C tests below would then test nothing. Restore the default
# here; the processes these tests start inherit it.
signal.signal(signal.SIGINT, signal.default_int_handler)


@pytest.fixture(scope="module")
def sim20(paper_cfg):
    return run_sim(paper_cfg.model_copy(update={"duration_s": 20.0}))


@pytest.mark.lockstep
def test_lockstep_run_equals_sim_and_is_repeatable(tmp_path, sim20):
    runs = []
    for name in ("a", "b"):
        out = tmp_path / name
        r = cli("run", CONFIGS / "paper.yaml", "--duration", 20, "--out", out, "--quiet")
        assert r.returncode == 0, r.stderr + r.stdout
        runs.append({i: dict(np.load(out / f"follower_{i}.npz")) for i in range(1, 5)})
    for i, s in sim20.followers.items():
        a, b = runs[0][i], runs[1][i]
        assert np.isfinite(a["p_W"]).all()
        assert np.abs(a["p_W"] - s["p_W"]).max() <= 1e-9  # the bound; in fact bit for bit
        assert np.abs(a["v_W"] - s["v_W"]).max() <= 1e-9
        assert np.abs(a["p_hat"] - s["p_hat"]).max() <= 1e-9
        for key in a:
            assert np.array_equal(a[key], b[key], equal_nan=True), key  # two runs: identical

    out = tmp_path / "a"
    assert {p.name for p in (out / "logs").iterdir()} >= {"leader.log", "controller_4.log", "vehicle_4.log"}
    log = mavutil.mavlink_connection(str(out / "tlogs" / "vehicle_2.tlog"))
    kinds: dict[str, int] = {}
    while (m := log.recv_match()) is not None:
        kinds[m.get_type()] = kinds.get(m.get_type(), 0) + 1
    # one setpoint per tick, plus any resent after a lost answer (a slow moment of a loaded machine)
    assert kinds["SET_ATTITUDE_TARGET"] >= 2000 and kinds["LOCAL_POSITION_NED"] >= 2001
    _, truth = read_rows(out / "procs" / "vehicle_2.truth")
    assert len(np.unique(np.round(truth[:, 0] * 1000))) == 2001  # stepped exactly once per tick
    assert {"HEARTBEAT", "PARAM_VALUE", "COMMAND_ACK", "ATTITUDE_QUATERNION"} <= set(kinds)
    assert not processes_mentioning(str(tmp_path))


def test_realtime_run_reaches_the_formation(tmp_path, paper_cfg):
    out = tmp_path / "rt"
    r = cli("run", CONFIGS / "paper.yaml", "--realtime", "--duration", 14, "--out", out, "--quiet")
    assert r.returncode == 0, r.stderr + r.stdout
    summary = json.loads((out / "summary.json").read_text())
    logs = "; ".join(
        (out / "logs" / f"controller_{i}.log").read_text().strip().splitlines()[-1] for i in range(1, 5)
    )
    worst_after_10 = 0.0
    for i in range(1, 5):
        a = np.load(out / f"follower_{i}.npz")
        t, p, s = a["t_s"], a["p_W"], a["sample_t_s"]
        ok = np.isfinite(t)
        # ticks recorded: a tick that starts a whole period late is skipped (NaN); on a loaded 2-core
        # machine that can be a fifth of them, and the formation must hold regardless
        assert ok.mean() > 0.5, logs
        dt = 0.01
        # staggered ticks (the real-time default): follower i ticks (i - 1) / 4 of a period late
        assert np.allclose(t[ok] - np.flatnonzero(ok) * dt, (i - 1) / 4 * dt, atol=1e-12), i
        age = t[ok] - s[ok]
        assert np.all(age >= 0), (i, age.min())
        # samples are recent. The vehicle's stream grid has an arbitrary phase against the ticks, so a
        # tick reads the latest sample or, when that one is still in flight, the one before: at most
        # one period plus its delivery delay. A controller reading a stale queue would sit periods
        # behind. The tail is left to the machine's load: a vehicle held off the CPU sends late.
        assert np.median(age) < dt + 0.005 and np.percentile(age, 90) < 3 * dt, (
            i,
            np.percentile(age, [50, 90, 99, 100]),
            logs,
        )
        assert np.isfinite(p[ok]).all()
        # each in-edge's newest estimate was made at a tick of its sender: t - age is one of the
        # sender's instants (its tick times its period, plus its phase), at most a period after
        # this tick's (a tick that starts late reads what came meanwhile; one a period late is
        # skipped)
        sources = [src for src, _ in paper_cfg.build_graph().in_neighbours(i)]
        for j, src in enumerate(sources):
            heard = ok & np.isfinite(a["in_age_s"][:, j])
            assert heard.mean() > 0.5, (i, src)
            made = t[heard] - a["in_age_s"][heard, j]
            ticks = (made - (0.0 if src == 0 else (src - 1) / 4 * dt)) / dt
            assert np.allclose(ticks, np.round(ticks), rtol=0, atol=1e-6), (i, src)
            assert np.all(a["in_age_s"][heard, j] >= -dt - 1e-9), (i, src)
        assert summary["followers"][str(i)]["final_pos_err_m"] < 0.05, (i, summary["followers"][str(i)], logs)
        e = np.linalg.norm(a["pos_err_m"], axis=1)
        worst_after_10 = max(worst_after_10, float(np.nanmax(e[t >= 10.0])))
    assert worst_after_10 < 0.05, (worst_after_10, logs)


@pytest.mark.lockstep
def test_a_process_failing_to_start_tears_everything_down(tmp_path):
    busy = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    busy.bind(("127.0.0.1", 0))
    busy.listen()
    cfg = yaml.safe_load((CONFIGS / "paper.yaml").read_text())
    taken = f"tcp/127.0.0.1:{busy.getsockname()[1]}"
    cfg["zenoh"] = {"mode": "peer", "listen": [taken]}  # every node fails to listen
    path = tmp_path / "bad.yaml"
    path.write_text(yaml.safe_dump(cfg))
    out = tmp_path / "run"
    r = cli("run", path, "--out", out, "--quiet", "--duration", 5)
    assert r.returncode == 1
    line = r.stderr.strip().splitlines()[-1]
    assert re.search(r"(leader|controller_\d) exited with code 1: .*zenoh", line), r.stderr
    assert not processes_mentioning(str(tmp_path))
    assert all(udp_port_free(p) for p in vehicle_ports(out))
    cfg["zenoh"] = {"mode": "router", "listen": [taken]}  # the supervisor's router cannot listen
    path.write_text(yaml.safe_dump(cfg))
    r = cli("run", path, "--out", tmp_path / "run2", "--quiet", "--duration", 5)
    busy.close()
    assert r.returncode == 1 and len(r.stderr.strip().splitlines()) == 1, r.stderr
    assert "zenoh (router mode): Can not create a new TCP listener" in r.stderr
    assert not processes_mentioning(str(tmp_path))


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM], ids=lambda s: s.name)
def test_ctrl_c_or_sigterm_leaves_no_process_no_bound_port_and_the_run_written(tmp_path, sig):
    """SIGTERM (timeout, systemd, CI runners, container stops) ends a run as Ctrl-C does:
    everything torn down, the run directory written whole from what was recorded, one line, exit
    128 + the signal. (SIGHUP takes the same path: ``test_run_dir_writes``.)"""
    out = tmp_path / "int"
    proc = start_paper_run(out, "--realtime", "--duration", 60)
    wait_running(out)
    ports = vehicle_ports(out)
    assert len(ports) == 4 and not any(udp_port_free(p) for p in ports)
    proc.send_signal(sig)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 128 + sig, err
    assert err.strip().splitlines()[-1].startswith(f"swarm-sitl: interrupted ({sig.name}); partial run in")
    assert "Traceback" not in err
    assert not processes_mentioning(str(tmp_path))
    assert all(udp_port_free(p) for p in ports)
    a = np.load(out / "follower_1.npz")  # what was recorded is kept
    assert np.isfinite(a["p_W"]).any()
    assert json.loads((out / "summary.json").read_text())["swarm"]
    assert not list(out.glob(".*.partial"))  # every file written whole


def test_a_killed_controller_ends_the_run_naming_it(tmp_path):
    out = tmp_path / "kill"
    proc = start_paper_run(out, "--duration", 60)
    wait_running(out)
    victim = [
        pid
        for pid in processes_mentioning(str(out))
        if " controller " in cmdline(pid) and "--id 3" in cmdline(pid)
    ]
    assert len(victim) == 1
    os.kill(victim[0], signal.SIGKILL)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 1
    assert "controller_3 exited with code -9" in err
    assert not processes_mentioning(str(tmp_path))


def test_own_vehicles_and_controllers_meet_over_given_endpoints(tmp_path, paper_cfg):
    """``vehicles`` on one side, ``controllers --mavlink`` on the other, as a user would split them,
    two of the vehicles speaking as PX4 and two as ArduCopter: the controllers read only the
    autopilots' own parameters and fly the swarm as ``sim`` does."""
    data = yaml.safe_load((CONFIGS / "paper.yaml").read_text())
    for f in data["followers"]:
        if f["id"] in (2, 4):
            f["autopilot"] = "ardupilot"
    mixed = tmp_path / "mixed.yaml"
    mixed.write_text(yaml.safe_dump(data))
    vehicles = start_cli(
        "vehicles",
        str(mixed),
        "--lockstep",
        "--out",
        str(tmp_path / "veh"),
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        start_new_session=True,
    )
    try:
        urls = []
        while len(urls) < 4:
            line = vehicles.stdout.readline()
            assert line, vehicles.stderr.read()
            m = re.search(r"vehicle \d+: controller (udpout:[^\s,]+)", line)
            if m:
                urls.append(m.group(1))
        out = tmp_path / "ctl"
        r = cli(
            "controllers",
            mixed,
            "--lockstep",
            "--duration",
            5,
            "--out",
            out,
            "--quiet",
            "--mavlink",
            *urls,
        )
        assert r.returncode == 0, r.stderr
    finally:
        vehicles.send_signal(signal.SIGINT)
        vehicles.communicate(timeout=30)
    assert vehicles.returncode == 0
    sim = run_sim(parse_config({**data, "duration_s": 5.0}))
    for i in range(1, 5):
        a = np.load(out / f"follower_{i}.npz")
        # no truth from vehicles that are not ours: the run records the float32 samples it received
        assert np.abs(a["p_W"] - sim.followers[i]["p_W"]).max() < 1e-5
        assert np.array_equal(a["p_hat"], sim.followers[i]["p_hat"])  # the controllers are exact
    assert not processes_mentioning(str(tmp_path))


ROUTER = """
import json, signal, sys, time, zenoh
c = zenoh.Config()
c.insert_json5("mode", '"router"')
c.insert_json5("listen/endpoints", json.dumps([sys.argv[1]]))
c.insert_json5("scouting/multicast/enabled", "false")
s = zenoh.open(c)
print("up", flush=True)
signal.signal(signal.SIGTERM, lambda *a: sys.exit(0))
while True:
    time.sleep(1)
"""


def test_the_same_swarm_runs_as_zenoh_peers(tmp_path, paper_cfg):
    """``zenoh.mode: peer``: no router, no authentication; the nodes meet at the supervisor's
    session and talk to each other directly. The same run, bit for bit."""
    cfg = yaml.safe_load((CONFIGS / "paper.yaml").read_text())
    cfg["zenoh"] = {"mode": "peer"}
    path = tmp_path / "peers.yaml"
    path.write_text(yaml.safe_dump(cfg))
    out = tmp_path / "run"
    r = cli("run", path, "--duration", 3, "--out", out, "--quiet")
    assert r.returncode == 0, r.stderr
    assert not (out / "zenoh_users.txt").exists()
    sim = run_sim(paper_cfg.model_copy(update={"duration_s": 3.0}))
    for i in range(1, 5):
        assert np.array_equal(np.load(out / f"follower_{i}.npz")["p_W"], sim.followers[i]["p_W"])


def test_the_same_swarm_runs_through_a_zenoh_router(tmp_path, paper_cfg):
    """Client sessions through a router (a Python session in router mode; zenohd would do the same):
    the configuration a multi-host swarm uses, here on loopback."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        endpoint = f"tcp/127.0.0.1:{s.getsockname()[1]}"
    router = subprocess.Popen([sys.executable, "-c", ROUTER, endpoint], stdout=subprocess.PIPE, text=True)
    try:
        assert router.stdout.readline().strip() == "up"
        cfg = yaml.safe_load((CONFIGS / "paper.yaml").read_text())
        cfg["zenoh"] = {"mode": "client", "connect": [endpoint]}
        path = tmp_path / "routed.yaml"
        path.write_text(yaml.safe_dump(cfg))
        out = tmp_path / "run"
        r = cli("run", path, "--duration", 3, "--out", out, "--quiet")
        assert r.returncode == 0, r.stderr
    finally:
        router.terminate()
        router.wait(timeout=10)
    sim = run_sim(paper_cfg.model_copy(update={"duration_s": 3.0}))
    for i in range(1, 5):
        assert np.array_equal(np.load(out / f"follower_{i}.npz")["p_W"], sim.followers[i]["p_W"])
