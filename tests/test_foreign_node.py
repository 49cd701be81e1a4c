"""A controller the bench does not run joins a real-time swarm (``run --external``): written with
only ``zenoh`` and ``struct`` from ``docs/bus.md`` (``foreign_node.py``), it takes controller 3's
place, and a follower that hears it flies on its messages."""

import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import yaml

from tests.support import CONFIGS, start_cli

pytestmark = pytest.mark.system
HERE = Path(__file__).resolve().parent


def _complete(path: Path) -> bool:
    try:
        json.loads(path.read_text())
    except (OSError, ValueError):
        return False
    return True


def test_a_foreign_node_takes_a_controllers_place_and_the_formation_holds(tmp_path):
    cfg = yaml.safe_load((CONFIGS / "paper.yaml").read_text())
    cfg["graph"]["edges"].append([3, 4])  # so the foreign node's messages are flown on, by 4
    cfg["signing"] = {"enabled": False}  # it frames MAVLink by hand, unsigned
    path = tmp_path / "paper_3to4.yaml"
    path.write_text(yaml.safe_dump(cfg))
    out = tmp_path / "run"
    duration = 12.0
    run_args = ["--duration", str(duration), "--out", str(out), "--quiet"]
    node_args = ["--id", "3", "--offset", "-2", "-2", "0", "--duration", str(duration), "--out-edges", "4"]
    run = start_cli(
        "run",
        str(path),
        "--realtime",
        "--external",
        "3",
        *run_args,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        start_new_session=False,
    )
    node = None
    try:
        info = out / "external.json"
        end = time.monotonic() + 120
        while not _complete(info) and run.poll() is None and time.monotonic() < end:
            time.sleep(0.1)
        assert _complete(info), run.communicate()
        assert info.stat().st_mode & 0o077 == 0  # it holds a zenoh password
        node = subprocess.Popen(
            [sys.executable, str(HERE / "foreign_node.py"), str(info), *node_args],
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
        )
        stdout, stderr = run.communicate(timeout=240)
        assert run.returncode == 0, stderr + stdout
        node_out = node.communicate(timeout=30)[0]
        assert node.returncode == 0, node_out
    finally:
        for p in (run, node):
            if p is not None and p.poll() is None:
                p.kill()
    assert "controller 3: yours" in stdout
    summary = json.loads((out / "summary.json").read_text())
    f3 = np.load(out / "follower_3.npz")
    err3 = np.linalg.norm(f3["pos_err_m"], axis=1)
    t = f3["t_s"]
    late = (t >= 8) & np.isfinite(err3)
    assert late.sum() > 0.9 * np.sum(t >= 8)  # its truth, tick by tick, though nobody of ours recorded it
    assert err3[late].max() < 0.1  # its PD flies it into its place
    assert np.isnan(f3["thrust_N"]).all()  # no command recorded: not our controller
    f4 = np.load(out / "follower_4.npz")
    assert np.nanmax(np.linalg.norm(f4["pos_err_m"][f4["t_s"] >= 8], axis=1)) < 0.05
    link = summary["links"]["3->4"]
    assert link["received"] > 0.9 * duration / 0.01  # 4 heard 3 every tick, give or take
