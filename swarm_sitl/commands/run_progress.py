"""``run``'s progress bar: the slowest follower's tick, and each follower's formation error from
its status messages, with the lines a user must see printed above it."""

import sys
from typing import Any

from tqdm import tqdm

from swarm_sitl.config.schema import SwarmConfig


class _Bar(tqdm):
    """tqdm without its monitor thread: the bar is updated from the supervisor's loop, and a thread
    in the supervisor's process would keep it from forking the run's fork server from itself
    (``running.fork_server``: half a second of the run's start-up)."""

    monitor_interval = 0


class RunProgress:
    """A progress bar over ticks with each follower's formation error from its status messages."""

    def __init__(self, cfg: SwarmConfig, label: str, quiet: bool):
        self.cfg = cfg
        self.bar: Any = None
        if not quiet:
            self.bar = _Bar(
                total=cfg.n_control_steps + 1, unit="tick", desc=label, mininterval=0.25, leave=False
            )

    def __call__(self, step: int, errors_m: dict[int, float]) -> None:
        if self.bar is None:
            return
        if step + 1 > self.bar.n:
            self.bar.update(step + 1 - self.bar.n)
        if errors_m:
            worst = max(errors_m, key=lambda i: errors_m[i])
            shown = (
                " ".join(f"{i}:{e:.3f}" for i, e in sorted(errors_m.items()))
                if len(errors_m) <= 6
                else f"max {errors_m[worst]:.3f} (#{worst})"
            )
            self.bar.set_postfix_str(f"|p-p_r-d| m {shown}", refresh=False)

    def note(self, lines: list[str]) -> None:
        """Lines printed above the bar (the vehicles' ports, as they come up); with ``--quiet``
        only what a user must act on (``run --external``)."""
        if self.bar is not None:
            for line in lines:
                self.bar.write(line)
        else:
            for line in lines:
                if "(--external)" in line:
                    print(line)
        sys.stdout.flush()  # a pipe's reader (a script waiting for the ports) gets them now

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()
