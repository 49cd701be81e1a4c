"""The tests' ``swarm-sitl``, forked from a warm interpreter (``tests/cli_host.py``), is the process
a new interpreter would be: what a command can see of its process, its exit and its streams are
the same both ways."""

import json
import os
import signal
import subprocess

import pytest
import yaml

from tests.support import CONFIGS, cli, start_cli

pytestmark = [pytest.mark.system, pytest.mark.lockstep]

#: a law's module that writes what its process looks like, then refuses to load
PROBE = """
import json, os, random, signal, sys, tempfile
import numpy as np
SIGNALS = ("SIGINT", "SIGTERM", "SIGHUP", "SIGPIPE", "SIGCHLD", "SIGUSR1")
seen = {
    "signals": {s: getattr(h := signal.getsignal(getattr(signal, s)), "__qualname__", str(h))
                for s in SIGNALS},
    "cwd": os.getcwd(),
    "path0": sys.path[0],
    "argv": sys.argv[1:],
    "own_session": os.getsid(0) == os.getpid(),
    "nice": os.nice(0),
    "tmp": tempfile.gettempdir(),
    "mine": os.environ.get("SWARM_SITL_PROBE"),
    "stdin_tty_or_null": os.path.realpath("/proc/self/fd/0"),
    "random": [random.random(), float(np.random.random())],
    "title": open("/proc/self/cmdline", "rb").read().replace(b"\\0", b" ").decode().strip(),
    "parent_python": os.path.realpath(f"/proc/{os.getppid()}/exe") == os.path.realpath(sys.executable),
}
with open(os.environ["SWARM_SITL_PROBE"], "a") as f:
    f.write(json.dumps(seen) + "\\n")
print("probe: to stdout")
print("probe: to stderr", file=sys.stderr)
raise ImportError("the probe refuses to load")
"""


def _config(folder):
    data = yaml.safe_load((CONFIGS / "paper.yaml").read_text())
    data["law"] = {"entry": "probe.py:Law"}
    (folder / "probe.py").write_text(PROBE)
    (folder / "swarm.yaml").write_text(yaml.safe_dump(data))
    return folder / "swarm.yaml"


def test_a_forked_command_sees_the_process_a_new_interpreter_would_be(tmp_path):
    """cwd, ``sys.path[0]``, ``sys.argv``, its session, priority, signal dispositions, temporary
    directory, environment, stdin, command line: the same as ``fresh``; its own random streams;
    its exit code and its streams' text the same."""
    config = _config(tmp_path)
    tmp = tmp_path / "tmp"
    tmp.mkdir()
    seen, results = [], []
    for fresh in (True, False, False):
        log = tmp_path / f"seen-{fresh}-{len(results)}.jsonl"
        env = {**os.environ, "SWARM_SITL_PROBE": str(log), "TMPDIR": str(tmp)}
        r = cli("check", config.name, cwd=tmp_path, env=env, fresh=fresh)
        results.append(r)
        lines = log.read_text().splitlines()
        seen.append(json.loads(lines[0]))
    fresh_seen, forked, again = seen
    assert fresh_seen["random"] != forked["random"] != again["random"]
    for s in seen:
        s.pop("random")
        s["mine"] = os.path.basename(s["mine"])[:4]
    assert forked == fresh_seen and again == fresh_seen
    assert fresh_seen["cwd"] == str(tmp_path) and fresh_seen["tmp"] == str(tmp)
    assert fresh_seen["argv"] == ["check", "swarm.yaml"]
    codes = {r.returncode for r in results}
    assert len(codes) == 1 and codes != {0}, results
    assert len({r.stdout for r in results}) == 1 and "probe: to stdout" in results[0].stdout
    assert len({r.stderr for r in results}) == 1 and "probe: to stderr" in results[0].stderr


@pytest.mark.parametrize("sig, code", [(signal.SIGINT, 130), (signal.SIGTERM, 143), (signal.SIGKILL, -9)])
def test_a_started_command_is_ended_by_a_signal_as_a_new_interpreter_is(tmp_path, sig, code):
    """A run started (``start_cli``) in its own session: a signal to its group ends it with the code
    ``swarm-sitl`` gives that signal (``-N``: killed), as a new interpreter's."""
    procs = [
        start_cli("run", CONFIGS / "paper.yaml", "--realtime", "--out", tmp_path / f"r{k}") for k in range(2)
    ]
    for p in procs:
        assert p.stdout.readline(), "the run printed nothing"  # (started: its first line)
    for p in procs:
        assert os.getsid(p.pid) == p.pid
        os.killpg(p.pid, sig)
    codes = [p.wait(timeout=60) for p in procs]
    assert codes == [code, code], [p.communicate() for p in procs]


def test_a_command_past_its_timeout_is_killed_and_said(tmp_path):
    with pytest.raises(subprocess.TimeoutExpired):
        cli("run", CONFIGS / "paper.yaml", "--realtime", "--out", tmp_path / "r", timeout=2)
