"""A campaign flies a user's law wherever its runs go: the law's file travels with each run (a Dask
worker in another directory, on a machine without the file, gives the rows the local path gives),
and a run that outlasts its wall budget is a failed row, ``timed out``, not a hung campaign."""

import os
import shutil
import time
from pathlib import Path

import pytest
import yaml

import swarm_sitl
import swarm_sitl.campaigns.sweep as sweep_module
from swarm_sitl.campaigns.point import INTERRUPT_GRACE_S
from tests import misbehaving_laws
from tests.support import CONFIGS, ROOT

#: its system tests run in lockstep or ``sim`` only (no wall clock): free to run beside others
pytestmark = pytest.mark.lockstep


def _config(src: Path, entry: str, duration_s: float, params: dict | None = None) -> Path:
    data = yaml.safe_load((CONFIGS / "paper.yaml").read_text())
    data["duration_s"] = duration_s
    data["law"] = {"entry": entry, **({"params": params} if params else {})}
    data["run"] = {**data.get("run", {}), "settle_s": 1.0, "max_formation_error_m": 50.0}
    path = src / "campaign.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def _strip(rows):
    return [{k: v for k, v in r.items() if k != "wall_s"} for r in rows]


@pytest.mark.system
def test_a_campaign_on_dask_ships_the_law_file_and_gives_the_local_rows(tmp_path, monkeypatch):
    from distributed import LocalCluster

    src = tmp_path / "src"
    src.mkdir()
    shutil.copy(ROOT / "examples" / "laws" / "consensus_pd.py", src / "my_law.py")
    cfg = _config(src, "my_law.py:ConsensusPD", 3.0)
    vary = {"link.loss": [0.5]}
    here = swarm_sitl.sweep(cfg, vary, seeds=[2], out=tmp_path / "here", jobs=2)
    assert [r["failure"] for r in here.rows] == [""]
    assert (tmp_path / "here" / "points" / "plugins" / "my_law.py").is_file()

    real_pack = sweep_module.pack_with_models

    def pack_then_lose_the_file(base, models):  # packed: from now on the file exists nowhere
        shipped = real_pack(base, models)
        shutil.rmtree(src)
        return shipped

    monkeypatch.setattr(sweep_module, "pack_with_models", pack_then_lose_the_file)
    elsewhere = tmp_path / "worker_home"
    elsewhere.mkdir()
    cwd = os.getcwd()
    os.chdir(elsewhere)  # the workers start here, far from the law's directory
    try:
        with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as c:
            there = swarm_sitl.sweep(
                cfg, vary, seeds=[2], out=tmp_path / "there", scheduler=c.scheduler_address
            )
    finally:
        os.chdir(cwd)
    assert not src.exists()
    assert _strip(there.rows) == _strip(here.rows)


@pytest.mark.system
def test_a_run_past_its_wall_budget_is_a_timed_out_row_and_the_campaign_ends(tmp_path):
    """Follower 2 sleeping 0.25 s a tick makes a 2 s lockstep run last 50 s of wall time; with a
    budget of 10 s its row fails ``timed out`` and the campaign ends within the budget and the
    interrupt's grace; the point that sleeps not at all (a few seconds) passes."""
    src = tmp_path / "src"
    src.mkdir()
    cfg = _config(src, f"{Path(misbehaving_laws.__file__)}:Sleeps", 2.0, {"sleep_s": 0.0})
    t0 = time.monotonic()
    c = swarm_sitl.sweep(
        cfg, {"law.params.sleep_s": [0.0, 0.25]}, seeds=[0], out=tmp_path / "c", jobs=2, point_timeout_s=10.0
    )
    wall = time.monotonic() - t0
    by = {r["law.params.sleep_s"]: r for r in c.rows}
    assert by[0.0]["failure"] == "" and by[0.0]["passed"] == 1
    assert by[0.25]["failure"] == "timed out after 10 s (the point's wall budget)" and by[0.25]["passed"] == 0
    assert 10.0 <= by[0.25]["wall_s"] < 10.0 + INTERRUPT_GRACE_S
    assert wall < 10.0 + INTERRUPT_GRACE_S + 60.0
