"""A run directory stands on its own (``rundir.plugins``): flown with a law from a file, moved
elsewhere with the law's file deleted, ``plot`` (every figure), ``export`` and ``merge`` read it
without importing any plug-in (they work with its kept copies removed too), and ``swarm-sitl run
RUN_DIR/config.yaml`` flies it again from the run directory alone, bit for bit."""

import hashlib
import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import yaml

from tests.support import CONFIGS, ROOT, cli_ok

#: its system tests run in lockstep or ``sim`` only (no wall clock): free to run beside others
pytestmark = pytest.mark.lockstep

LAW = ROOT / "examples" / "laws" / "consensus_pd.py"


def _arrays(run_dir: Path) -> dict[str, dict[str, np.ndarray]]:
    return {p.name: dict(np.load(p)) for p in sorted(run_dir.glob("*.npz"))}


def _same(a: dict, b: dict) -> bool:
    return a.keys() == b.keys() and all(
        a[f].keys() == b[f].keys() and all(np.array_equal(a[f][k], b[f][k], equal_nan=True) for k in a[f])
        for f in a
    )


@pytest.mark.system
@pytest.mark.parametrize("command", ["run", "sim"])
def test_a_moved_run_directory_reads_and_flies_again_without_the_law_file(tmp_path, command):
    src = tmp_path / "src"
    src.mkdir()
    shutil.copy(LAW, src / "my_law.py")
    data = yaml.safe_load((CONFIGS / "consensus_pd.yaml").read_text())
    data["law"]["entry"] = "my_law.py:ConsensusPD"
    data["duration_s"] = 2.0
    data["faults"] = {"plan": [{"edge": [1, 4], "loss": 0.3}]}
    (src / "cfg.yaml").write_text(yaml.safe_dump(data))
    cli_ok(command, "cfg.yaml", "--out", str(tmp_path / "first"), "--quiet", cwd=src)
    shutil.rmtree(src)  # the law's file, and the config that named it, gone
    moved = tmp_path / "elsewhere" / "run"
    moved.parent.mkdir()
    shutil.move(tmp_path / "first", moved)

    kept = json.loads((moved / "plugins.json").read_text())["law"]
    copy = moved / kept["kept"]
    assert (
        kept["sha256"]
        == hashlib.sha256(LAW.read_bytes()).hexdigest()
        == hashlib.sha256(copy.read_bytes()).hexdigest()
    )
    assert (
        yaml.safe_load((moved / "config.yaml").read_text())["law"]["entry"] == "plugins/my_law.py:ConsensusPD"
    )
    summary = json.loads((moved / "summary.json").read_text())
    assert summary["provenance"]["plugins"]["law"]["sha256"] == kept["sha256"]
    before = _arrays(moved)

    again = tmp_path / "again"  # from the run directory alone, elsewhere
    cli_ok(
        "run" if command == "run" else "sim",
        str(moved / "config.yaml"),
        "--out",
        str(again),
        "--quiet",
        cwd=tmp_path,
    )
    assert _same(_arrays(again), before)

    shutil.rmtree(moved / "plugins")  # the readers import no plug-in: the copies are not needed
    figures = cli_ok("plot", str(moved), cwd=tmp_path).stdout.split()
    names = {Path(f).name for f in figures}
    expected = {"position_error.png", "velocity_error.png", "estimator_error.png", "thrust.png"}
    assert expected <= names and all(Path(f).stat().st_size > 0 for f in figures)
    if command == "run":
        assert "links.png" in names  # the edges' traffic, read from the recorded config
        cli_ok("merge", str(moved), cwd=tmp_path)
        assert _same(_arrays(moved), before)
    cli_ok("export", str(moved), "--out", str(tmp_path / "run.mcap"), cwd=tmp_path)
    assert (tmp_path / "run.mcap").stat().st_size > 0
