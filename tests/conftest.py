import os
import re
import subprocess
import sys
from pathlib import Path

import pytest
from hypothesis import settings

# kernels are compiled (or loaded from cache) on first call: no per-example deadline
settings.register_profile("swarm", deadline=None, max_examples=100)
settings.load_profile("swarm")

ROOT = Path(__file__).resolve().parents[1]


def page_files(text: str) -> dict[str, str]:
    """The files a guide in ``docs/`` gives: each ``<!-- file: NAME -->`` and the Python or YAML
    block after it."""
    return dict(re.findall(r"<!-- file: (\S+) -->\n```(?:python|yaml)\n(.*?)```", text, re.S))


def page_command(cmd: str, cwd: Path) -> "subprocess.CompletedProcess[str]":
    """A guide's ``swarm-sitl ...`` command line, run in ``cwd`` with this interpreter."""
    argv = [sys.executable, "-m", "swarm_sitl", *cmd.split()[1:]]
    return subprocess.run(argv, cwd=cwd, capture_output=True, text=True, timeout=300)


CONFIGS = ROOT / "configs"


def processes_mentioning(text: str) -> list[int]:
    """Live processes whose command line contains ``text`` (a run directory): what a run left."""
    found = []
    for d in Path("/proc").iterdir():
        if not d.name.isdigit():
            continue
        try:
            cmd = (d / "cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
            state = (d / "stat").read_text().rsplit(")", 1)[1].split()[0]
        except OSError:
            continue
        if text in cmd and state != "Z":
            found.append(int(d.name))
    return found


#: every test is one of these (``pyproject.toml`` says what each means; ``-m`` selects them)
LAYERS = ("unit", "integration", "system")
#: system-test files that run in lockstep or ``sim`` only: nothing in them reads the wall clock
LOCKSTEP_ONLY = {
    "test_law_from_docs.py",
    "test_sweep.py",
    "test_wind.py",
    "test_sensors.py",
    "test_link_models.py",
    "test_radio_models.py",
    "test_fault_tolerance.py",
    "test_consensus_pd.py",
    "test_full_disk.py",
    "test_law_contract.py",
    "test_misbehaving_laws.py",
    "test_self_contained_runs.py",
    "test_sweep_plugins.py",
    "test_leader_restart.py",
    "test_sim_faults.py",
    "test_falsify.py",
    "test_counts_across_restarts.py",
    "test_quad_swarm.py",
    "test_vehicle_from_docs.py",
    "test_link_from_docs.py",
    "test_view_foxglove.py",
    "test_zenoh_attacks.py",
    "test_arducopter_swarm.py",
}


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """Tests that are not marked with exactly one layer fail the collection, each named."""
    bad = []
    for item in items:
        layers = sorted(m.name for m in item.iter_markers() if m.name in LAYERS)
        if len(layers) != 1:
            bad.append(f"{item.nodeid}: {layers or 'none'}")
    if bad:
        raise pytest.UsageError(f"mark each test with one of {', '.join(LAYERS)}:\n" + "\n".join(bad))
    # with pytest-xdist's --dist loadgroup: the system tests on one worker, in their order. The
    # group is a suffix of the node id (what xdist's own hook makes of an xdist_group mark, which
    # may run before this one; pytest 9 no longer reads it, so pyproject.toml keeps pytest 8).
    # The lockstep-only system tests (CPU, no wall clock) are left free to go to either worker.
    grouped = bool(config.getvalue("loadgroup")) if hasattr(config.option, "loadgroup") else False
    for item in items:
        free = Path(str(item.fspath)).name in LOCKSTEP_ONLY
        if grouped and item.get_closest_marker("system") is not None and not free and "@" not in item.nodeid:
            item._nodeid = f"{item.nodeid}@system"


_COMPILED: list[bool] = []


@pytest.fixture(autouse=True)
def compiled_kernels(request: pytest.FixtureRequest) -> None:
    """Before the first test of a process that starts processes (a system test): every kernel a
    vehicle and a node run compiled into numba's disk cache, once, here. On a fresh machine (CI)
    the first swarm's processes would otherwise each compile them at once (two namespaces' worth
    in the two-host test, over a minute on two cores), inside the test's time limits."""
    if _COMPILED or request.node.get_closest_marker("system") is None:
        return
    _COMPILED.append(True)
    if os.environ.get("NUMBA_DISABLE_JIT") == "1":
        return
    # the wire's kernels in a second process while this one compiles the laws': two cores, as a
    # first sim or run on a fresh install does (``running.first_compile``)
    from swarm_sitl.config.load import load_config
    from swarm_sitl.running.first_compile import compile_once

    compile_once(load_config(CONFIGS / "paper.yaml"), lambda line: None)


@pytest.fixture(scope="session")
def paper_cfg():
    from swarm_sitl.config.load import load_config

    return load_config(CONFIGS / "paper.yaml")


@pytest.fixture(scope="session")
def ring_cfg():
    from swarm_sitl.config.load import load_config

    return load_config(CONFIGS / "ring.yaml")
