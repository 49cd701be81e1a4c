"""The one place that decides how numerical kernels are compiled.

Kernels are cached on disk, in a directory named after the sources of every module that defines
one (``_cache_dir``): numba checks a cached kernel against its own file only, so a kernel that
calls one from another file (``tick_frames.read_setpoint`` calls ``wire_format``'s) kept the old
callee after that file changed, and an upgraded install would have flown stale code.

Inside it, a kernel's cache is named after its module's folder in the package
(``sim_vehicles_plant``), not after that folder's absolute path as numba names it
(``_TreeLocator``): a checkout and an installed copy of the same sources (a test run from the
checkout and the commands it starts from the installed package) load each other's kernels instead
of compiling the whole set twice on a fresh machine.
"""

import hashlib
import os
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numba
import numpy as np
from numba import njit as _njit
from numba.core import caching as _caching

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


def package_folder(py_file: str) -> str | None:
    """The folder of ``py_file`` from its package on (``sim_vehicles/plant``), or None for a file
    of no package of ours (a user's model: numba's own locators place it)."""
    parts = Path(py_file).resolve().parts[:-1]
    at = [i for i, part in enumerate(parts) if part in _PACKAGES]
    return "/".join(parts[at[-1] :]) if at else None


#: numba's locator of ``NUMBA_CACHE_DIR`` and its list of locators, tried in order (numba 0.68's
#: names; were either gone in a later numba, kernels would still cache, one folder per copy)
_USER_LOCATOR: Any = getattr(_caching, "UserProvidedCacheLocator", None)
_LOCATORS: Any = getattr(getattr(_caching, "CacheImpl", None), "_locator_classes", None)

if _USER_LOCATOR is not None and isinstance(_LOCATORS, list):

    class _TreeLocator(_USER_LOCATOR):
        """numba's locator of ``NUMBA_CACHE_DIR``, for our kernels: named after the package
        folder (module docstring). numba stamps a cached kernel with its file's content (since
        0.68), which two copies of one source share."""

        def __init__(self, py_func: Any, py_file: str):
            super().__init__(py_func, py_file)
            folder = str(package_folder(py_file)).replace("/", "_")
            self._cache_path = os.path.join(str(numba.config.CACHE_DIR), folder)  # type: ignore[attr-defined]

        @classmethod
        def from_function(cls, py_func: Any, py_file: str) -> Any:
            if package_folder(py_file) is None:
                return None
            return super().from_function(py_func, py_file)

    if not any(c.__name__ == "_TreeLocator" for c in _LOCATORS):  # (not again: a module reloaded)
        _LOCATORS.insert(0, _TreeLocator)


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
