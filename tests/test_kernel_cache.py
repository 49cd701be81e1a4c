"""The compiled kernels' disk cache (``sim_vehicles.common.jit``): two copies of the same sources (a
checkout and its installed package) share one compiled kernel, and a changed source is compiled
again, never served from the other's cache."""

import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from sim_vehicles.common.jit import package_folder
from tests.support import ROOT

#: one process per copy, a kernel each, no clock: free to run beside others
pytestmark = pytest.mark.lockstep

CALL = (
    "import numpy as np, sim_vehicles.common.quaternion as q; "
    "assert q.__file__.startswith(__import__('os').getcwd()); "
    "q.qmul(np.array([1.0, 0, 0, 0]), np.array([0.0, 1, 0, 0]))"
)


def _copy(dst: Path) -> Path:
    """Both packages, as an installed copy holds them (the cache's directory is named after the
    kernels' sources in both)."""
    for package in ("sim_vehicles", "swarm_sitl"):
        shutil.copytree(ROOT / package, dst / package, ignore=shutil.ignore_patterns("__pycache__"))
    return dst


def _kernel_from(root: Path, cache: Path) -> str:
    """What numba says of its cache when ``root``'s copy of the package calls one kernel."""
    env = {"PATH": "/usr/bin:/bin", "NUMBA_CACHE_DIR": str(cache), "NUMBA_DEBUG_CACHE": "1"}
    r = subprocess.run(
        [sys.executable, "-c", CALL], cwd=root, env=env, capture_output=True, text=True, timeout=120
    )
    assert r.returncode == 0, r.stderr[-2000:]
    return r.stdout + r.stderr


@pytest.mark.system
def test_a_checkout_and_a_copy_of_it_share_a_kernel_and_a_changed_source_is_compiled_again(tmp_path):
    cache = tmp_path / "cache"
    copy = _copy(tmp_path / "copy")
    first = _kernel_from(copy, cache)
    assert "data saved" in first and "qmul" in first  # compiled, on a cold cache
    again = _kernel_from(ROOT, cache)
    assert "data loaded" in again and "data saved" not in again  # the checkout loads the copy's
    quaternion = copy / "sim_vehicles" / "common" / "quaternion.py"
    quaternion.write_text(quaternion.read_text() + "\n# changed\n")
    assert "data saved" in _kernel_from(copy, cache)  # a changed source: compiled anew


@pytest.mark.unit
@pytest.mark.parametrize("prefix", ["/", "/opt/venv/lib/python3.11/site-packages/", "/home/u/swarm_sitl/"])
def test_a_kernels_cache_is_named_after_its_folder_in_the_package_wherever_the_package_is(prefix):
    for package in ("sim_vehicles", "swarm_sitl"):
        for folder in ("common", "plant/deeper"):
            path = f"{prefix}{package}/{folder}/module.py"
            assert package_folder(path) == f"{package}/{folder}"
    assert package_folder("/home/u/my_models/vehicle.py") is None  # a user's file: numba places it
