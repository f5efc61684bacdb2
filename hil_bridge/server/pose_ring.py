"""The server's newest ticks of some vehicles' poses, shared in memory with its echo nodes.

The server writes every tick's poses of the vehicles carrying sonars into a ring of
:data:`SLOTS` ticks in one file in shared memory (``/dev/shm``, the domain's
:meth:`~hil_bridge.bus.domain.Domain.shared_dir` tagged ``poses``); each echo node
(:mod:`hil_bridge.server.echo_nodes`) maps it and copies the new ticks into its own
:class:`~hil_bridge.server.pose_history.PoseHistory`. Nothing is encoded or decoded: writing a
tick costs the tick loop one array copy, and a node reads the ticks it missed in one go (its
pose history is then the server's, bit for bit), instead of decoding every state message.

Layout (native byte order, int64 then float64): a header of 8 int64 (``b"ELPOSE01"``, M
vehicles, slots, ``written`` = ticks written so far), the M vehicle ids, the slots' tick stamps
(slots,), then per slot and vehicle 13 float64: position (3), velocity (3), quat (4), rates (3).
The writer fills slot ``written % slots`` and then increments ``written``; a reader takes the
ticks after the last it saw, and keeps only those whose slot was not being written or written
again meanwhile (it reads ``written`` again after copying: of the last ``slots`` ticks, the
oldest shares its slot with the one being written). The server removes the file when it stops; a
killed run's file is swept with the domain's stale tile stores
(:func:`hil_bridge.server.shared_tiles.sweep_stale`).
"""

from __future__ import annotations

import contextlib
import shutil
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from hil_bridge.server.pose_history import F8, PoseHistory
from hil_bridge.server.shared_tiles import sweep_stale

__all__ = ["SLOTS", "PoseRing"]

#: ticks the ring holds (a reader polls well within them)
SLOTS = 256
_MAGIC = np.frombuffer(b"ELPOSE01", dtype=np.int64)[0]
_HEADER = 8
_WRITTEN = 3
_FIELDS = 13


class PoseRing:
    """A pose ring file at ``path`` (module docstring): :meth:`create` makes it (the server),
    :meth:`open` maps it (an echo node)."""

    def __init__(self, path: Path, mm: NDArray[np.int64]) -> None:
        self.path = path
        self._mm = mm
        m, slots = int(mm[1]), int(mm[2])
        self.ids: tuple[int, ...] = tuple(int(i) for i in mm[_HEADER:_HEADER + m])
        self.slots = slots
        at = _HEADER + m
        self._t = mm[at:at + slots]
        self._data = mm[at + slots:].view(np.float64).reshape(slots, m, _FIELDS)
        self.seen = 0
        #: ticks a reader found overwritten before it read them
        self.missed = 0

    @classmethod
    def create(cls, domain: object, ids: Sequence[int], slots: int = SLOTS) -> PoseRing:
        """A fresh ring for vehicles ``ids`` in ``domain`` (stale stores of dead processes
        are removed first)."""
        sweep_stale(domain)  # type: ignore[arg-type]
        path = domain.shared_dir("poses") / "ring"  # type: ignore[attr-defined]
        m = len(ids)
        words = _HEADER + m + slots + slots * m * _FIELDS
        arr = np.memmap(path, dtype=np.int64, mode="w+", shape=(words,))
        arr[:_HEADER] = 0
        arr[0], arr[1], arr[2] = _MAGIC, m, slots
        arr[_HEADER:_HEADER + m] = np.asarray(ids, dtype=np.int64)
        arr.flush()
        return cls(path, arr)

    @classmethod
    def open(cls, path: str | Path) -> PoseRing:
        arr = np.memmap(path, dtype=np.int64, mode="r")
        if arr.size < _HEADER or arr[0] != _MAGIC:
            raise ValueError(f"{path}: not a pose ring")
        return cls(Path(path), arr)

    def write(self, t_ns: int, position: F8, velocity: F8, quat: F8, rates: F8) -> None:
        """Tick ``t_ns``: rows in the order of :attr:`ids` (the writer only)."""
        written = int(self._mm[_WRITTEN])
        k = written % self.slots
        row = self._data[k]
        row[:, 0:3] = position
        row[:, 3:6] = velocity
        row[:, 6:10] = quat
        row[:, 10:13] = rates
        self._t[k] = t_ns
        self._mm[_WRITTEN] = written + 1

    def follow(self, history: PoseHistory) -> int:
        """Record the ticks written since the last call in ``history`` (oldest first); returns
        how many."""
        written = int(self._mm[_WRITTEN])
        # the writer may be filling the slot of tick `written` (that of `written - slots`)
        first = max(self.seen, written - self.slots + 1)
        self.missed += first - self.seen
        if written <= first:
            return 0
        ks = np.arange(first, written) % self.slots
        times = self._t[ks].copy()
        data = self._data[ks].copy()
        now = int(self._mm[_WRITTEN])
        keep = np.arange(first, written) > now - self.slots  # not written again meanwhile
        self.missed += int((~keep).sum())
        self.seen = written
        for t_ns, d in zip(times[keep].tolist(), data[keep], strict=True):
            history.record(t_ns, self.ids, d[:, 0:3], d[:, 3:6], d[:, 6:10], d[:, 10:13])
        return int(keep.sum())

    def remove(self) -> None:
        """Remove the ring's directory (the server, when it stops; idempotent)."""
        shutil.rmtree(self.path.parent, ignore_errors=True)
        with contextlib.suppress(OSError):
            self.path.parent.parent.rmdir()  # the domain's directory, if that emptied it
