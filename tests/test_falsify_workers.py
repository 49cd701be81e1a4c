"""``falsify``'s worker processes (``falsify/workers.py``): forked from the search where that is
safe, spawned otherwise, and either way the same process as far as a plan can tell.

The checks run in a process of their own (``python -c``): the pytest worker that runs this file
has threads of its own, and a fork of it is what ``_start_method`` refuses."""

import json
import math
import os
import signal
import subprocess
import sys
import tempfile
import textwrap
from pathlib import Path

import pytest
import yaml

import swarm_sitl.falsify.workers as workers
from tests.support import BLACKOUT_MODEL, CONFIGS, ROOT, config_data

ESTIMATE_SPEC = '- {name: estimate, formula: "always[2, end] (est_pos_err_m <= 1e-4)"}\n'

#: a search's process (its ``_Stop`` installed: the handlers a forked worker would inherit) with
#: one ``Local`` per start method flying the same plans, each worker asked its signal dispositions
PROBE = textwrap.dedent(
    """
    import json, signal, sys, threading
    import swarm_sitl.falsify.workers as w
    from swarm_sitl.falsify.search import _Stop, load_inputs

    def main():
        cfg, _space, name = load_inputs(sys.argv[1], None, sys.argv[2], None, None, 4.0, 1, "severity")
        plans = [
            {"seed": 0, "plan": []},
            {"seed": 1, "plan": [{"edge": [0, 2], "loss": 0.9}]},
            {"seed": 0, "plan": [{"edge": [0, 2], "loss": 0.9}, {"edge": [0, 3], "loss": 0.6}]},
        ]
        chosen = w._start_method
        out = {"alone": chosen()}
        stop = _Stop()
        for how in ("fork", "spawn"):
            w._start_method = lambda how=how: how
            ev = w.Local(2, cfg, name)
            try:
                robustness = ev.map(plans)
                out[how] = {
                    "robustness": robustness,
                    "method": ev.pool._mp_context.get_start_method(),
                    "signals": {
                        int(s): repr(ev.pool.submit(signal.getsignal, s).result())
                        for s in signal.valid_signals() if s not in (signal.SIGKILL, signal.SIGSTOP)
                    },
                }
            finally:
                ev.close()
        stop.close()
        w._start_method = chosen
        held = threading.Event()
        t = threading.Thread(target=held.wait)
        t.start()
        out["beside_a_thread"] = w._start_method()
        held.set()
        t.join()
        print(json.dumps(out))

    if __name__ == "__main__":
        main()
    """
)


@pytest.mark.integration
def test_a_worker_forked_or_spawned_flies_the_same_plans_and_starts_with_a_new_processs_signals(tmp_path):
    """A search of one thread forks its workers, one beside another thread spawns them; a forked
    worker, whose parent holds the search's SIGINT and SIGTERM handlers, has every signal's
    disposition a spawned one has (SIGTERM ends it, SIGINT is the search's to take), and both fly
    the same plans to the same robustness, bit for bit."""
    spec = tmp_path / "spec.yaml"
    spec.write_text(ESTIMATE_SPEC)
    r = subprocess.run(
        [sys.executable, "-c", PROBE, str(CONFIGS / "paper.yaml"), str(spec)],
        cwd=ROOT, capture_output=True, text=True, timeout=300, check=False,
    )  # fmt: skip
    assert r.returncode == 0, r.stderr
    out = json.loads(r.stdout.strip().splitlines()[-1])
    assert out["alone"] == "fork" and out["beside_a_thread"] == "spawn"
    forked, spawned = out["fork"], out["spawn"]
    assert forked["method"] == "fork" and spawned["method"] == "spawn"
    assert forked["robustness"] == spawned["robustness"]
    held, broken = forked["robustness"][0], forked["robustness"][2]
    assert held >= 0 > broken  # (the plans differ: an equality of constants would pass anything)
    assert forked["signals"] == spawned["signals"]
    assert forked["signals"][str(int(signal.SIGTERM))] == repr(signal.Handlers.SIG_DFL)
    assert forked["signals"][str(int(signal.SIGINT))] == repr(signal.Handlers.SIG_IGN)


def _shipment_inputs(tmp_path):
    """The paper's config with a plan of its own on a user's link model kept in a sub-folder
    (``models/blackout.py``) and a space searching that same model's ``dark``."""
    from swarm_sitl.falsify.search import load_inputs

    (tmp_path / "models").mkdir()
    (tmp_path / "models" / "blackout.py").write_text(BLACKOUT_MODEL)
    data = config_data("paper")
    data["faults"] = {
        "plan": [{"edge": [0, 1], "model": {"entry": "models/blackout.py:Blackout", "params": {"dark": 0.2}}}]
    }
    (tmp_path / "own.yaml").write_text(yaml.safe_dump(data))
    entry = {"entry": "models/blackout.py:Blackout", "params": {"dark": [0.0, 0.9]}}
    (tmp_path / "space.yaml").write_text(yaml.safe_dump({"entries": [{"edges": [[0, 2]], "model": entry}]}))
    (tmp_path / "spec.yaml").write_text(ESTIMATE_SPEC)
    return load_inputs(
        tmp_path / "own.yaml", tmp_path / "space.yaml", tmp_path / "spec.yaml", None, None, 3.0, 2, "severity"
    )


@pytest.mark.integration
def test_a_shipment_unpacked_where_its_files_are_not_flies_its_own_copies_as_here(tmp_path, monkeypatch):
    """A worker elsewhere (a Dask cluster's: nothing of this machine's files) unpacks the config
    and every file it names, a searched model's too, in a directory of its own, once per
    shipment, and flies a plan that names the model by this machine's path from its copy: the
    robustness is what this machine flies; the directory goes when the process ends."""
    monkeypatch.setattr(workers, "_UNPACKED", {})
    monkeypatch.setattr(workers, "_SHIPPED", {})
    cfg, sp, name = _shipment_inputs(tmp_path)
    (searched,) = sp.user_models()
    plan = {
        "seed": 3,
        "plan": [
            {"edge": [0, 2], "model": {"entry": searched, "params": {"dark": 0.5}}},
            {"edge": [1, 4], "loss": 0.2},
        ],
    }
    here = workers.fly(cfg, name, plan)
    ship = workers.Shipment.of(cfg, name, [searched])
    source = (tmp_path / "models" / "blackout.py").read_bytes()
    assert sorted(ship.files.values()) == [source] and set(ship.models) == {searched}
    (tmp_path / "models").rename(tmp_path / "gone")  # (this machine's files are not the worker's)
    registered: list[tuple] = []
    monkeypatch.setattr(workers.atexit, "register", lambda *a: registered.append(a))
    r, why = workers.fly_shipped(ship, plan)
    assert (r, why) == (here, "")
    ((remove, where, quiet),) = registered  # (one directory, for the process's end)
    assert where.name.startswith("swarm-sitl-shipment-") and Path(where).parent == Path(tempfile.gettempdir())
    copies = sorted(p for p in where.rglob("*") if p.is_file())
    assert [p.read_bytes() for p in copies if p.suffix == ".py"] == [source]
    assert yaml.safe_load((where / "config.yaml").read_text()) == yaml.safe_load(ship.config_yaml)
    moved = ship.plan_here(plan)
    assert moved["plan"][1] == plan["plan"][1] and moved["seed"] == 3
    assert moved["plan"][0]["model"] == {"entry": str(where / ship.models[searched]), "params": {"dark": 0.5}}
    assert Path(moved["plan"][0]["model"]["entry"].rpartition(":")[0]).read_bytes() == source
    assert workers.fly_shipped(ship, plan) == (here, "") and len(registered) == 1  # (unpacked once)
    assert ship.unpack(str(tmp_path / "under")).law == cfg.law and not (tmp_path / "under").exists()
    remove(where, quiet)
    remove(where, quiet)  # (gone already, at exit: quietly)
    assert not where.exists()
    other = workers.Shipment.of(cfg, name)  # (another shipment: no searched model)
    assert other.plan_here(plan) is plan and other.digest != ship.digest


@pytest.mark.integration
def test_a_shipment_unpacked_under_a_directory_lands_there_once_and_a_plan_that_cannot_fly_is_said(
    tmp_path, monkeypatch
):
    """``unpack(under)``: the copies land in one directory under it named after the process and
    the shipment; a plan a worker cannot fly comes back as its reason (``Dask worker pid N: ...``),
    and a cluster whose task failed is one ``WorkerError`` naming what failed."""
    monkeypatch.setattr(workers, "_UNPACKED", {})
    monkeypatch.setattr(workers, "_SHIPPED", {})
    cfg, sp, name = _shipment_inputs(tmp_path)
    ship = workers.Shipment.of(cfg, name, sp.user_models())
    under = tmp_path / "under"
    unpacked = ship.unpack(str(under))
    (where,) = list(under.iterdir())
    assert where.name == f"shipment-{os.getpid()}-{ship.digest[:16]}"
    assert unpacked.faults.plan[0].model.entry == f"{where / 'plugins' / 'blackout.py'}:Blackout"
    assert ship.unpack(str(under)) == unpacked and list(under.iterdir()) == [where]
    bare = workers.Shipment.of(cfg.model_copy(update={"faults": type(cfg.faults)()}), name)  # (no file)
    assert not bare.files and bare.unpack(str(tmp_path / "a" / "b")).faults.plan == []
    bad = {"seed": 0, "plan": [{"edge": [0, 2], "model": {"entry": "nowhere.py:Nothing", "params": {}}}]}
    r, why = workers.fly_shipped(ship, bad)
    assert r is None and why.startswith(f"Dask worker pid {os.getpid()}: ") and "nowhere.py" in why

    class Failing:
        def submit(self, fn, *args, **kw):
            return None

        def gather(self, futures):
            raise RuntimeError("worker tcp://10.0.0.9 lost")

        def close(self):
            pass

    import swarm_sitl.campaigns.runner as runner

    monkeypatch.setattr(runner, "connect", lambda address: Failing())
    ev = workers.Dask("tcp://x:1", cfg, name, sp.user_models())
    assert ev.ship == ship  # (the searched model's file shipped with the config)
    with pytest.raises(
        workers.WorkerError, match=r"^a Dask worker failed: RuntimeError: worker tcp://10\.0\.0\.9 lost$"
    ):
        ev.map([{"seed": 0, "plan": []}])

    class Answering(Failing):  # (a task that ran and could not fly its plan)
        def gather(self, futures):
            return [(0.5, ""), (None, "Dask worker pid 7: the reason")]

    monkeypatch.setattr(runner, "connect", lambda address: Answering())
    plans = [{"seed": 0, "plan": []}, {"seed": 1, "plan": []}]
    with pytest.raises(
        workers.WorkerError, match=r'^plan \{"plan": \[\], "seed": 1\}: Dask worker pid 7: the reason$'
    ):
        workers.Dask("tcp://x:1", cfg, name).map(plans)


@pytest.mark.integration
def test_a_plan_that_leaves_nothing_to_judge_is_a_violation_and_a_vacuous_hold_is_capped(tmp_path):
    """A follower's controller killed for good leaves the requirement nothing after it: robustness
    ``-inf``, which the study takes as ``NO_ROBUSTNESS``; one that holds it over an empty window
    (``+inf``) is capped at ``-NO_ROBUSTNESS``; any other is the requirement's own."""
    from swarm_sitl.falsify.evaluate import evaluate
    from swarm_sitl.falsify.search import load_inputs

    killed = {"seed": 0, "plan": [{"controller": 1, "kill": True, "from_s": 0.5}]}
    got = {}
    for formula in ("always[1, end] (pos_err_m <= 1)", "always[1.991, 1.999] (pos_err_m <= 1)"):
        (tmp_path / "spec.yaml").write_text(f'- {{name: r, formula: "{formula}"}}\n')
        cfg, _sp, name = load_inputs(
            CONFIGS / "paper.yaml", None, tmp_path / "spec.yaml", None, None, 2.0, 1, "severity"
        )
        for plan in (killed, {"seed": 0, "plan": []}):
            got[formula, bool(plan["plan"])] = (evaluate(cfg, name, plan), workers.fly(cfg, name, plan))
    assert got["always[1, end] (pos_err_m <= 1)", True] == (-math.inf, workers.NO_ROBUSTNESS)
    plain = got["always[1, end] (pos_err_m <= 1)", False]
    assert math.isfinite(plain[0]) and plain[0] == plain[1]
    assert got["always[1.991, 1.999] (pos_err_m <= 1)", False] == (math.inf, -workers.NO_ROBUSTNESS)


@pytest.mark.unit
def test_a_plan_is_told_in_one_line_of_at_most_300_characters():
    """``shown``: the plan's JSON, keys sorted; a longer one cut to 297 characters and ``...``."""
    short = {"seed": 1, "plan": [{"edge": [0, 1], "loss": 0.5}]}
    assert workers.shown(short) == json.dumps(short, sort_keys=True)
    for size in (299, 300, 301, 302, 2000):  # (the plan's text this long, around the cut)
        bare = json.dumps({"plan": [{"note": ""}], "seed": 2}, sort_keys=True)
        long = {"seed": 2, "plan": [{"note": "x" * (size - len(bare))}]}
        text, full = workers.shown(long), json.dumps(long, sort_keys=True)
        assert len(full) == size and "\n" not in text
        assert text == (full if size <= 300 else full[:297] + "...") and len(text) == min(size, 300)
