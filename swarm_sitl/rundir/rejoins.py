"""Whether the followers came back after each planned restart: the summary's ``rejoins``.

A fault plan's ``restart_after_s`` starts a killed controller or leader again. A follower
*depends* on a restarted process when its information flows from it: the restarted follower
itself and every follower a directed path of the graph leads to from it; every follower, for the
leader. Each one that depends on it (and whose vehicle is not lost) is judged over the *window*
from the restart instant ``t_r`` (the supervisor's ``process_restarted`` event) to the next planned
kill of any process, or the run's end:

- it is **back** at the first recorded instant ``t_b >= t_r`` from which its formation error
  ``|p - p_r - delta|`` stays at or below the *rejoin bound* to the window's end. The bound is
  ``run.max_formation_error_m`` where it is set, else ``REJOIN_ERROR_M``;
- it **rejoined** if it is back within ``run.rejoin_within_s`` of ``t_r``;
- it **did not rejoin** if it is not, and the window lasted at least ``run.rejoin_within_s``;
- it is **not judged** if the window was shorter than that (the run ended, or another kill came,
  first) and it was not back by then.

A follower that did not rejoin is named in the run's last lines, and with a bound set it fails
the run (``bound_failures``' lines, exit 3). Rows not recorded (ticks a real-time controller
skipped, or the ones it was down) are left out.
"""

from typing import Any

import numpy as np

from swarm_sitl.laws.graph import Graph
from swarm_sitl.rundir.settling import time_to_converge

#: the rejoin bound without ``run.max_formation_error_m`` [m]: the summary's first convergence
#: level (``time_to_0.1m_s``)
REJOIN_ERROR_M = 0.1


def dependants(graph: Graph, process: str) -> list[int]:
    """The followers whose information flows from ``process`` (``leader`` or ``controller_<i>``)."""
    if process == "leader":
        node = 0
    else:
        head, _, num = process.partition("_")
        if head != "controller" or not num.isdigit():
            return []
        node = int(num)
    return sorted(graph.reached_from(node) - {0})


def judge_rejoins(
    followers: dict[int, dict[str, np.ndarray]],
    events: list[dict[str, Any]],
    graph: Graph,
    end_s: float,
    bound_m: float | None,
    within_s: float,
    lost: set[int],
) -> list[dict[str, Any]]:
    """One entry per planned restart of a controller or the leader, in time order: the process,
    its restart instant, the window and bound it was judged over, and per dependant follower
    ``back_after_s`` (None: not back), ``error_at_end_m`` (the last recorded in the window; None:
    nothing recorded) and ``verdict`` (``rejoined``, ``did not rejoin``, ``not judged``)."""
    bound = REJOIN_ERROR_M if bound_m is None else bound_m
    kills = sorted(float(e["t_s"]) for e in events if e.get("kind") == "process_killed")
    out = []
    for e in sorted(
        (e for e in events if e.get("kind") == "process_restarted"), key=lambda e: float(e["t_s"])
    ):
        t_r = float(e["t_s"])
        until = min([k for k in kills if k > t_r] + [end_s])
        judged: dict[str, Any] = {}
        for i in dependants(graph, str(e.get("process", ""))):
            a = followers.get(i)
            if i in lost or a is None:
                continue
            err = np.linalg.norm(a["pos_err_m"], axis=1)
            t = a["t_s"]
            ok = np.isfinite(t) & np.isfinite(err) & (t >= t_r) & (t <= until)
            back = time_to_converge(t[ok], err[ok], bound)
            back_after = None if back is None else round(back - t_r, 6)
            if back_after is not None and back_after <= within_s:
                verdict = "rejoined"
            elif until - t_r >= within_s:
                verdict = "did not rejoin"
            else:
                verdict = "not judged"
            judged[str(i)] = {
                "back_after_s": back_after,
                "error_at_end_m": float(err[ok][-1]) if ok.any() else None,
                "verdict": verdict,
            }
        out.append(
            {
                "process": e.get("process"),
                "restart_s": t_r,
                "window_s": round(until - t_r, 6),
                "bound_m": bound,
                "within_s": within_s,
                "followers": judged,
            }
        )
    return out


def _error(x: float | None) -> str:
    return "nothing recorded" if x is None else f"{x:.3g} m"


def rejoin_lines(summary: dict[str, Any]) -> tuple[list[str], list[str]]:
    """What the run says of its restarts: lines to print, and the failures (``did not rejoin:
    follower 2, 25.5 m at the end ...``), one per follower that did not come back."""
    lines: list[str] = []
    failures: list[str] = []
    for r in summary.get("rejoins", []):
        where = f"{r['process']} restarted at {r['restart_s']:g} s"
        back, unjudged = [], []
        for i, f in sorted(r["followers"].items(), key=lambda kv: int(kv[0])):
            if f["verdict"] == "rejoined":
                back.append(f"{i} after {f['back_after_s']:.2f} s")
            elif f["verdict"] == "did not rejoin":
                failures.append(
                    f"did not rejoin: follower {i}, {_error(f['error_at_end_m'])} at the end ({where}; "
                    f"not within {r['bound_m']:g} m for good within "
                    f"run.rejoin_within_s = {r['within_s']:g} s)"
                )
            else:
                unjudged.append(i)
        if back:
            lines.append(f"  {where}: back within {r['bound_m']:g} m: follower " + ", ".join(back))
        if unjudged:
            lines.append(
                f"  {where}: follower {', '.join(unjudged)} not back within {r['bound_m']:g} m when the "
                f"run ended or the next kill came {r['window_s']:.2f} s later: not judged "
                f"(run.rejoin_within_s = {r['within_s']:g} s)"
            )
    return lines, failures
