"""A link model written from ``docs/links.md`` alone, outside the repository: the page's files in
a temporary directory, through the page's commands (a generated swarm run under the plan that
names the model), with no edit of the package; and a link model that is not one, refused in one
line before anything runs."""

import json
import re

import pytest
import yaml

from swarm_sitl.config.load import ConfigError, parse_config
from swarm_sitl.faults.link_model import MessageOnLink
from swarm_sitl.faults.plan import FaultPlan, edge_channel, fate
from tests.support import CONFIGS, ROOT, page_command, page_files

#: its system tests run in lockstep or ``sim`` only (no wall clock): free to run beside others
pytestmark = pytest.mark.lockstep

GUIDE = ROOT / "docs" / "links.md"
COMMANDS = [
    "swarm-sitl new --followers 4 --graph layered --duration 8 -o my_swarm.yaml",
    "swarm-sitl run my_swarm.yaml --faults my_plan.yaml --out runs/link",
]


@pytest.mark.system
def test_the_guides_link_model_flies_and_delays_each_message_by_its_distance(tmp_path):
    text = GUIDE.read_text()
    files = page_files(text)
    assert set(files) == {"my_link.py", "my_plan.yaml"}
    for name, body in files.items():
        (tmp_path / name).write_text(body)
    for cmd in COMMANDS:
        assert cmd in text
        r = page_command(cmd, tmp_path)
        assert r.returncode == 0, f"{cmd}: {r.stdout}{r.stderr}"
    assert "delayed" in r.stdout
    summary = json.loads((tmp_path / "runs" / "link" / "summary.json").read_text())
    edges = {k: v for k, v in summary["links"].items() if "->" in k}
    assert edges and all(st["received"] > 0 for st in edges.values())
    for edge, st in edges.items():
        assert st["delayed"] == st["received"] == st["delivered"] - st["duplicated"] + st["held"], edge
        d, delay = st["distance_m"], st["delay_s"]
        # every delay is 0.005 + d / 200 for a distance d the edge's messages crossed
        assert (
            0.005 + d["min"] / 200 - 1e-12
            <= delay["median"]
            <= delay["max"]
            <= 0.005 + d["max"] / 200 + 1e-12
        )
    cfg = yaml.safe_load((tmp_path / "runs" / "link" / "config.yaml").read_text())
    entry = cfg["faults"]["plan"][0]["model"]["entry"]
    run_dir = tmp_path / "runs" / "link"  # the run directory keeps the model's file and names its copy
    assert entry == "plugins/my_link.py:DistanceDelay"
    assert (run_dir / "plugins" / "my_link.py").read_bytes() == (tmp_path / "my_link.py").read_bytes()


@pytest.mark.integration
def test_a_link_model_draws_only_through_its_message_and_is_the_same_every_time(tmp_path):
    """A model's fate is a pure function of the plan and the message: the same twice, and a
    seeded loss of one half within five standard deviations of half."""
    (tmp_path / "coin.py").write_text(
        "from pydantic import BaseModel, Field\n"
        "from swarm_sitl.faults.link_model import Effect\n\n"
        "class Coin:\n"
        "    class Params(BaseModel):\n"
        "        p: float = Field(gt=0, le=1)\n\n"
        "    def fate(self, params, m):\n"
        "        return Effect(lost=True) if m.uniform(7) < params.p else None\n"
    )
    plan = FaultPlan(
        seed=3,
        plan=[{"all_edges": True, "model": {"entry": f"{tmp_path}/coin.py:Coin", "params": {"p": 0.5}}}],
    )
    rules = list(enumerate(plan.plan))
    n = 4000
    lost = [fate(3, rules, edge_channel(0, 1), k, k * 0.01, 60.0, 0.01).lost for k in range(n)]
    again = [fate(3, rules, edge_channel(0, 1), k, k * 0.01, 60.0, 0.01).lost for k in range(n)]
    assert lost == again and abs(sum(lost) - n / 2) < 5 * (n / 4) ** 0.5
    m = MessageOnLink(3, 0, edge_channel(0, 1), 5, 0.05, 0.01)
    assert m.uniform(7) == MessageOnLink(3, 0, edge_channel(0, 1), 5, 0.05, 0.01).uniform(7)


@pytest.mark.integration
@pytest.mark.parametrize(
    ("model", "named"),
    [
        ({"entry": "nowhere.py:X"}, "no such file"),
        ({"entry": "LINK:Coin", "params": {"p": 2}}, "params.p: Input should be less than or equal to 1"),
        ({"entry": "LINK:Coin", "params": {}}, "params.p: Field required"),
        ({"entry": "LINK:NoParams"}, "does not meet the link-model contract: no Params (a pydantic model"),
        ({"entry": "LINK:DictParams"}, "Params must be a pydantic model"),
        ({"entry": "LINK:NoFate"}, "does not meet the link-model contract: no fate(params, message) method"),
        ({"entry": "LINK:FateNotAMethod"}, "link-model contract: no fate(params, message) method"),
        (
            {"entry": "LINK:Empty"},
            "contract: no Params (a pydantic model of its parameters), fate(params, message) method",
        ),
        ({"entry": "LINK:NOT_A_CLASS"}, "LINK:NOT_A_CLASS' is a int, not a class"),
        ({"entry": "LINK:BuildFails"}, "LINK:BuildFails': building it raised RuntimeError: no radio"),
    ],
)
def test_a_link_model_that_is_not_one_is_one_line_naming_it(tmp_path, model, named):
    link = tmp_path / "coin.py"
    link.write_text(
        "from pydantic import BaseModel, Field\n\n"
        "class Coin:\n"
        "    class Params(BaseModel):\n"
        "        p: float = Field(gt=0, le=1)\n\n"
        "    def fate(self, params, m):\n"
        "        return None\n\n"
        "class NoParams:\n"
        "    def fate(self, params, m):\n"
        "        return None\n\n"
        "class DictParams(NoParams):\n"
        "    Params = dict\n\n"
        "class NoFate:\n"
        "    Params = Coin.Params\n\n"
        "class FateNotAMethod(NoFate):\n"
        "    fate = 3\n\n"
        "class Empty:\n"
        "    pass\n\n"
        "NOT_A_CLASS = 3\n\n"
        "class BuildFails(Coin):\n"
        "    def __init__(self):\n"
        "        raise RuntimeError('no radio')\n"
    )
    model = {**model, "entry": model["entry"].replace("LINK", str(link))}
    named = named.replace("LINK", str(link))
    data = yaml.safe_load((CONFIGS / "paper.yaml").read_text())
    data["faults"] = {"plan": [{"all_edges": True, "model": model}]}
    with pytest.raises(ConfigError, match=re.escape(named)) as e:
        parse_config(data)
    assert "\n" not in str(e.value)
