"""``falsify``'s worker processes (``falsify/workers.py``): forked from the search where that is
safe, spawned otherwise, and either way the same process as far as a plan can tell.

The checks run in a process of their own (``python -c``): the pytest worker that runs this file
has threads of its own, and a fork of it is what ``_start_method`` refuses."""

import json
import signal
import subprocess
import sys
import textwrap

import pytest

from tests.support import CONFIGS, ROOT

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
