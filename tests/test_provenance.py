"""``summary.json``'s ``provenance``: the versions, each plug-in's hash and the seeds a run was
made with, so two runs made with different code can be told apart."""

import hashlib
import platform
import shutil
import subprocess
from importlib import metadata

import pytest
import yaml

from swarm_sitl.config.load import parse_config
from swarm_sitl.rundir.provenance import git_describe, provenance
from tests.support import CONFIGS, ROOT, config

pytestmark = pytest.mark.unit


def test_it_names_the_versions_in_use_and_the_seeds():
    cfg = config("paper")
    p = provenance(cfg)
    assert p["swarm_sitl"] == {"version": metadata.version("swarm-sitl"), "git": git_describe(ROOT)}
    assert p["python"] == platform.python_version()
    assert (p["numpy"], p["numba"], p["zenoh"], p["pymavlink"]) == tuple(
        metadata.version(d) for d in ("numpy", "numba", "eclipse-zenoh", "pymavlink")
    )
    assert p["seeds"] == {"run": 0, "faults": 0, "law": 0, "wind": 0, "sensors": 0}
    assert p["pinned_seeds"] == []
    assert p["plugins"]["law"]["entry"] == "swarm_sitl.laws.zou_meng:ZouMengLaw"
    paper_law = ROOT / "swarm_sitl" / "laws" / "zou_meng.py"
    assert p["plugins"]["law"]["sha256"] == hashlib.sha256(paper_law.read_bytes()).hexdigest()


def test_each_plug_in_file_is_hashed_and_a_changed_file_hashes_otherwise(tmp_path):
    law = tmp_path / "my_law.py"
    law.write_text((ROOT / "examples" / "laws" / "consensus_pd.py").read_text())
    data = yaml.safe_load((CONFIGS / "consensus_pd.yaml").read_text())
    data["law"]["entry"] = f"{law}:ConsensusPD"
    data["faults"] = {"seed": 9, "plan": [{"edge": [1, 4], "loss": 0.1}]}
    first = provenance(parse_config(data))
    assert first["plugins"]["law"] == {
        "entry": f"{law}:ConsensusPD",
        "sha256": hashlib.sha256(law.read_bytes()).hexdigest(),
    }
    assert first["seeds"]["faults"] == 9
    law.write_text(law.read_text() + "\n# edited\n")
    assert provenance(parse_config(data))["plugins"]["law"]["sha256"] != first["plugins"]["law"]["sha256"]


def test_a_kept_plug_in_is_named_by_its_copy_and_a_recorded_config_hashes_nothing(tmp_path):
    cfg = config("paper")
    kept = {
        "law": {"entry": "plugins/law.py:Law", "sha256": "ab" * 32, "kept": "plugins/law.py"},
        "faults.plan.7": {"entry": "plugins/x.py:X", "sha256": None, "kept": None},  # not a plug-in of cfg
        "vehicle": "not a record",
    }
    assert provenance(cfg, kept)["plugins"] == {"law": kept["law"]}
    recorded = parse_config(cfg.data(), recorded=True)
    assert provenance(recorded)["plugins"] == {"law": {"entry": cfg.law.entry, "sha256": None}}


def _git(root, *args):
    return subprocess.run(["git", *args], cwd=root, capture_output=True, text=True, check=True).stdout.strip()


@pytest.mark.skipif(shutil.which("git") is None, reason="needs git on PATH (a checkout's git describe)")
def test_git_describe_is_the_checkouts_commit_dirty_when_changed_and_none_outside_one(tmp_path):
    repo = tmp_path / "repo"
    repo.mkdir()
    _git(repo, "init", "-q")
    (repo / "a.py").write_text("A = 1\n")
    _git(repo, "add", "a.py")
    _git(repo, "-c", "user.name=t", "-c", "user.email=t@t", "commit", "-q", "-m", "one")
    head = _git(repo, "rev-parse", "--short", "HEAD")
    assert git_describe(repo) == head  # (no tag: the commit, abbreviated)
    (repo / "a.py").write_text("A = 2\n")
    assert git_describe(repo) == f"{head}-dirty"
    assert git_describe(tmp_path) is None  # not a checkout
    (tmp_path / "broken").mkdir()
    (tmp_path / "broken" / ".git").write_text("gitdir: nowhere\n")  # a .git git cannot read
    assert git_describe(tmp_path / "broken") is None
