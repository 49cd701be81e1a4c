"""``running.warm_commands``: ``swarm-sitl`` forked from a warm server is the command a new
interpreter runs, as its caller sees it (exit code, stdout, stderr, the command line ``ps``
shows, how a signal ends it), from any number of threads at once; any other command line, and
any command started where no fork server may be (a daemonic process), is started as it is."""

import multiprocessing
import os
import signal
import subprocess
import sys
import threading
import time

import pytest
import yaml

from swarm_sitl.running import warm_commands
from tests.support import CONFIGS, ROOT, cmdline, config_data, wait_running

pytestmark = pytest.mark.integration


def _cli(*argv: str) -> list[str]:
    """``swarm-sitl ARGV``'s command line as a campaign gives it (``warm_commands.CLI`` first)."""
    return [*warm_commands.CLI, *argv]


def _both(tmp_path, argv: list[str], name: str) -> list[tuple[int, str, str]]:
    """``swarm-sitl ARGV`` forked, and as a new interpreter (a command line the server does not
    take: ``-P`` before ``-m``): exit code, stdout and stderr of each."""
    out = []
    for k, head in enumerate((warm_commands.CLI, [sys.executable, "-P", "-m", "swarm_sitl"])):
        o, e = tmp_path / f"{name}{k}.out", tmp_path / f"{name}{k}.err"
        c = warm_commands.start(head + argv, o, e)
        assert isinstance(c._proc, subprocess.Popen) == (k == 1)
        out.append((c.wait(timeout=120), o.read_text(), e.read_text()))
    return out


def test_a_forked_command_ends_and_says_what_a_new_interpreters_does(tmp_path):
    """A config that checks (exit 0, its report on stdout) and one that does not (exit 2, one
    line on stderr naming the file and the problem): the same code and the same text both ways."""
    bad = tmp_path / "bad.yaml"
    bad.write_text("name: x\nduration_s: -1\n")
    for argv, code in ((["check", str(CONFIGS / "paper.yaml")], 0), (["check", str(bad)], 2)):
        forked, fresh = _both(tmp_path, argv, argv[1].rsplit("/", 1)[-1])
        assert forked == fresh and forked[0] == code, (forked, fresh)
        assert (forked[1] if code == 0 else forked[2]).strip()
    assert "bad.yaml" in forked[2] and len(forked[2].strip().splitlines()) == 1


def test_commands_started_from_many_threads_each_get_their_own_output_and_code(tmp_path):
    """Eight threads at once (a campaign's), each checking a file of its own that names another
    problem: each command's stderr names its file and its code is its own."""
    files = []
    for i in range(8):
        f = tmp_path / f"c{i}.yaml"
        f.write_text(f"name: c{i}\nduration_s: {-i}\n" if i % 2 else f"name: c{i}\n")
        files.append(f)
    got: dict[int, tuple[int, str]] = {}

    def go(i: int) -> None:
        c = warm_commands.start(_cli("check", str(files[i])), tmp_path / f"{i}.o", tmp_path / f"{i}.e")
        got[i] = (c.wait(timeout=120), (tmp_path / f"{i}.e").read_text())

    threads = [threading.Thread(target=go, args=(i,)) for i in range(8)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    for i in range(8):
        code, err = got[i]
        assert code == 2 and f"c{i}.yaml" in err, (i, got[i])
        assert ("missing key" in err) == (i % 2 == 0) and len(err.strip().splitlines()) == 1, err
        assert not any(f"c{j}.yaml" in err for j in range(8) if j != i)


def test_a_forked_run_shows_its_command_line_and_ends_on_sigint_as_a_run_does(tmp_path):
    """A real-time run: ``ps`` shows ``python -m swarm_sitl run ...``; Ctrl-C (SIGINT) ends it
    with 130 after it wrote its run directory; SIGKILL of another ends it with -9."""
    ends = {}
    for sig in (signal.SIGINT, signal.SIGKILL):
        out = tmp_path / f"run{int(sig)}"
        argv = ["run", str(CONFIGS / "paper.yaml"), "--realtime", "--duration", "60", "--out", str(out)]
        c = warm_commands.start(_cli(*argv), tmp_path / "o", tmp_path / "e")
        assert not isinstance(c._proc, subprocess.Popen)
        wait_running(out)
        assert cmdline(c.pid).split()[1:] == ["-m", "swarm_sitl", *argv]
        c.send_signal(sig)
        ends[sig] = c.wait(timeout=120)
        if sig == signal.SIGINT:
            assert (out / "summary.json").is_file()
    assert ends == {signal.SIGINT: 130, signal.SIGKILL: -signal.SIGKILL}


def _in_a_daemon(conn) -> None:
    c = warm_commands.start(_cli("check", "/no/such.yaml"), "/dev/null", "/dev/null")
    conn.send((type(c._proc).__name__, c.wait(timeout=120)))


def test_a_daemonic_process_which_may_have_no_children_of_multiprocessing_starts_a_new_interpreter():
    """(A Dask worker is one.) The command still runs, as a new interpreter."""
    ctx = multiprocessing.get_context("spawn")
    recv, send = ctx.Pipe(duplex=False)
    p = ctx.Process(target=_in_a_daemon, args=(send,), daemon=True)
    p.start()
    assert recv.poll(120)
    assert recv.recv() == ("Popen", 2)
    p.join()


def test_a_command_past_its_wait_is_told_and_goes_on_until_killed(tmp_path):
    """``wait(timeout)`` raises ``TimeoutExpired`` and leaves the command running."""
    c = warm_commands.start(
        _cli("run", str(CONFIGS / "paper.yaml"), "--realtime", "--out", str(tmp_path / "r")),
        tmp_path / "o",
        tmp_path / "e",
    )
    t0 = time.monotonic()
    with pytest.raises(subprocess.TimeoutExpired):
        c.wait(timeout=0.5)
    assert 0.5 <= time.monotonic() - t0 < 30 and c.poll() is None and os.path.exists(f"/proc/{c.pid}")
    c.kill()
    assert c.wait(timeout=60) == -signal.SIGKILL


def test_a_forked_commands_exit_handlers_run_and_it_sees_its_callers_environment_as_a_new_interpreter(
    tmp_path, monkeypatch
):
    """A user's law that reads a variable of its environment and the temporary directory when
    imported, and registers an exit handler (its own log flushed, a device closed): the handler
    runs once when ``check`` ends, forked as in a new interpreter, and each command sees the
    environment its caller had when it started it (the fork server's is the first caller's)."""
    config = dict(config_data("paper"), law={"entry": "my_law.py:ConsensusPD", "params": {}})
    (tmp_path / "c.yaml").write_text(yaml.safe_dump(config))
    law = (ROOT / "examples" / "laws" / "consensus_pd.py").read_text()
    marker = tmp_path / "marker"
    (tmp_path / "my_law.py").write_text(
        law
        + "\n\nimport atexit, os, tempfile\n\n"
        + "mark = os.environ['SWARM_MARK'] + ' ' + tempfile.gettempdir()\n"
        + f"open({str(marker)!r}, 'a').write(mark + '\\n')\n"
        + f"atexit.register(lambda: open({str(marker)!r}, 'a').write('ran\\n'))\n"
    )
    seen = []
    for mark in ("first", "second"):
        tmp = tmp_path / f"tmp-{mark}"
        tmp.mkdir()
        monkeypatch.setenv("SWARM_MARK", mark)
        monkeypatch.setenv("TMPDIR", str(tmp))
        forked, fresh = _both(tmp_path, ["check", str(tmp_path / "c.yaml")], "law")
        assert forked[0] == fresh[0] == 0, (forked, fresh)
        seen.append(f"{mark} {tmp}")
    assert marker.read_text() == "".join(f"{s}\nran\n" * 2 for s in seen)
