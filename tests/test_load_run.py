"""A run directory read back (``rundir.load.load_run``): its followers in their numbers' order
(10 after 9, not after 1), each with its offset taken apart from its arrays; a directory that is
not one is one line naming it, whatever else is in it."""

import numpy as np
import pytest

from swarm_sitl.rundir.load import RunDirError, load_run
from swarm_sitl.rundir.recording import save_npz

pytestmark = pytest.mark.unit


def test_followers_come_in_their_numbers_order_with_their_offsets(tmp_path):
    n = 5
    t = np.arange(n) * 0.01
    zeros = np.zeros((n, 3))
    save_npz(tmp_path / "leader.npz", {"t_s": t, "p_r": zeros, "v_r": zeros, "a_r": zeros})
    ids = [10, 2, 1, 9, 11]
    for i in ids:
        save_npz(
            tmp_path / f"follower_{i}.npz",
            {"t_s": t, "p_W": zeros + i, "v_W": zeros, "offset_m": np.full(3, i)},
        )
    rec = load_run(tmp_path)  # (no config.yaml: the errors against the leader's recorded reference)
    assert list(rec.followers) == sorted(ids)
    for i in ids:
        assert rec.offsets[i].tolist() == [i] * 3 and "offset_m" not in rec.followers[i]
        assert np.array_equal(rec.followers[i]["pos_err_m"], zeros)  # i - 0 - i


@pytest.mark.parametrize("inside", ["nothing", "procs only", "config only"])
def test_a_directory_that_is_not_a_run_is_one_line_naming_it(tmp_path, inside):
    if inside == "procs only":
        (tmp_path / "procs").mkdir()
    if inside == "config only":
        (tmp_path / "config.yaml").write_text("seed: 1\n")
    with pytest.raises(RunDirError) as e:
        load_run(tmp_path)
    assert str(e.value) == f"{tmp_path}: not a run directory (no leader.npz)"
