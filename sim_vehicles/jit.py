"""The one place that decides how numerical kernels are compiled."""

from collections.abc import Callable
from typing import Any

from numba import njit as _njit


def kernel(fn: Callable[..., Any]) -> Any:
    """Compile ``fn`` in nopython mode, cached on disk so later processes start fast.

    ``error_model="numpy"``: a division by zero gives inf/nan instead of raising inside the kernel;
    callers check results for finiteness where it matters (``FollowerController.step``).
    """
    return _njit(cache=True, fastmath=False, nogil=True, error_model="numpy")(fn)
