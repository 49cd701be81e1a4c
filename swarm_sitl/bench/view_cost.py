"""``bench --view``: what a page open on a run costs it, measured in one go.

The lockstep ``run`` of the config without a page and with ``--view 0`` and a page open on it
(Debian's ``chromium``, headless, loading the page as a user's browser does and polling it as it
does; where there is no chromium, a client in this process that requests what the page requests,
as often), alternated ``pairs`` times after one untimed run of each. Printed: the run phase's wall
time (start signal to last tick, as the CLI prints it) and the CPU of every process (the
browser's included), with and without, and their ratios. The issue's target: the run phase
within 5 % of the run without a page.
"""

import json
import re
import shutil
import signal
import subprocess
import tempfile
import threading
import urllib.request
from pathlib import Path

from swarm_sitl.bench.speed import cpu_now, ended, print_pairs
from swarm_sitl.running.children import child_env, module_argv
from swarm_sitl.running.supervisor import RunFailedError

_URL = re.compile(r"http://[0-9.]+:\d+/")
POLL_S = 0.2  #: how often the page asks for new frames (view.js: POLL_MS)


def _poll_like_the_page(url: str, stop: threading.Event) -> None:
    """The page's requests without a browser: the page, the document, then new frames every 0.2 s."""
    try:
        for path in ("", "view.js", "view.css"):
            urllib.request.urlopen(url + path, timeout=5).read()
        doc = json.loads(urllib.request.urlopen(url + "document.json", timeout=5).read())
        frames, events = len(doc["frames"]["t_s"]), len(doc["events"])
        while not stop.wait(POLL_S):
            more = json.loads(
                urllib.request.urlopen(f"{url}frames.json?from={frames}&events={events}", timeout=5).read()
            )
            frames += len(more["frames"]["t_s"])
            events += len(more["events"])
    except OSError:
        return  # the run is over: its server is gone


def _run(cfg_path: str, out: Path, page: str | None, profile: Path) -> tuple[float, float]:
    """One lockstep run (``page``: None, ``chromium`` or ``client``): its run phase's wall time
    and the CPU seconds of every process it took, the page's own included. ``profile``: the
    browser's, made by the untimed first run and used by every other (as a user's browser has one)."""
    cpu0 = cpu_now()
    argv = [*module_argv("swarm_sitl"), "run", cfg_path, "--quiet", "--out", str(out)]
    if page is not None:
        argv += ["--view", "0"]
    proc = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=child_env())
    browser = None
    stop = threading.Event()
    poller = None
    first = ""
    if page is not None and proc.stdout is not None:
        first = proc.stdout.readline()
        m = _URL.search(first)
        if m is None:
            proc.kill()
            raise RunFailedError(f"run --view printed {first.strip()!r}, not the page's address")
        if page == "chromium":
            chromium = shutil.which("chromium") or shutil.which("chromium-browser")
            assert chromium is not None
            browser = subprocess.Popen(
                [
                    chromium,
                    "--headless=new",
                    "--no-sandbox",
                    "--disable-gpu",
                    f"--user-data-dir={profile}",
                    m.group(0),
                ],
                stdout=subprocess.DEVNULL,
                stderr=subprocess.DEVNULL,
            )
        else:
            poller = threading.Thread(target=_poll_like_the_page, args=(m.group(0), stop), daemon=True)
            poller.start()
    stdout, stderr = proc.communicate()
    stop.set()
    if poller is not None:
        poller.join()
    if browser is not None:
        browser.send_signal(signal.SIGTERM)
        browser.wait(30)
    answered = re.search(r"live view: (\d+) requests answered", stderr)
    if page is not None and (answered is None or int(answered.group(1)) < 3):
        raise RunFailedError(
            f"the page ({page}) did not load: {answered.group(0) if answered else stderr[-200:]}"
        )
    return ended(proc.returncode, first + stdout, stderr, cpu0)


def view_cost(cfg_path: str, pairs: int) -> int:
    """The run of ``cfg_path`` without and with a page, alternated; prints both and the ratios."""
    page = "chromium" if shutil.which("chromium") or shutil.which("chromium-browser") else "client"
    got: dict[str | None, list[tuple[float, float]]] = {None: [], page: []}
    with tempfile.TemporaryDirectory() as tmp:
        for r in range(pairs + 1):
            order = (None, page) if r % 2 == 0 else (page, None)
            for j, how in enumerate(order):
                w = _run(cfg_path, Path(tmp) / f"r{r}_{j}", how, Path(tmp) / "browser_profile")
                if r > 0:
                    got[how].append(w)
    shown = "a headless chromium on the page" if page == "chromium" else "a client polling like the page"
    print(f"lockstep run of {cfg_path}, without and with --view ({shown}), {pairs} pairs alternated:")
    for what, col in (("run phase wall, as the CLI prints it", 0), ("CPU of every process", 1)):
        without, with_page = [x[col] for x in got[None]], [x[col] for x in got[page]]
        print_pairs(what, ("with", with_page), ("without", without), "with / without")
    print("  target: the run phase with a page within 5 % of the run without")
    return 0
