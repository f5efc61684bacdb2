"""What went wrong in one node: the shared record behind every launchable's ``failure()``.

Every node, driver, worker and recorder keeps one :class:`Faults` and reports to it instead of
only logging and counting. The launch runner asks each launchable for ``failure()`` while the
run goes and at its end (:func:`hil_bridge.launch.runner.judge`), so a failure that used to
be a log line and a counter now makes the run exit non-zero, naming the node and the place.

Contract:

1. ``report(where, exc)`` records an unrecoverable fault: ``failure()`` names it from then on.
2. ``report(where, exc, recoverable=True)`` records a fault the node declares it can recover
   from; ``recovered(where)`` clears it. One still pending when the node is asked for its
   ``failure()`` at the end of the run counts as a failure: a node that said it would recover
   and did not has failed.
3. Every report is logged once per place with its traceback (later repeats are counted, not
   logged), and counted in ``counts()`` by place.
4. Thread-safe; reporting never raises.

A thread whose body should never end by an exception is started on :meth:`Faults.guarded`
(``threading.Thread(target=faults.guarded("rx loop", self._rx_loop))``): what escapes it is
reported, not only printed by :func:`threading.excepthook` while the run goes on.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable
from dataclasses import dataclass

__all__ = ["Fault", "Faults"]

log = logging.getLogger(__name__)


@dataclass(frozen=True, slots=True)
class Fault:
    """One fault: the place it happened (``"callback /glider/0/cmd"``), what, and whether the
    node declared it recoverable."""

    where: str
    what: str
    recoverable: bool

    def __str__(self) -> str:
        return f"{self.where}: {self.what}"


def _describe(exc: BaseException | str) -> str:
    if isinstance(exc, BaseException):
        text = str(exc)
        return f"{type(exc).__name__}: {text}" if text else type(exc).__name__
    return str(exc)


class Faults:
    """The faults of the node called ``node`` (see the module docstring)."""

    def __init__(self, node: str) -> None:
        self.node = node
        self._lock = threading.Lock()
        self._fatal: list[Fault] = []
        self._pending: dict[str, Fault] = {}
        self._counts: dict[str, int] = {}

    def report(self, where: str, exc: BaseException | str, *, recoverable: bool = False) -> None:
        """Record a fault at ``where`` (logged with its traceback the first time per place)."""
        fault = Fault(where, _describe(exc), recoverable)
        with self._lock:
            first = where not in self._counts
            self._counts[where] = self._counts.get(where, 0) + 1
            if recoverable:
                self._pending[where] = fault
            elif len(self._fatal) < 16:
                self._fatal.append(fault)
        if first:
            kind = "recoverable fault" if recoverable else "failed"
            if isinstance(exc, BaseException):
                log.error("%s: %s %s", self.node, kind, fault, exc_info=exc)
            else:
                log.error("%s: %s %s", self.node, kind, fault)

    def recovered(self, where: str) -> None:
        """A recoverable fault at ``where`` is over (no-op when none is pending there)."""
        with self._lock:
            fault = self._pending.pop(where, None)
        if fault is not None:
            log.info("%s: recovered from %s", self.node, fault)

    def fatal(self) -> list[Fault]:
        """The unrecoverable faults so far (at most 16 kept)."""
        with self._lock:
            return list(self._fatal)

    def pending(self) -> list[Fault]:
        """Recoverable faults not yet recovered."""
        with self._lock:
            return list(self._pending.values())

    def failure(self, *, final: bool = False) -> str | None:
        """Why the node failed, or None: its first unrecoverable fault (and how many more);
        with ``final`` (the end of the run) also a recoverable fault that never recovered."""
        with self._lock:
            faults = list(self._fatal)
            if final:
                faults += [f for f in self._pending.values() if f not in faults]
        if not faults:
            return None
        more = f" (and {len(faults) - 1} more)" if len(faults) > 1 else ""
        suffix = " (declared recoverable, never recovered)" if faults[0].recoverable else ""
        return f"{faults[0]}{suffix}{more}"

    def counts(self) -> dict[str, int]:
        """Faults reported so far, by place."""
        with self._lock:
            return dict(self._counts)

    def guarded(self, where: str, body: Callable[[], object]) -> Callable[[], None]:
        """``body`` as a thread target: an exception escaping it is reported at ``where``
        (unrecoverable: the thread has ended) instead of vanishing with the thread."""

        def run() -> None:
            try:
                body()
            except Exception as exc:
                self.report(where, exc)

        return run
