"""The test suite's own rules: one toolbox (``tests/support.py``, ``tests/fakes.py``), no test
module reaching into another, and which system tests may run beside others said by a marker on
the test, not by a list of file names."""

import ast
import re

import pytest

from tests.support import ROOT

pytestmark = pytest.mark.unit

TEST_FILES = sorted([*(ROOT / "tests").glob("test_*.py"), *(ROOT / "examples").rglob("test_*.py")])


def test_no_test_module_imports_another():
    found = []
    for path in TEST_FILES:
        for node in ast.walk(ast.parse(path.read_text())):
            names = []
            if isinstance(node, ast.ImportFrom) and node.module:
                names = [node.module] + [f"{node.module}.{a.name}" for a in node.names]
            elif isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            found += [f"{path.name}: {n}" for n in names if re.match(r"(tests|examples)\.test_", n)]
    assert not found, f"test modules importing test modules (share through tests/support.py): {found}"


def test_swarm_sitl_is_run_one_way():
    """``swarm-sitl`` is run through ``support.cli``, ``cli_ok`` and ``start_cli``, a vehicle through
    ``vehicle``, ``start_vehicle`` and ``spawn_vehicle`` (forked from a warm interpreter,
    ``tests/cli_host.py``): no test spells their command lines (``"-m", "swarm_sitl"``, ``"-m",
    "sim_vehicles"``, ``module_argv("swarm_sitl")``, ``[*CLI, ...]``) to start them some other
    way, nor the command line a campaign forks its runs by (``warm_commands.CLI``). One may in a
    network namespace (``ip netns exec``), where the host cannot fork it; the supervisor's own
    tests give it ``module_argv("sim_vehicles")``: it starts what it is given; and
    ``warm_commands``' own tests compare what it forks with a new interpreter's command."""
    forms = (
        r'"-m",\s*"(swarm_sitl|sim_vehicles)"[,\]]|\*CLI\b|(?<!"exec", ns, \*)module_argv\("swarm_sitl"\)'
        r"|warm_commands\.CLI\b"
    )
    own = ("test_suite_rules.py", "test_warm_commands.py")  # (this rule names the forms; the fork's own)
    others = [p for p in TEST_FILES if p.name not in own]
    spelled = [f"{p.name}: {m.group(0)}" for p in others for m in re.finditer(forms, p.read_text())]
    assert not spelled, f"run swarm-sitl through tests.support.cli, cli_ok or start_cli: {spelled}"


def test_the_configs_are_loaded_through_the_toolbox():
    """``support.config(NAME)`` loads a config of ``configs/`` once per process."""
    direct = [p.name for p in TEST_FILES if re.search(r'load_config\(CONFIGS / "\w+\.yaml"\)', p.read_text())]
    assert not direct, f"load configs/ through tests.support.config: {direct}"
