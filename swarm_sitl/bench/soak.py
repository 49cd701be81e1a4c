"""``swarm-sitl bench --soak MINUTES``: a long real-time run, watched from outside, for leaks.

Each config (the paper swarm, then a 16-follower generated one, by default) flies ``MINUTES`` of
real time as ``swarm-sitl run --realtime`` does. Every ``SAMPLE_EVERY_S`` the watcher reads, for
every process of the run (each found by its standard output, which is its log file in the run
directory, and this one as ``supervisor``), its resident memory and its open files from ``/proc``,
and the size of the run directory. Printed per process and written to ``OUT/soak.csv`` (every
sample), ``OUT/soak.json`` (the figures) and ``OUT/soak.png``:

- resident memory after the first minute (start-up, kernels loaded, buffers at their working size)
  and at the end, and the growth between them (target: < 5 %);
- open files after the first minute and at the end (a leak of sockets or files shows here);
- late control ticks over all controllers (skipped, or whose setpoint went out after the next
  tick's instant; target: < 1 %);
- the run directory's size per simulated minute, and how fast the raw records grew while it ran.

Linux only (``/proc``). Not part of the test run: it is as long as it is told to be.
"""

import contextlib
import csv
import json
import os
import shutil
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt

from swarm_sitl.bench.speed import late_ticks
from swarm_sitl.config.load import load_config
from swarm_sitl.rundir.merge import merge_run
from swarm_sitl.rundir.outputs import write_outputs
from swarm_sitl.running.run import RunRequest, run_swarm

SAMPLE_EVERY_S = 10.0
SETTLED_AFTER_S = 60.0  #: the growth is measured from here ("after the first minute")
RSS_GROWTH_TARGET = 0.05
LATE_TARGET = 0.01


@dataclass
class Sample:
    t_s: float  #: since the run's first tick [s]
    rss_kb: dict[str, int]
    open_files: dict[str, int]
    run_dir_bytes: int


@dataclass
class Watcher:
    """Samples the run's processes from ``/proc`` every ``SAMPLE_EVERY_S`` of wall time."""

    run_dir: Path
    samples: list[Sample] = field(default_factory=list)
    t0: float = 0.0
    next_s: float = 0.0

    def __call__(self, _step: int, _errors: dict[int, float]) -> None:
        now = time.monotonic()
        if not self.t0:
            self.t0 = now
        if now < self.next_s:
            return
        self.next_s = now + SAMPLE_EVERY_S
        rss, files = {}, {}
        for name, pid in self.processes().items():
            kb, n = _rss_kb(pid), _open_files(pid)
            if kb is not None and n is not None:
                rss[name], files[name] = kb, n
        self.samples.append(Sample(now - self.t0, rss, files, _tree_bytes(self.run_dir)))

    def processes(self) -> dict[str, int]:
        """``{name: pid}`` of the run's live processes: those whose stdout is a log of the run."""
        logs = str((self.run_dir / "logs").resolve()) + os.sep
        found = {"supervisor": os.getpid()}
        for entry in os.scandir("/proc"):
            if not entry.name.isdigit():
                continue
            try:
                out = os.readlink(f"/proc/{entry.name}/fd/1")
            except OSError:
                continue
            if out.startswith(logs) and out.endswith(".log"):
                found[Path(out).stem] = int(entry.name)
        return found


def _rss_kb(pid: int) -> int | None:
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1])
    except OSError:
        return None
    return None


def _open_files(pid: int) -> int | None:
    try:
        return len(os.listdir(f"/proc/{pid}/fd"))
    except OSError:
        return None


def _tree_bytes(path: Path) -> int:
    total = 0
    for dirpath, _dirs, files in os.walk(path):
        for f in files:
            with contextlib.suppress(OSError):  # a file renamed or removed while we walk
                total += os.stat(os.path.join(dirpath, f)).st_size
    return total


def _at(samples: list[Sample], t_s: float) -> Sample:
    """The first sample at or after ``t_s`` (the last one if the run was shorter)."""
    return next((s for s in samples if s.t_s >= t_s), samples[-1])


def _figures(name: str, minutes: float, w: Watcher, late: int, ticks: int) -> dict:
    first, last = _at(w.samples, SETTLED_AFTER_S), w.samples[-1]
    procs = {}
    for p in sorted(set(first.rss_kb) & set(last.rss_kb)):
        procs[p] = {
            "rss_kb_after_1_min": first.rss_kb[p],
            "rss_kb_end": last.rss_kb[p],
            "rss_growth": last.rss_kb[p] / first.rss_kb[p] - 1.0,
            "open_files_after_1_min": first.open_files[p],
            "open_files_end": last.open_files[p],
        }
    raw_rate = (last.run_dir_bytes - first.run_dir_bytes) / max(last.t_s - first.t_s, 1e-9) * 60
    return {
        "config": name,
        "minutes": minutes,
        "processes": procs,
        "late_ticks": late,
        "ticks": ticks,
        "late_fraction": late / ticks,
        "raw_bytes_per_minute_while_running": raw_rate,
    }


def _print(fig: dict) -> None:
    head = ("process", "RSS 1 min", "RSS end", "growth", "files 1 min", "files end")
    print("  {:<16} {:>10} {:>10} {:>8} {:>12} {:>10}".format(*head))
    for p, f in fig["processes"].items():
        print(
            f"  {p:<16} {f['rss_kb_after_1_min'] / 1024:>7.1f} MiB {f['rss_kb_end'] / 1024:>6.1f} MiB "
            f"{100 * f['rss_growth']:>7.2f}% {f['open_files_after_1_min']:>12} {f['open_files_end']:>10}"
        )
    worst = max(fig["processes"].items(), key=lambda kv: kv[1]["rss_growth"])
    print(
        f"  largest growth after the first minute: {worst[0]} {100 * worst[1]['rss_growth']:.2f} % "
        f"(target: < {100 * RSS_GROWTH_TARGET:g} %)"
    )
    print(
        f"  late ticks: {fig['late_ticks']} of {fig['ticks']} = {100 * fig['late_fraction']:.3f} % "
        f"(target: < {100 * LATE_TARGET:g} %)"
    )
    print(
        f"  run directory: {fig['run_dir_bytes'] / 1e6:.1f} MB = {fig['run_dir_mb_per_sim_minute']:.2f} MB "
        f"per simulated minute; raw records grew {fig['raw_bytes_per_minute_while_running'] / 1e6:.2f} MB "
        "per minute while it ran"
    )


def _plot(results: list[tuple[dict, Watcher]], path: Path) -> None:
    fig, axes = plt.subplots(1, len(results), figsize=(6.5 * len(results), 4.2), squeeze=False)
    for ax, (f, w) in zip(axes[0], results, strict=True):
        t_min = [s.t_s / 60 for s in w.samples]
        for p in f["processes"]:
            ax.plot(t_min, [s.rss_kb.get(p, float("nan")) / 1024 for s in w.samples], lw=0.8, label=p)
        ax.axvline(SETTLED_AFTER_S / 60, color="grey", ls=":", lw=0.8)
        ax.set(xlabel="run time [min]", ylabel="resident memory [MiB]", title=f"{f['config']} (real time)")
        if len(f["processes"]) <= 12:
            ax.legend(fontsize=7, ncol=2)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def run_soak(minutes: float, configs: list[str], out: Path) -> int:
    """Fly each config ``minutes`` in real time, watched; print and write the figures."""
    if not Path("/proc/self/status").is_file():
        print("swarm-sitl: error: bench --soak reads /proc (Linux only)", file=sys.stderr)
        return 2
    out.mkdir(parents=True, exist_ok=True)
    results = []
    rows = []
    for cfg_path in configs:
        cfg = load_config(cfg_path).model_copy(update={"duration_s": minutes * 60.0})
        run_dir = out / Path(cfg_path).stem
        if run_dir.exists():
            shutil.rmtree(run_dir)
        print(
            f"soak: {cfg_path} ({cfg.n_followers} followers, {2 * cfg.n_followers + 1} processes) "
            f"for {minutes:g} min in real time -> {run_dir}",
            flush=True,
        )
        w = Watcher(run_dir)
        run_swarm(RunRequest(cfg, run_dir, lockstep=False, on_progress=w))
        w.next_s = 0.0
        late, ticks, _ = late_ticks(cfg, run_dir)
        write_outputs(cfg, merge_run(cfg, run_dir), run_dir, processes=True)
        fig = _figures(cfg_path, minutes, w, late, ticks)
        fig["run_dir_bytes"] = _tree_bytes(run_dir)
        fig["run_dir_mb_per_sim_minute"] = fig["run_dir_bytes"] / 1e6 / minutes
        _print(fig)
        results.append((fig, w))
        for s in w.samples:
            for p in s.rss_kb:
                rows.append([cfg_path, f"{s.t_s:.1f}", p, s.rss_kb[p], s.open_files[p], s.run_dir_bytes])
    with open(out / "soak.csv", "w", newline="") as fh:
        wr = csv.writer(fh)
        wr.writerow(["config", "t_s", "process", "rss_kb", "open_files", "run_dir_bytes"])
        wr.writerows(rows)
    (out / "soak.json").write_text(json.dumps([f for f, _ in results], indent=1) + "\n")
    _plot(results, out / "soak.png")
    print(f"soak figures in {out}/soak.csv, soak.json and soak.png")
    return 0
