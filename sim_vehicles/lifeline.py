"""Die with the parent: a child process started by a supervisor asks the kernel for SIGTERM when
its parent goes away, so a supervisor killed with SIGKILL leaves no orphan (Linux; elsewhere a no-op).

The supervisor puts its pid in ``SWARM_SITL_PARENT_PID``; the child calls ``hold_on()`` first thing.
"""

import ctypes
import os
import signal
import sys

ENV = "SWARM_SITL_PARENT_PID"
_PR_SET_PDEATHSIG = 1


def hold_on() -> None:
    parent = os.environ.get(ENV)
    if not parent or not sys.platform.startswith("linux"):
        return
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(_PR_SET_PDEATHSIG, int(signal.SIGTERM), 0, 0, 0)
    except (OSError, AttributeError):
        return
    if str(os.getppid()) != parent:  # the parent died before we asked
        os.kill(os.getpid(), signal.SIGTERM)
