"""A follower flown by a ROS 2 node (``run --ros2-controller 4 --realtime``): the node, written
here with ``zenoh-ros2-sdk`` only (no code of ours on its wire), joins the run's router as the user
the run names for follower 4, reads its vehicle's odometry and its in-neighbours' messages as ROS 2
topics, runs the paper's law on them and publishes its setpoint and its own message. Follower 4
reaches the formation, the commands its vehicle flew are the node's, and the node's rights are its
follower's control topics alone."""

import json

import numpy as np
import pytest
import zenoh

from swarm_sitl.bus.access import access_control, ros2_controller_user
from swarm_sitl.nodes.ros2_controller import SETPOINT
from swarm_sitl.ros2 import types
from tests.support import CONFIGS, ROOT, config, fresh_ros2_client, msg_dir, ros2_user_session, start_cli


@pytest.mark.unit
@pytest.mark.parametrize("flown", [[1], [2, 4]])
def test_a_ros2_controllers_user_writes_only_its_followers_setpoint_and_message(flown):
    cfg = config("paper")
    controls = {i: f"swarm/follower_{i}/control" for i in flown}
    ac = access_control(cfg.name, [cfg.node_keys(n) for n in range(5)], 0, controls)
    for i in flown:
        who = ros2_controller_user(i)
        granted = {r for p in ac["policies"] if who in p["subjects"] for r in p["rules"]}
        puts = [
            k
            for r in ac["rules"]
            if r["id"] in granted and "put" in r["messages"] and "ingress" in r["flows"]
            for k in r["key_exprs"]
        ]
        assert sorted(puts) == [
            f"0/swarm/follower_{i}/control/message/**",
            f"0/swarm/follower_{i}/control/setpoint/**",
        ]
        node = {r for p in ac["policies"] if f"node_{i}" in p["subjects"] for r in p["rules"]}
        node_puts = {
            k
            for r in ac["rules"]
            if r["id"] in node and "put" in r["messages"] and "ingress" in r["flows"]
            for k in r["key_exprs"]
        }
        froms = {f"0/swarm/follower_{i}/control/from_{s}/**" for s, _ in cfg.build_graph().in_neighbours(i)}
        assert node_puts >= {f"0/swarm/follower_{i}/control/odom/**", *froms}


def _example():
    """``examples/ros2_controller.py``, imported as the user runs it (it is no module of ours)."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("ros2_controller", ROOT / "examples" / "ros2_controller.py")
    assert spec is not None and spec.loader is not None
    example = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(example)
    return example


@pytest.mark.system
def test_the_examples_ros2_node_flies_follower_4_into_the_formation(tmp_path, monkeypatch):
    example = _example()
    cfg = config("paper")
    out = tmp_path / "run"
    fresh_ros2_client(monkeypatch)  # (its own session, as the node's user, and its own .msg files)
    monkeypatch.setenv("ZENOH_CONFIG_OVERRIDE", "")  # (the example sets it)
    plan = tmp_path / "plan.yaml"  # beside our controllers, under an edge fault into its follower
    plan.write_text(json.dumps({"seed": 3, "plan": [{"edge": [1, 4], "loss": 0.3}]}))
    flags = ("--realtime", "--ros2-controller", 4, "--duration", 14, "--quiet", "--faults", plan)
    run = start_cli("run", CONFIGS / "paper.yaml", *flags, "--out", out)
    reader = ros2_user_session(out)  # the read-only ROS 2 user, on the whole domain (ros2 topic echo)
    heard = reader.declare_subscriber("0/**", zenoh.handlers.FifoChannel(1_000_000))
    sent = example.fly(out, 4, msg_dir(tmp_path / "msgs", [types.ODOMETRY, types.ESTIMATE, SETPOINT]))
    stdout, stderr = run.communicate(timeout=120)
    assert run.returncode == 0, stderr + stdout
    topics = set()
    while (sample := heard.try_recv()) is not None:
        topics.add("/".join(str(sample.key_expr).split("/")[1:-2]))
    reader.close()
    # it reads the bridge's topics, the node's and the leader's clock by its one wildcard
    assert {"clock", "swarm/follower_4/control/odom", "swarm/follower_4/control/setpoint"} <= topics
    a = np.load(out / "follower_4.npz")
    kept = np.isfinite(a["t_s"]) & np.isfinite(a["thrust_N"])  # (ticks recorded)
    flown, t, err = a["thrust_N"][kept], a["t_s"][kept], np.linalg.norm(a["pos_err_m"][kept], axis=1)
    hover = flown[0]  # the bridge's, before the node's first setpoint
    assert hover == pytest.approx(cfg.vehicle.mass_kg * cfg.gravity_mps2, rel=1e-6)
    first = int(np.argmax(flown != hover))  # the node's first setpoint flown
    assert first > 0 and t[first] < 4.0, f"the node's first setpoint flew at {t[first]:.2f} s"
    assert np.all(flown[first:] != hover)  # from then on its thrusts (computed: never that one exactly)
    assert sent > 0.5 * (len(t) - first)  # it answered most ticks from its first on
    # the formation: within 0.1 m (what the run reports as converged) over the run's last 3 s;
    # later than our controllers (tests/test_restarts.py: 0.05 m from 6 s on): its answers fly at
    # least a tick late, several when this machine is loaded, and it waits to hear its
    # in-neighbours (0.127 m seen 6 s after its first setpoint beside a lockstep run, 0.069 m
    # beside two workers; under 0.1 m a few tenths of a second later)
    settled = t > t[-1] - 3.0
    said = (
        t[first],
        sent,
        len(t),
        float(np.nanmax(err[settled], initial=0.0)),
    )  # (first, answers, ticks, worst)
    assert settled.sum() > 100 and np.nanmax(err[settled]) < 0.1, said  # (ticks skipped under load)
    edge = json.loads((out / "summary.json").read_text())["links"]["1->4"]
    assert 0.2 < edge["lost"] / edge["received"] < 0.4  # the plan's loss, on the bridge's in-edge
    assert np.all(np.isnan(a["p_hat"]))  # and the law's internals are the node's: not recorded here


@pytest.mark.system
@pytest.mark.lockstep
def test_in_lockstep_the_node_answers_every_tick_and_its_answer_flies_at_that_tick(tmp_path, monkeypatch):
    """The same node, a lockstep run: the bridge waits for its answer to each tick's odometry, so
    every tick's recorded thrust is the node's answer to that very tick, the followers it does
    not feed (4 has no out-edge) are sim's bit for bit, and follower 4 reaches the formation."""
    from swarm_sitl.running.sim import run_sim

    example = _example()
    fresh_ros2_client(monkeypatch)
    monkeypatch.setenv("ZENOH_CONFIG_OVERRIDE", "")
    out, dur = tmp_path / "run", 8.0
    run = start_cli(
        "run", CONFIGS / "paper.yaml", "--ros2-controller", 4, "--duration", dur, "--quiet", "--out", out
    )
    answers: list = []
    example.fly(out, 4, msg_dir(tmp_path / "msgs", [types.ODOMETRY, types.ESTIMATE, SETPOINT]), answers)
    stdout, stderr = run.communicate(timeout=120)
    assert run.returncode == 0, stderr + stdout
    a = np.load(out / "follower_4.npz")
    n = round(dur * 100)
    assert [round(t * 100) for t, _ in answers] == list(range(n + 1))  # each tick once, in order
    assert np.array_equal(a["thrust_N"], np.array([th for _, th in answers]))  # flown at its own tick
    sim = run_sim(config("paper").model_copy(update={"duration_s": dur}))
    for i in (1, 2, 3):
        assert np.array_equal(np.load(out / f"follower_{i}.npz")["p_W"], sim.followers[i]["p_W"]), i
    err = np.linalg.norm(a["pos_err_m"], axis=1)
    assert np.all(
        err[a["t_s"] > 6.0] < 0.05
    )  # (our controllers' bound after the same settling: test_restarts)
