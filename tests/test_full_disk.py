"""A run on a filesystem that really fills: a tmpfs sized to hold the processes' raw records but
only half of the run directory's outputs. One line, exit 1, the raw records intact; with room made
(the tmpfs grown, as a user frees space), ``swarm-sitl merge`` writes the run directory and
``swarm-sitl plot`` draws it.

Needs root to mount a tmpfs; skipped, saying why, where that is not allowed."""

import math
import os
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from tests.support import CONFIGS, cli

#: its system tests run in lockstep or ``sim`` only (no wall clock): free to run beside others
pytestmark = [pytest.mark.system, pytest.mark.lockstep]
PAGE = 4096
OUTPUTS = ("summary.json", "events.jsonl", "leader.npz")


def _pages(paths) -> int:
    return sum(math.ceil(p.stat().st_size / PAGE) for p in paths if p.is_file())


@pytest.fixture
def small_disk(tmp_path):
    mnt = tmp_path / "disk"
    mnt.mkdir()
    if os.geteuid() != 0 or shutil.which("mount") is None:
        pytest.skip("mounting a tmpfs needs root and mount(8)")
    probe = subprocess.run(
        ["mount", "-t", "tmpfs", "-o", "size=64k", "tmpfs", str(mnt)], capture_output=True, text=True
    )
    if probe.returncode != 0:
        pytest.skip(f"this machine does not allow mounting a tmpfs: {probe.stderr.strip()}")

    def resize(n_bytes: int) -> None:
        subprocess.run(["mount", "-o", f"remount,size={n_bytes}", str(mnt)], check=True, capture_output=True)

    try:
        yield mnt, resize
    finally:
        subprocess.run(["umount", "-l", str(mnt)], capture_output=True)


def test_a_run_on_a_disk_that_fills_keeps_its_raw_records_and_is_rebuilt_where_there_is_room(
    tmp_path, small_disk
):
    mnt, resize = small_disk
    args = ["run", str(CONFIGS / "paper.yaml"), "--duration", "3", "--quiet"]
    good = tmp_path / "good"
    r = cli(*args, "--out", str(good), timeout=180)
    assert r.returncode == 0, r.stderr
    files = [p for p in good.rglob("*") if p.is_file()]
    outputs = [p for p in files if p.name in OUTPUTS or p.name.startswith("follower_")]
    raw = [p for p in files if p not in outputs]
    # room for every raw record (and a margin for the logs' wall-clock stamps), and half the outputs
    resize(PAGE * (_pages(raw) + 16 + _pages(outputs) // 2))
    full = mnt / "run"
    r = cli(*args, "--out", str(full), timeout=180)
    assert r.returncode == 1, r.stdout + r.stderr
    last = r.stderr.strip().splitlines()[-1]
    assert last.startswith(f"swarm-sitl: error: cannot write {full}/") and "(No space left on device)" in last
    assert f"`swarm-sitl merge {full}` writes the run directory from them" in last
    for p in raw:  # every raw record is there, whole (the run is lockstep: the same bytes)
        if p.parent.name == "procs" and p.suffix in (".rows", ".truth"):
            assert (full / "procs" / p.name).read_bytes() == p.read_bytes(), p.name
    resize(PAGE * (_pages(raw) + 16 + 2 * _pages(outputs)))  # room made
    r = cli("merge", str(full), timeout=120)
    assert r.returncode == 0, r.stderr
    for i in range(1, 5):
        a, b = np.load(good / f"follower_{i}.npz"), np.load(full / f"follower_{i}.npz")
        assert all(np.array_equal(a[k], b[k], equal_nan=True) for k in a.files), i
    r = cli("plot", str(full), timeout=120)
    assert r.returncode == 0, r.stderr
    assert (full / "plots").is_dir() and any(Path(full / "plots").glob("*.png"))
