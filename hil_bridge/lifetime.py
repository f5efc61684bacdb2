"""A process that ends with the one that spawned it (Linux ``PR_SET_PDEATHSIG``).

Node hosts (:mod:`hil_bridge.launch.host`, SIGTERM: they stop their nodes first) and echo
workers (:mod:`hil_bridge.server.echo_pool`, SIGKILL: they hold nothing to clean up) call
:func:`die_with_parent` first thing, so neither outlives a parent killed with -9.
"""

from __future__ import annotations

import contextlib
import ctypes
import os
import signal

__all__ = ["die_with_parent"]

_PR_SET_PDEATHSIG = 1


def die_with_parent(parent_pid: int, sig: int = signal.SIGTERM) -> None:
    """Have the kernel send ``sig`` to this process when its parent dies (``prctl``; the parent
    is the *thread* that spawned it, so spawn from a thread that outlives the child); exit now
    if the parent is already gone."""
    with contextlib.suppress(OSError, AttributeError):
        ctypes.CDLL(None, use_errno=True).prctl(_PR_SET_PDEATHSIG, int(sig), 0, 0, 0)
    if os.getppid() != parent_pid:
        os._exit(1)
