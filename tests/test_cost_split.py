"""The bench's split of a process's CPU by activity, on profiles of code whose costs are known."""

import cProfile
import importlib.util
import os
import threading
import time

import pytest

from sim_vehicles.runtime.lifeline import thread_cpu_s
from swarm_sitl.bench.cost_split import ACTIVITIES, activity_of, activity_split

_BURN = """
import time

def burn(seconds):
    end = time.thread_time() + seconds
    while time.thread_time() < end:
        pass

def burn_in_a_builtin(n):
    return sorted(range(n, 0, -1))  # the builtin's time belongs to this caller
"""


def _module(tmp_path, package: str, name: str):
    folder = tmp_path / package
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / f"{name}.py"
    path.write_text(_BURN)
    spec = importlib.util.spec_from_file_location(f"{package.replace('/', '_')}_{name}", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


@pytest.mark.unit
def test_time_goes_to_the_activity_of_the_file_and_builtins_to_their_caller(tmp_path):
    laws = _module(tmp_path, "sim_vehicles/plant", "autopilot")  # physics and laws
    bus = _module(tmp_path, "swarm_sitl/bus", "node_bus")  # zenoh
    link = _module(tmp_path, "swarm_sitl/link", "decoding")  # MAVLink

    def body():
        laws.burn(0.06)
        bus.burn(0.02)
        for _ in range(3):
            link.burn_in_a_builtin(200_000)
        time.sleep(0.05)  # waking up: next to no CPU

    prof = cProfile.Profile(time.thread_time_ns, 1e-9)
    prof.runcall(body)
    path = tmp_path / "p.prof"
    prof.dump_stats(path)
    s = activity_split([path])
    assert set(s) == set(ACTIVITIES)
    assert s["physics and laws"] == pytest.approx(0.06, rel=0.2)
    assert s["zenoh"] == pytest.approx(0.02, rel=0.3)
    assert s["MAVLink"] > 0.005  # the sorting, in the caller's activity
    assert s["physics and laws"] / s["zenoh"] == pytest.approx(3.0, rel=0.3)
    assert s["waking up"] < 0.005 and s["logs"] == 0.0


@pytest.mark.unit
def test_builtins_are_named_by_what_they_do():
    assert activity_of(("~", 0, "<built-in method select.select>")) == "waking up"
    assert activity_of(("~", 0, "<method 'put' of 'builtins.Publisher' objects>")) == "zenoh"
    assert activity_of(("~", 0, "<built-in method builtins.len>")) is None  # its caller's
    assert activity_of(("/x/sim_vehicles/vehicle/endpoint.py", 1, "run_lockstep")) == "loop and other"
    assert activity_of(("/x/sim_vehicles/vehicle/endpoint.py", 1, "_send_attitude")) == "MAVLink"
    assert activity_of(("/x/sim_vehicles/runtime/row_log.py", 1, "append")) == "logs"
    assert activity_of(("/x/sim_vehicles/runtime/udp_arrival.py", 56, "__call__")) is None  # link's or bus's
    assert activity_of(("~", 0, "<method 'poll' of 'select.poll' objects>")) is None  # poll(0): a look


@pytest.mark.unit
@pytest.mark.skipif(not os.path.isdir("/proc/self/task"), reason="per-thread CPU is read from Linux /proc")
def test_thread_cpu_tells_the_main_thread_from_the_others():
    def burn(seconds: float) -> None:
        end = time.thread_time() + seconds
        while time.thread_time() < end:
            pass

    main0, others0 = thread_cpu_s()
    ended = threading.Thread(target=burn, args=(0.1,))
    ended.start()
    ended.join()  # a thread that has ended is no longer counted
    burnt, done = threading.Event(), threading.Event()
    waiting = threading.Thread(target=lambda: (burn(0.15), burnt.set(), done.wait()))
    waiting.start()
    burn(0.1)
    # the other thread has burnt its 0.15 s and waits (however long a loaded machine took)
    assert burnt.wait(30)
    main1, others1 = thread_cpu_s()
    done.set()
    waiting.join()
    assert main1 - main0 == pytest.approx(0.1, abs=0.05)
    assert others1 - others0 == pytest.approx(0.15, abs=0.05)
