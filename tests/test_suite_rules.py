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
    """The command line is ``support.CLI`` (and ``cli``, ``cli_ok``, ``start_cli``): no test spells
    its own."""
    spelled = [p.name for p in TEST_FILES if re.search(r'"-m",\s*"swarm_sitl"[,\]]', p.read_text())]
    assert not spelled, f"spell swarm-sitl's command line through tests.support.CLI: {spelled}"


def test_the_configs_are_loaded_through_the_toolbox():
    """``support.config(NAME)`` loads a config of ``configs/`` once per process."""
    direct = [p.name for p in TEST_FILES if re.search(r'load_config\(CONFIGS / "\w+\.yaml"\)', p.read_text())]
    assert not direct, f"load configs/ through tests.support.config: {direct}"
