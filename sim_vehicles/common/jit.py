"""The one place that decides how numerical kernels are compiled.

Kernels are cached on disk, in a directory named after the sources of every module that defines
one (``_cache_dir``): numba checks a cached kernel against its own file only, so a kernel that
calls one from another file (``tick_frames.read_setpoint`` calls ``wire_format``'s) kept the old
callee after that file changed, and an upgraded install would have flown stale code.
"""

import hashlib
import os
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numba
import numpy as np
from numba import njit as _njit

_PACKAGES = ("sim_vehicles", "swarm_sitl")


def _cache_dir() -> Path:
    """``$NUMBA_CACHE_DIR`` (default ``~/.cache/swarm-sitl/numba``) / a hash of the kernel sources."""
    root = Path(__file__).resolve().parents[2]
    h = hashlib.sha256(numba.__version__.encode())
    for package in _PACKAGES:
        for path in sorted((root / package).rglob("*.py")):
            text = path.read_bytes()
            if b"@kernel" in text:
                h.update(path.relative_to(root).as_posix().encode() + b"\0" + text)
    base = os.environ.get("NUMBA_CACHE_DIR") or str(Path.home() / ".cache" / "swarm-sitl" / "numba")
    return Path(base) / h.hexdigest()[:16]


numba.config.CACHE_DIR = str(_cache_dir())  # type: ignore[attr-defined]


def kernel(fn: Callable[..., Any]) -> Any:
    """Compile ``fn`` in nopython mode, cached on disk so later processes start fast.

    ``error_model="numpy"``: a division by zero gives inf/nan instead of raising inside the kernel;
    callers check results for finiteness where it matters (``ZouMengLaw.step``).
    """
    return _njit(cache=True, fastmath=False, nogil=True, error_model="numpy")(fn)


def kernel_array(v: Any) -> np.ndarray:
    """``v`` as a writable C-contiguous float64 array, itself if it is one already: a kernel is
    compiled once per argument type, and a read-only or strided array is another type (each
    process would load a second version of the kernel the first time it met one)."""
    if type(v) is np.ndarray and v.dtype == np.float64 and v.flags.c_contiguous and v.flags.writeable:
        return v
    return np.require(v, dtype=np.float64, requirements=["C", "W"])
