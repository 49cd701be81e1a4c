"""The suite's own scheduling (``tests/workers.py``): a real-time system test runs only on a
real-time worker, in the order collected, one at a time per worker; every other test goes to any
worker; every test runs once; and only the other workers lower their priority. Driven as
pytest-xdist drives a scheduler, with workers that finish their tests in a random order."""

import random
from types import SimpleNamespace

import pytest

from tests import workers

pytestmark = pytest.mark.unit


class FakeNode:
    """A worker as the scheduler sees it (``WorkerController``): its id, its tests, shutdown."""

    def __init__(self, gid: str):
        self.gateway = SimpleNamespace(id=gid)
        self.sent: list[int] = []
        self.shutting_down = False

    def send_runtest_some(self, indices):
        self.sent.extend(indices)

    def send_runtest_all(self):
        raise AssertionError("a scope scheduler sends test by test")

    def shutdown(self):
        self.shutting_down = True


def _session(
    n_workers: int, collection: list[str], rng: random.Random
) -> tuple[dict[str, list[str]], list[str]]:
    """Run a session to its end: every worker, in a random order, finishes its oldest test. Returns
    what each ran and the workers kept (xdist shuts down those beyond the number of groups)."""
    config = SimpleNamespace(
        getvalue=lambda name: [f"{n_workers}*popen"], option=SimpleNamespace(loadscopereorder=True)
    )
    sched = workers.RealtimeOnTheirWorkers(config)  # type: ignore[arg-type]
    nodes = [FakeNode(f"gw{i}") for i in range(n_workers)]
    rng.shuffle(nodes)  # workers come up in any order
    for node in nodes:
        sched.add_node(node)
    for node in nodes:
        sched.add_node_collection(node, collection)
    sched.schedule()
    kept = [n.gateway.id for n in sched.nodes]
    ran: dict[str, list[str]] = {n.gateway.id: [] for n in nodes}
    done = {n.gateway.id: 0 for n in nodes}
    while busy := [n for n in nodes if done[n.gateway.id] < len(n.sent)]:
        node = rng.choice(busy)
        index = node.sent[done[node.gateway.id]]
        done[node.gateway.id] += 1
        ran[node.gateway.id].append(collection[index])
        sched.mark_test_complete(node, index)
    assert sched.tests_finished and not sched.workqueue, "work is left and no worker has any"
    return ran, kept


@pytest.mark.parametrize("n_workers", [1, 2, 3, 4, 6])
def test_real_time_tests_run_once_each_on_a_real_time_worker_in_their_order(n_workers):
    rng = random.Random(n_workers)
    for _ in range(20):
        collection = []
        for k in range(rng.randrange(0, 30)):
            collection.append(f"tests/test_a.py::test_{k}")
            if rng.random() < 0.4:
                collection.append(f"tests/test_b.py::test_{k}@{workers.REALTIME_GROUP}-{len(collection):04d}")
        if not collection:
            continue
        ran, kept = _session(n_workers, collection, rng)
        assert sorted(t for ts in ran.values() for t in ts) == sorted(collection)  # each once
        realtime_ids = [w for w in kept if w in workers.REALTIME_WORKERS] or kept
        for worker, tests in ran.items():
            rt = [t for t in tests if "@" in t]
            assert worker in realtime_ids or not rt, (worker, rt)
            assert rt == sorted(rt, key=lambda t: t.rsplit("-", 1)[1])  # in the order collected


def _as_worker(monkeypatch, worker: str | None) -> list[int]:
    """This process as xdist worker ``worker`` (None: no xdist), never niced yet; the ``nice``
    calls it then makes, recorded instead of made."""
    calls: list[int] = []
    monkeypatch.setattr(workers.os, "nice", calls.append)
    monkeypatch.setattr(workers, "_NICED", [])
    if worker is None:
        monkeypatch.delenv("PYTEST_XDIST_WORKER", raising=False)
    else:
        monkeypatch.setenv("PYTEST_XDIST_WORKER", worker)
    return calls


@pytest.mark.parametrize(
    ("worker", "tests", "nices"),
    [
        ("gw0", [True, True, False, False], 1),  # its real-time tests, then the others': once
        ("gw0", [True, True], 0),
        ("gw2", [False, False], 1),  # at its first test
        ("gw2", [True, False], 1),  # real-time tests on it (gw0 shut down): the normal priority for them
        (None, [True, False], 0),  # -n 0: one process, nothing niced
    ],
)
def test_a_worker_gives_way_once_at_its_first_test_that_is_not_real_time(monkeypatch, worker, tests, nices):
    calls = _as_worker(monkeypatch, worker)
    for k, realtime in enumerate(tests):
        workers.before_test(realtime)
        assert calls == [workers.OTHERS_NICE] * (nices if not all(tests[: k + 1]) else 0)
    assert calls == [workers.OTHERS_NICE] * nices
