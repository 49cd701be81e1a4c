"""``sim`` with flat memory (``rundir.spool``): rows spooled to disk a block at a time give back
the arrays a recording in memory holds, bit for bit, whatever the blocks; an .npz written a block
at a time is ``save_npz``'s file byte for byte; and ``swarm-sitl sim`` writes the same run
directory, byte for byte, as the same run recorded in memory and written whole."""

import filecmp
import itertools
import tempfile
from pathlib import Path

import numpy as np
import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st

from sim_vehicles.common.command import AttitudeCommand
from sim_vehicles.common.state import STATE_SIZE
from swarm_sitl.config.load import parse_config, with_duration
from swarm_sitl.rundir import spool
from swarm_sitl.rundir.outputs import write_outputs
from swarm_sitl.rundir.recording import FollowerSeries, save_npz
from swarm_sitl.running.sim import SimFailedError, run_sim
from tests.misbehaving_runs import LAWS_FILE
from tests.support import cli_in_process, config

FIELDS = {"p_hat": 3, "gamma": 1, "u": 3}


def _command(rng) -> AttitudeCommand:
    q = rng.normal(size=4)
    return AttitudeCommand(
        q / np.linalg.norm(q), float(rng.uniform(0, 20)), rng.normal(size=3), rng.normal(size=3)
    )


@pytest.mark.unit
@settings(max_examples=60, deadline=None)
@given(st.integers(1, 300), st.integers(1, 64), st.integers(0, 3), st.integers(0, 2**32 - 1))
def test_spooled_rows_read_back_as_the_series_in_memory_whatever_the_blocks(n, block, n_in, seed):
    rng = np.random.default_rng(seed)
    with tempfile.TemporaryDirectory() as d:
        _spooled_equals_memory(rng, Path(d), n, block, n_in)


def _spooled_equals_memory(rng, d, n, block, n_in):
    memory = FollowerSeries(n, FIELDS, n_in)
    disk = spool.SpooledSeries(d / "s", n, FIELDS, n_in, block_rows=block)
    for k in range(n):  # some ticks not recorded at all, some with their vehicle only (NaN rows)
        if rng.random() < 0.15:
            continue
        state, t = rng.normal(size=STATE_SIZE), k * 0.01
        sample_t = None if rng.random() < 0.5 else t - 0.003
        for s in (memory, disk):
            s.record_vehicle(k, t, state, sample_t)
        if rng.random() < 0.1:
            continue
        cmd, record, ages = _command(rng), rng.normal(size=sum(FIELDS.values())), rng.normal(size=n_in)
        for s in (memory, disk):
            s.record_controller(k, cmd, record, ages)
    read_block = int(rng.integers(1, 80))
    blocks = list(disk.close().blocks(read_block))
    assert [a for a, _ in blocks] == list(range(0, n, read_block))
    whole = memory.arrays()
    for name, a in whole.items():
        back = np.concatenate([b[name] for _, b in blocks])
        assert back.shape == a.shape and back.tobytes() == np.ascontiguousarray(a).tobytes(), name


@pytest.mark.unit
def test_a_row_recorded_before_a_written_block_is_refused(tmp_path):
    s = spool.SpooledSeries(tmp_path, 20, FIELDS, 0, block_rows=4)
    s.record_vehicle(9, 0.09, np.zeros(STATE_SIZE))
    with pytest.raises(spool.SpoolError, match="row 2 recorded after rows from 8 on were written"):
        s.record_vehicle(2, 0.02, np.zeros(STATE_SIZE))


@pytest.mark.unit
@settings(max_examples=40, deadline=None)
@given(st.integers(0, 200), st.integers(0, 2**32 - 1))
def test_an_npz_written_in_blocks_is_save_npzs_file_byte_for_byte(n, seed):
    rng = np.random.default_rng(seed)
    arrays = {
        "t_s": np.arange(n) * 0.01,
        "p_W": rng.normal(size=(n, 7))[:, 2:5],  # a strided view, as a series is
        "f_ordered": np.asfortranarray(rng.normal(size=(n, 3))),
        "in_age_s": rng.normal(size=(n, int(rng.integers(0, 3)))),
    }
    with tempfile.TemporaryDirectory() as tmp:
        _npz_blocks_equal_save_npz(rng, Path(tmp), n, arrays)


def _npz_blocks_equal_save_npz(rng, d, n, arrays):
    save_npz(d / "whole.npz", {"offset_m": np.array([1.0, 2.0, 0.5]), **arrays})
    out = spool.NpzBlocks(d / "blocks.npz", d / "work", {"offset_m": np.array([1.0, 2.0, 0.5])})
    cuts = sorted(rng.integers(0, n + 1, size=int(rng.integers(0, 5))).tolist())
    for a, b in itertools.pairwise([0, *cuts, n]):
        out.add({k: v[a:b] for k, v in arrays.items()})
    out.close()
    assert (d / "blocks.npz").read_bytes() == (d / "whole.npz").read_bytes()
    assert not (d / "work").exists()


def _flown(tmp_path, monkeypatch, data, name):
    """The run of config ``data`` by ``swarm-sitl sim`` (blocks of 97 rows), and in memory
    written whole: the two directories."""
    monkeypatch.setattr(spool, "BLOCK_ROWS", 97)
    cfg = parse_config(data, name)
    (tmp_path / "memory").mkdir()
    try:
        rec = run_sim(cfg)
    except SimFailedError as e:  # (what it recorded before, as sim writes it)
        rec = e.recording
    write_outputs(cfg, rec, tmp_path / "memory")
    path = tmp_path / f"{name}.yaml"
    path.write_text(yaml.safe_dump(data))
    code, _, _ = cli_in_process("sim", path, "--quiet", "--out", tmp_path / "spooled")
    return code, tmp_path / "memory", tmp_path / "spooled"


def _files(d):
    return sorted(str(p.relative_to(d)) for p in d.rglob("*") if p.is_file())


@pytest.mark.integration
@pytest.mark.parametrize("case", ["paper", "faults and a spec", "a law that fails"])
def test_sim_writes_the_run_directory_of_the_run_in_memory_byte_for_byte(tmp_path, monkeypatch, case):
    data = with_duration(config("paper"), 6.0).data()
    if case == "faults and a spec":  # sim_plan's series, a vehicle lost, signals judged whole
        plan = [{"edge": [0, 1], "loss": 0.3}, {"vehicle": 2, "kill": True, "from_s": 2.0}]
        data["faults"] = {"seed": 5, "plan": plan}
        data["spec"] = [{"name": "near", "formula": "always[2, end] (pos_err_m <= 2.0)"}]
    if case == "a law that fails":  # (at 0.5 s: the rows after it NaN)
        data["law"] = {"entry": f"{LAWS_FILE}:SysExit"}
    code, memory, spooled = _flown(tmp_path, monkeypatch, data, case.replace(" ", "_"))
    assert code == {"paper": 0, "faults and a spec": 3, "a law that fails": 1}[case]
    files = _files(memory)
    assert [f for f in _files(spooled) if not f.startswith("logs/")] == files  # (no spool left)
    for f in files:
        assert filecmp.cmp(memory / f, spooled / f, shallow=False), f
