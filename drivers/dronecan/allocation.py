"""DroneCAN dynamic node-ID allocation, the allocatee's side (UAVCAN v0,
``uavcan.protocol.dynamic_node_id.Allocation``).

An anonymous node asks an allocator (ArduPilot's DNA server, ``dronecan``'s
``CentralizedServer``) for a node ID with its 16-byte unique ID, in three anonymous
single-frame messages of at most 6 bytes each: the first part (``first_part_of_unique_id``
set) every 600–1000 ms (random) until the allocator echoes it, then each following part
within 0–400 ms of the allocator's echo of the parts so far; an echo that does not match the
unique ID, or no echo within 500 ms, starts again. The allocator's message carrying all 16
bytes and a node ID is the allocation. :class:`Allocatee` is that state machine, on injected
time and randomness: :meth:`Allocatee.poll` says what to send when, :meth:`Allocatee.on_message`
takes what the allocator broadcasts.
"""

from __future__ import annotations

import random
from dataclasses import dataclass

__all__ = ["Allocatee", "Request"]

_MIN_PERIOD_S, _MAX_PERIOD_S = 0.6, 1.0
_MIN_FOLLOWUP_S, _MAX_FOLLOWUP_S = 0.0, 0.4
_FOLLOWUP_TIMEOUT_S = 0.5
_PART = 6


@dataclass(frozen=True, slots=True)
class Request:
    """One anonymous Allocation message to send: the preferred ``node_id`` (0: any),
    ``first_part`` of the unique ID or not, and the bytes of ``unique_id`` it carries."""

    node_id: int
    first_part: bool
    unique_id: bytes


class Allocatee:
    """The allocatee (module docstring) of ``unique_id`` (16 bytes), preferring
    ``preferred_node_id`` (0: any); ``rng`` times its requests."""

    def __init__(self, unique_id: bytes, preferred_node_id: int = 0, *,
                 rng: random.Random, now: float) -> None:
        if len(unique_id) != 16:
            raise ValueError(f"unique_id: expected 16 bytes, got {len(unique_id)}")
        if not 0 <= preferred_node_id <= 125:
            raise ValueError(f"preferred_node_id: expected 0..125, got {preferred_node_id}")
        self.unique_id = bytes(unique_id)
        self.preferred = preferred_node_id
        self._rng = rng
        self._sent = 0  # bytes of the unique ID the allocator has echoed
        self._due = now + self._rng.uniform(0.0, _MAX_PERIOD_S)
        self._echo_at: float | None = None
        #: the node ID allocated, once it is
        self.node_id: int | None = None
        self.restarts = 0

    def poll(self, now: float) -> Request | None:
        """What to send now, if anything."""
        if self.node_id is not None:
            return None
        if self._echo_at is not None and self._sent and now - self._echo_at > _FOLLOWUP_TIMEOUT_S:
            self._restart(now)
        if now < self._due:
            return None
        if self._sent == 0:
            self._due = now + self._rng.uniform(_MIN_PERIOD_S, _MAX_PERIOD_S)
            return Request(self.preferred, True, self.unique_id[:_PART])
        part = self.unique_id[self._sent:self._sent + _PART]
        self._due = now + self._rng.uniform(_MIN_PERIOD_S, _MAX_PERIOD_S)  # no echo: again later
        return Request(self.preferred, False, part)

    def on_message(self, node_id: int, unique_id: bytes, now: float) -> None:
        """An Allocation message from an allocator (a node with an ID)."""
        if self.node_id is not None:
            return
        got = bytes(unique_id)
        if not got or self.unique_id[:len(got)] != got:
            if self._sent:
                self._restart(now)
            return
        if len(got) == 16 and node_id != 0:
            self.node_id = int(node_id)
            return
        self._sent = len(got)
        self._echo_at = now
        self._due = now + self._rng.uniform(_MIN_FOLLOWUP_S, _MAX_FOLLOWUP_S)

    def _restart(self, now: float) -> None:
        self._sent = 0
        self._echo_at = None
        self.restarts += 1
        self._due = now + self._rng.uniform(_MIN_PERIOD_S, _MAX_PERIOD_S)
