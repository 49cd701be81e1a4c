"""Writing a run directory: each file whole or not at all, and a bad ``--out`` refused before
anything starts."""

import subprocess
import sys

import numpy as np
import pytest

from swarm_sitl.rundir import recording
from swarm_sitl.rundir.recording import save_npz
from swarm_sitl.rundir.whole_files import write_text_whole
from tests.conftest import CONFIGS

CLI = [sys.executable, "-m", "swarm_sitl"]


@pytest.mark.unit
def test_a_write_cut_short_leaves_the_old_file_or_none_never_half(tmp_path, monkeypatch):
    old = tmp_path / "follower_1.npz"
    save_npz(old, {"a": np.arange(3.0)})
    before = old.read_bytes()
    calls = []

    def second_signal(*args, **kwargs):  # a second Ctrl-C while the second array is written
        calls.append(1)
        if len(calls) == 2:
            raise KeyboardInterrupt
        return real(*args, **kwargs)

    real = np.lib.format.write_array
    monkeypatch.setattr(recording.np.lib.format, "write_array", second_signal)
    new = {"a": np.arange(5.0), "b": np.ones(2)}
    with pytest.raises(KeyboardInterrupt):
        save_npz(old, new)
    with pytest.raises(KeyboardInterrupt):
        calls.clear()
        save_npz(tmp_path / "follower_2.npz", new)
    assert old.read_bytes() == before  # the old file, whole
    assert not (tmp_path / "follower_2.npz").exists()  # or none
    assert sorted(p.name for p in tmp_path.iterdir()) == ["follower_1.npz"]  # no leftovers
    monkeypatch.undo()
    save_npz(old, new)
    assert np.array_equal(np.load(old)["a"], np.arange(5.0))


@pytest.mark.unit
def test_text_is_replaced_whole(tmp_path):
    p = tmp_path / "summary.json"
    write_text_whole(p, "one\n")
    write_text_whole(p, "two\n")
    assert p.read_text() == "two\n" and [q.name for q in tmp_path.iterdir()] == ["summary.json"]


@pytest.mark.integration
@pytest.mark.parametrize(
    ("command", "says"),
    [
        ("run", "exists and is not a directory"),
        ("sim", "exists and is not a directory"),
        ("run-below-file", "cannot create it (Not a directory)"),
    ],
)
def test_a_bad_out_is_one_line_before_anything_starts(tmp_path, command, says):
    f = tmp_path / "a_file"
    f.write_text("mine\n")
    out = f / "sub" if command == "run-below-file" else f
    r = subprocess.run(
        [*CLI, command.split("-")[0], str(CONFIGS / "paper.yaml"), "--out", str(out)],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert r.returncode == 2, r.stderr
    assert r.stderr.strip() == f"swarm-sitl: error: --out {out}: {says}"
    assert f.read_text() == "mine\n"  # untouched
