"""Writing a run directory: each file whole or not at all, and a bad ``--out`` refused before
anything starts."""

import errno
import os
import signal
from collections import namedtuple

import numpy as np
import pytest

from swarm_sitl.rundir import recording
from swarm_sitl.rundir.layout import expected_run_bytes
from swarm_sitl.rundir.recording import save_npz
from swarm_sitl.rundir.whole_files import WriteError, write_text_whole
from tests.support import CONFIGS, cli, config

Usage = namedtuple("Usage", "total used free")


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
    r = cli(command.split("-")[0], str(CONFIGS / "paper.yaml"), "--out", str(out), timeout=60)
    assert r.returncode == 2, r.stderr
    assert r.stderr.strip() == f"swarm-sitl: error: --out {out}: {says}"
    assert f.read_text() == "mine\n"  # untouched


@pytest.mark.unit
def test_a_run_that_will_not_fit_is_warned_of_in_one_line(tmp_path, monkeypatch, capsys, paper_cfg):
    from swarm_sitl.commands import runs

    need = expected_run_bytes(
        paper_cfg.n_control_steps + 1, paper_cfg.n_followers, paper_cfg.law_class().record_fields
    )
    for free, warned in ((need - 1, True), (need, False)):
        monkeypatch.setattr(runs.shutil, "disk_usage", lambda _p, free=free: Usage(0, 0, free))
        runs.warn_if_short_of_disk(paper_cfg, tmp_path)
        assert bool(capsys.readouterr().err) == warned
    monkeypatch.setattr(runs.shutil, "disk_usage", lambda _p: Usage(0, 0, 10**6))
    not_yet = tmp_path / "not" / "yet"  # a run directory not made yet: its disk is its parent's
    runs.warn_if_short_of_disk(paper_cfg, not_yet)
    line = capsys.readouterr().err
    mb = f"{need / 1e6:.0f}"
    assert (
        line == f"swarm-sitl: warning: this run writes about {mb} MB to {not_yet}, whose disk has 1 MB free\n"
    )


@pytest.mark.unit
def test_a_failed_write_names_the_file_and_its_cause_in_one_line(tmp_path, monkeypatch):
    def full_disk(*args, **kwargs):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(recording.zipfile.ZipFile, "writestr", full_disk)
    with pytest.raises(WriteError) as e:
        save_npz(tmp_path / "leader.npz", {"a": np.zeros(2)})
    assert str(e.value) == f"cannot write {tmp_path / 'leader.npz'} (No space left on device)"
    assert e.value.errno == errno.ENOSPC and list(tmp_path.iterdir()) == []


@pytest.mark.system
def test_a_run_whose_disk_fills_keeps_its_raw_records_and_merge_rebuilds_it(tmp_path, monkeypatch, capsys):
    """The disk fills while the run directory is written: one line names the file and the cause,
    the processes' raw records stay, and `swarm-sitl merge RUN_DIR` writes the run directory from
    them, equal to what it would have been."""
    from swarm_sitl.commands.runs import _run_and_record

    cfg = config("paper").model_copy(update={"duration_s": 2.0})
    good = tmp_path / "good"
    assert _run_and_record(cfg, good, True, True, None, "run") == 0
    written = sum(p.stat().st_size for p in good.rglob("*") if p.is_file())
    expected = expected_run_bytes(cfg.n_control_steps + 1, cfg.n_followers, cfg.law_class().record_fields)
    assert 0.8 < written / expected < 1.25  # the low-disk warning's estimate

    real = recording.zipfile.ZipFile.writestr

    def full_disk_on_followers(self, info, data, *a, **k):
        if "follower_" in str(self.filename):
            raise OSError(errno.ENOSPC, "No space left on device")
        return real(self, info, data, *a, **k)

    monkeypatch.setattr(recording.zipfile.ZipFile, "writestr", full_disk_on_followers)
    full = tmp_path / "full"
    capsys.readouterr()
    code = _run_and_record(cfg, full, True, True, None, "run")
    monkeypatch.undo()
    assert code == 1
    err = capsys.readouterr().err.strip()
    assert err == (
        f"swarm-sitl: error: cannot write {full / 'follower_1.npz'} (No space left on device); every "
        f"process's raw records are kept in {full / 'procs'}: `swarm-sitl merge {full}` writes the run "
        "directory from them"
    )
    assert not list(full.glob("follower_*.npz")) and (full / "procs" / "controller_1.rows").is_file()
    r = cli("merge", str(full), timeout=120)
    assert r.returncode == 0, r.stderr
    for i in range(1, 5):
        a, b = np.load(good / f"follower_{i}.npz"), np.load(full / f"follower_{i}.npz")
        assert set(a.files) == set(b.files)
        for k in a.files:  # a lockstep run is the same twice: the rebuilt directory equals a good one
            assert np.array_equal(a[k], b[k], equal_nan=True), (i, k)


@pytest.mark.unit
@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGHUP], ids=lambda s: s.name)
def test_sigterm_and_sighup_interrupt_as_ctrl_c_does_with_their_own_exit_code(sig):
    """The CLI's handlers make either signal a KeyboardInterrupt where the main thread is (what
    run's teardown and writing already handle), whose exit code is 128 + the signal."""
    from swarm_sitl.commands.common import Terminated, end_on_signals, interrupted_exit

    before = {s: signal.getsignal(s) for s in (signal.SIGTERM, signal.SIGHUP)}
    try:
        end_on_signals()
        with pytest.raises(KeyboardInterrupt) as e:
            os.kill(os.getpid(), sig)
            for _ in range(1000):  # the handler runs between bytecodes of the main thread
                pass
        assert isinstance(e.value, Terminated)
        assert interrupted_exit(e.value) == (128 + sig, sig.name)
        assert interrupted_exit(KeyboardInterrupt()) == (130, "SIGINT")
    finally:
        for s, h in before.items():
            signal.signal(s, h)
