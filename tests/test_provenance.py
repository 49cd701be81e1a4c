"""``summary.json``'s ``provenance``: the versions, each plug-in's hash and the seeds a run was
made with, so two runs made with different code can be told apart."""

import hashlib
import platform
from importlib import metadata

import pytest
import yaml

from swarm_sitl.config.load import parse_config
from swarm_sitl.rundir.provenance import provenance
from tests.support import CONFIGS, ROOT, config

pytestmark = pytest.mark.unit


def test_it_names_the_versions_in_use_and_the_seeds():
    cfg = config("paper")
    p = provenance(cfg)
    assert p["swarm_sitl"]["version"] == metadata.version("swarm-sitl")
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
