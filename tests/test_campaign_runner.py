"""Where a campaign's runs go on this machine (``campaigns.runner``): every task run once with its
own inputs and its row given back with it, never more runs at once than ``jobs``, and a campaign
that stops (Ctrl-C, a point that raised) stopping the runs under way and starting no other;
``connect``'s refusals in one line. (``run_point`` is stood in for: its own tests are
``test_campaign_point.py``; a cluster's runs, ``test_sweep_plugins.py``.)"""

import os
import signal
import threading
import time

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import swarm_sitl.campaigns.runner as runner
from swarm_sitl.campaigns.runner import SchedulerError, Task, connect, default_jobs, run_local

pytestmark = pytest.mark.unit


class _Points:
    """``run_point`` stood in for: each call noted (its inputs, how many ran at once), a row
    naming its inputs back after ``sleep_s``; a name in ``fail`` raises ``fail[name]``."""

    def __init__(self, sleep_s: float = 0.0, fail: dict[str, BaseException] | None = None, together: int = 1):
        self.sleep_s, self.fail, self.together = sleep_s, fail or {}, together
        self.calls: list[tuple] = []
        self.now = self.most = 0
        self.stopped = 0
        self._lock = threading.Condition()

    def __call__(self, config_yaml, name, keep_dir, plugins, timeout_s):
        with self._lock:
            self.calls.append((config_yaml, name, keep_dir, plugins, timeout_s))
            self.now += 1
            self.most = max(self.most, self.now)
            self._lock.notify_all()
            # the first runs wait (a while) for ``together`` of them to be under way at once
            self._lock.wait_for(lambda: self.most >= self.together, timeout=10.0)
        try:
            time.sleep(self.sleep_s)
            if name in self.fail:
                raise self.fail[name]
            return {
                "name": name,
                "config": config_yaml,
                "keep": keep_dir,
                "plugins": plugins,
                "timeout": timeout_s,
            }
        finally:
            with self._lock:
                self.now -= 1

    def stop(self) -> None:
        self.stopped += 1


def _tasks(n: int) -> list[Task]:
    return [
        Task(key=(i, i % 3), name=f"p{i}", config_yaml=f"name: p{i}\n", keep_dir=f"/k/{i}" if i % 2 else None,
             plugins={f"plugins/l{i}.py": bytes([i])} if i % 3 else None, timeout_s=float(i) or None)
        for i in range(n)
    ]  # fmt: skip


@settings(max_examples=20, deadline=None)
@given(n=st.integers(0, 12), jobs=st.integers(1, 5))
def test_every_task_runs_once_with_its_own_inputs_and_never_more_than_jobs_at_once(n, jobs):
    points = _Points(sleep_s=0.002, together=min(n, jobs))
    tasks = _tasks(n)
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(runner, "run_point", points)
        done = list(run_local(tasks, jobs))
    assert sorted(t.name for t, _ in done) == sorted(t.name for t in tasks) and len(points.calls) == n
    for t, row in done:
        assert row == {"name": t.name, "config": t.config_yaml, "keep": t.keep_dir, "plugins": t.plugins,
                       "timeout": t.timeout_s}  # fmt: skip
    assert points.most == min(n, jobs)  # (as many at once as it may: each waits for the others)


@pytest.mark.parametrize("stop", [KeyboardInterrupt(), RuntimeError("a point broke")])
def test_a_campaign_that_stops_stops_the_runs_under_way_and_starts_no_other(monkeypatch, stop):
    """Point p1 raises (Ctrl-C in its run, or an error): the campaign raises it, the runs under
    way are told to stop once, and of twelve tasks run two at a time no more than the first few
    ever start."""
    points = _Points(sleep_s=0.05, fail={"p1": stop})
    monkeypatch.setattr(runner, "run_point", points)
    monkeypatch.setattr(runner, "stop_running", points.stop)
    with pytest.raises(type(stop)):
        for _ in run_local(_tasks(12), 2):
            pass
    assert points.stopped == 1 and 2 <= len(points.calls) <= 4, points.calls


def test_a_campaign_left_by_its_reader_waits_for_the_runs_it_started():
    """The reader stops reading (a ``break``): the runs under way finish, no other starts."""
    points = _Points(sleep_s=0.05)
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(runner, "run_point", points)
        rows = run_local(_tasks(10), 2)
        next(rows)
        rows.close()
    assert points.now == 0 and len(points.calls) <= 4


def test_the_default_is_one_run_per_core_this_process_may_use():
    assert default_jobs() == len(os.sched_getaffinity(0)) >= 1


@pytest.mark.parametrize(
    ("address", "says"),
    [
        ("tcp://127.0.0.1:1", "cannot reach the Dask scheduler at tcp://127.0.0.1:1"),
        ("nonsense://x", "nonsense://x"),
    ],
)
def test_a_scheduler_that_cannot_be_used_is_one_line_naming_it(address, says):
    pytest.importorskip("distributed", reason="Dask's scheduler is the cluster extra")
    with pytest.raises(SchedulerError, match=says) as e:
        connect(address, timeout_s=0.5)
    assert "\n" not in str(e.value)


def test_where_the_cores_usable_cannot_be_asked_the_default_is_the_cores_and_at_least_one(monkeypatch):
    """(macOS has no ``sched_getaffinity``.) The machine's cores; one where even they are unknown."""
    import types

    for cores, jobs in ((6, 6), (None, 1)):
        monkeypatch.setattr(runner, "os", types.SimpleNamespace(cpu_count=lambda cores=cores: cores))
        assert default_jobs() == jobs
    monkeypatch.setattr(
        runner, "os", types.SimpleNamespace(sched_getaffinity=lambda pid: set(), cpu_count=lambda: 8)
    )
    assert default_jobs() == 1


def test_ctrl_c_ends_at_once_runs_that_end_only_when_told_and_no_other_starts(monkeypatch):
    """Each run under way ends only when the campaign tells it to (as ``swarm-sitl run`` on its
    interrupt); the reader's Ctrl-C tells the runs under way, and the campaign returns without
    waiting for them first, nor starting one that nothing would tell."""
    told = threading.Event()
    started: list[str] = []
    under_way: set[str] = set()
    lock = threading.Lock()
    stops: dict[str, threading.Event] = {}

    threads: set[str] = set()

    def point(config_yaml, name, keep_dir, plugins, timeout_s):
        with lock:
            started.append(name)
            threads.add(threading.current_thread().name)
            stops[name] = threading.Event()
            under_way.add(name)
        stops[name].wait(20)  # (a run no one stops: the test would wait 20 s and fail)
        with lock:
            under_way.discard(name)
        return {"name": name}

    def stop():
        with lock:  # the runs under way now, as point.RUNNING holds them
            for n in under_way:
                stops[n].set()
        time.sleep(0.3)  # (telling takes a while: a task still pending would start meanwhile)
        told.set()

    monkeypatch.setattr(runner, "run_point", point)
    monkeypatch.setattr(runner, "stop_running", stop)

    def ctrl_c_once_two_run() -> None:  # (Ctrl-C reaches the campaign's main thread)
        end = time.monotonic() + 30
        while time.monotonic() < end:
            with lock:
                if len(under_way) == 2:
                    break
            time.sleep(0.01)
        os.kill(os.getpid(), signal.SIGINT)

    t0 = time.monotonic()
    threading.Thread(target=ctrl_c_once_two_run, daemon=True).start()
    before = signal.signal(signal.SIGINT, signal.default_int_handler)  # (Python's, whatever runs the tests)
    try:
        with pytest.raises(KeyboardInterrupt):
            for _ in run_local(_tasks(6), 2):
                pass
    finally:
        signal.signal(signal.SIGINT, before)
    assert told.is_set() and time.monotonic() - t0 < 20  # (not the 20 s a run no one told waits)
    assert sorted(started) == ["p0", "p1"] and all(stops[n].is_set() for n in started)
    assert all(t.startswith("sweep") for t in threads), threads  # (named in a stack dump)


def test_an_address_that_accepts_and_never_answers_is_one_line_within_the_timeout():
    """Another service's port: Dask's own client would wait for ever."""
    pytest.importorskip("distributed", reason="Dask's scheduler is the cluster extra")
    import socket

    with socket.socket() as silent:
        silent.bind(("127.0.0.1", 0))
        silent.listen(4)
        address = f"tcp://127.0.0.1:{silent.getsockname()[1]}"
        t0 = time.monotonic()
        with pytest.raises(SchedulerError) as e:
            connect(address, timeout_s=0.5)
    assert str(e.value) == f"cannot reach the Dask scheduler at {address} (no answer within 0.5 s)"
    assert time.monotonic() - t0 < 0.5 + 5.0  # (the handshake's cancellation, on a loaded machine)


def test_a_scheduler_reached_gives_a_client_that_is_not_the_callers_default(monkeypatch):
    """The campaign's client is its own: a user's code that asks Dask for its default client
    still gets its own (or none), not the campaign's."""
    distributed = pytest.importorskip("distributed", reason="Dask's scheduler is the cluster extra")
    with distributed.LocalCluster(n_workers=0, processes=False, dashboard_address=None) as cluster:
        client = connect(cluster.scheduler_address, timeout_s=5.0)
        try:
            assert client.scheduler.address == cluster.scheduler_address
            with pytest.raises(ValueError, match="No clients found"):
                distributed.default_client()
        finally:
            client.close()


def test_without_dask_installed_a_scheduler_is_one_line_saying_what_to_install(monkeypatch):
    import sys

    monkeypatch.setitem(sys.modules, "distributed", None)  # (import distributed: ImportError)
    with pytest.raises(SchedulerError) as e:
        connect("tcp://127.0.0.1:8786")
    assert str(e.value) == "--scheduler needs Dask's distributed scheduler: pip install 'swarm-sitl[cluster]'"
