import os

# MAVLink 2 for every pymavlink the tests import, whichever module imports it first: pymavlink picks
# its wire protocol once, at its import, from this variable (signing and the vehicles' messages
# need 2). A test of a client without it removes it from that client's environment.
os.environ.setdefault("MAVLINK20", "1")

import pytest
from hypothesis import Phase, settings

from tests import support, workers

# kernels are compiled (or loaded from cache) on first call: no per-example deadline
# under mutation testing (mutmut sets MUTANT_UNDER_TEST) a failing example is the verdict: it is
# not shrunk nor explained, which would cost minutes per killed mutant with kernels run as Python
_MUTATION = bool(os.environ.get("MUTANT_UNDER_TEST"))
PHASES = tuple(p for p in Phase if not (_MUTATION and p in (Phase.shrink, Phase.explain)))
settings.register_profile("swarm", deadline=None, max_examples=100, phases=PHASES)
settings.load_profile("swarm")

#: every test is one of these (``pyproject.toml`` says what each means; ``-m`` selects them)
LAYERS = ("unit", "integration", "system")


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """Tests that are not marked with exactly one layer fail the collection, each named."""
    bad = []
    for item in items:
        layers = sorted(m.name for m in item.iter_markers() if m.name in LAYERS)
        if len(layers) != 1:
            bad.append(f"{item.nodeid}: {layers or 'none'}")
    if bad:
        raise pytest.UsageError(f"mark each test with one of {', '.join(LAYERS)}:\n" + "\n".join(bad))
    # with pytest-xdist's --dist loadgroup: each system test that flies in real time is a group of
    # its own, numbered in the order collected, which only the real-time workers take
    # (``tests/workers.py``). The group is a suffix of the node id (what xdist's own hook makes of an
    # xdist_group mark, which may run before this one; pytest 9 no longer reads it, so
    # pyproject.toml keeps pytest 8). A system test marked ``lockstep`` (it runs in lockstep or
    # ``sim`` only: CPU, no wall clock) or ``light`` (one vehicle for a client that mostly waits)
    # goes to any worker; a unit or integration test marked
    # ``realtime`` (an in-process loop timed to the millisecond) to a real-time worker.
    grouped = bool(config.getvalue("loadgroup")) if hasattr(config.option, "loadgroup") else False
    realtime = [item for item in items if _realtime(item)]
    for k, item in enumerate([item for item in realtime if "@" not in item.nodeid] if grouped else []):
        item._nodeid = f"{item.nodeid}@{workers.REALTIME_GROUP}-{k:04d}"


def _realtime(item: pytest.Item) -> bool:
    """A test that keeps time on the wall clock: a system test marked neither ``lockstep`` nor
    ``light``, or one marked ``realtime``."""
    beside = item.get_closest_marker("lockstep") or item.get_closest_marker("light")
    system = item.get_closest_marker("system") is not None and beside is None
    return system or item.get_closest_marker("realtime") is not None


def pytest_runtest_setup(item: pytest.Item) -> None:
    workers.before_test(_realtime(item))


@pytest.hookimpl(tryfirst=True)
def pytest_xdist_auto_num_workers(config: pytest.Config) -> int:
    return workers.worker_count()


def pytest_xdist_make_scheduler(config: pytest.Config, log):  # type: ignore[no-untyped-def]
    return workers.RealtimeOnTheirWorkers(config, log)


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
    from swarm_sitl.running.first_compile import compile_once

    compile_once(support.config("paper"), lambda line: None)


@pytest.fixture(scope="session")
def paper_cfg():
    return support.config("paper")


@pytest.fixture(scope="session")
def ring_cfg():
    return support.config("ring")
