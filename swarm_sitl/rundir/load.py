"""Reading a run directory back: the arrays a run wrote, or, where its supervisor died before
writing them, what every process recorded, merged now.
"""

from pathlib import Path

import numpy as np

from swarm_sitl.config.load import ConfigError, load_recorded
from swarm_sitl.rundir.layout import procs_dir
from swarm_sitl.rundir.merge import merge_run
from swarm_sitl.rundir.recording import Recording


class RunDirError(ValueError):
    """A directory is not a readable run directory."""


def load_run(run_dir: str | Path) -> Recording:
    """Every array of a run directory, with the error series (``Recording.with_errors``);
    ``RunDirError`` (one line) for a directory that is not one."""
    d = Path(run_dir)
    if not (d / "leader.npz").is_file():
        if (d / "config.yaml").is_file() and procs_dir(d).is_dir():
            return _merged_from_procs(d)
        raise RunDirError(f"{d}: not a run directory (no leader.npz)")
    leader = dict(np.load(d / "leader.npz"))
    followers: dict[int, dict[str, np.ndarray]] = {}
    offsets: dict[int, np.ndarray] = {}
    for f in sorted(d.glob("follower_*.npz"), key=lambda p: int(p.stem.split("_")[1])):
        i = int(f.stem.split("_")[1])
        arrays = dict(np.load(f))
        offsets[i] = arrays.pop("offset_m")
        followers[i] = arrays
    if not followers:
        raise RunDirError(f"{d}: run directory has no follower_<i>.npz")
    try:
        trajectory = load_recorded(d).trajectory()
    except ConfigError:
        trajectory = None
    return Recording(leader, followers, offsets).with_errors(trajectory)


def _merged_from_procs(d: Path) -> Recording:
    """A run whose supervisor died before it wrote the arrays (SIGKILL): what every process
    recorded, merged now."""
    try:
        cfg = load_recorded(d)
    except ConfigError as e:
        raise RunDirError(f"{d}: no leader.npz, and its config.yaml is unreadable ({e})") from None
    return merge_run(cfg, d)
