"""One end of the CAN glider profile: a :class:`~drivers.can.bus.CanLink` and its two threads.

The bridge (:class:`drivers.can.adapter.AutopilotAdapter`) and the autopilot emulator
(:class:`drivers.mocks.autopilot.MockAutopilot`) run the same machinery around their link,
:class:`CanEndpoint`:

* a receive thread decodes every frame the link delivers and hands it to the owner's
  ``handle``; a frame that does not decode is counted (``rx_decode_errors``) and dropped;
* a transmit thread runs the owner's periodic tasks ``(period_s, task(now))`` in order, each
  when it is due (``now``: monotonic seconds); a task that fell more than a period behind is due
  again at once and then every period: the periods it missed are not made up;
* an exception raised by ``handle`` or a task is counted (``loop_errors``) and reported to the
  owner's ``faults`` naming the frame or the cycle, and the loop goes on; anything that ends a
  thread is reported naming the loop (:meth:`~hil_bridge.bus.faults.Faults.guarded`).

Counts go through the owner's ``count(key)``, so they sit with the owner's own counters.
:meth:`CanEndpoint.stats` holds the link's counters (``can_*``), its report (``links``) and the
codec's saturation totals (``saturated_tx``, ``saturated_rx``).
"""

from __future__ import annotations

import functools
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

from drivers.can.bus import CanBusConfig, CanLink
from drivers.can.codec import DecodedFrame, GliderCanCodec
from hil_bridge.bus.faults import Faults
from hil_bridge.errors import CodecError

__all__ = ["CanEndpoint", "Task"]

#: A periodic task of the transmit thread: (period in s, task(now in monotonic s)).
Task = tuple[float, Callable[[float], None]]

_RX_WAIT_S = 0.05


class CanEndpoint:
    """The CAN side of one node of the profile (see the module docstring).

    ``name`` prefixes the thread names, ``loop_prefix`` the loop names reported when a thread
    ends (``<loop_prefix>rx loop``, ``<loop_prefix>tx loop``). ``log_path`` is the link's
    candump log (``overwrite`` replaces an existing one).
    """

    def __init__(
        self,
        name: str,
        config: CanBusConfig,
        *,
        faults: Faults,
        count: Callable[[str], None],
        log_path: str | Path | None = None,
        overwrite: bool = False,
        loop_prefix: str = "",
    ) -> None:
        self.name = name
        self.config = config
        self.codec = GliderCanCodec()
        self.faults = faults
        self.link: CanLink | None = None
        self.threads: list[threading.Thread] = []
        self._count = count
        self._log_path = log_path
        self._overwrite = overwrite
        self._loop_prefix = loop_prefix
        self._stop = threading.Event()

    def open(self) -> bool:
        """Open the link; False (nothing done) when it was opened before or the endpoint
        stopped."""
        if self.link is not None or self._stop.is_set():
            return False
        self.link = CanLink(self.config, log_path=self._log_path, stop_event=self._stop,
                            overwrite=self._overwrite)
        return True

    def run(
        self,
        handle: Callable[[DecodedFrame], None],
        tasks: Sequence[Task],
        *,
        rx_place: str,
        tx_place: str,
    ) -> None:
        """Start the receive and transmit threads (after :meth:`open`). An error of ``handle``
        is reported as ``<rx_place> <frame name>``, one of a task as ``tx_place``."""
        if not tasks:
            raise ValueError("tasks: expected at least one (period_s, task)")
        loops = (("rx", functools.partial(self._rx_loop, handle, rx_place)),
                 ("tx", functools.partial(self._tx_loop, tasks, tx_place)))
        for suffix, loop in loops:
            name = f"{self._loop_prefix}{suffix}"
            t = threading.Thread(target=self.faults.guarded(f"{name} loop", loop),
                                 name=f"{self.name}-{name}", daemon=True)
            t.start()
            self.threads.append(t)

    def stop(self) -> None:
        """Stop the threads and close the link, flushing its log (idempotent)."""
        self._stop.set()
        for t in self.threads:
            t.join(timeout=5.0)
        self.threads.clear()
        if self.link is not None:
            self.link.close()

    def send(self, name: str, node: int, values: Mapping[str, float]) -> bool:
        """Encode and send one frame; False when the link is not open or dropped it. A value
        the codec refuses raises its ValueError."""
        link = self.link
        if link is None:
            return False
        return link.send(self.codec.encode(name, node, values))

    def stats(self) -> dict[str, Any]:
        """``can_<counter>`` and ``can_state`` of the link, ``links`` (its report) once opened;
        ``saturated_tx`` / ``saturated_rx`` (values the codec clipped)."""
        out: dict[str, Any] = {}
        if self.link is not None:
            out.update({f"can_{k}": v for k, v in self.link.stats().items()})
            out["links"] = {"can": self.link.report()}
        sat = self.codec.saturation_counts()
        out["saturated_tx"] = sum(sat["tx"].values())
        out["saturated_rx"] = sum(sat["rx"].values())
        return out

    def _rx_loop(self, handle: Callable[[DecodedFrame], None], place: str) -> None:
        link = self.link
        if link is None:
            return
        while not self._stop.is_set():
            msg = link.recv(_RX_WAIT_S)
            if msg is None:
                continue
            try:
                frame = self.codec.decode(msg)
            except CodecError:
                self._count("rx_decode_errors")
                continue
            try:
                handle(frame)
            except Exception as exc:
                self._count("loop_errors")
                self.faults.report(f"{place} {frame.name}", exc)

    def _tx_loop(self, tasks: Sequence[Task], place: str) -> None:
        due = [time.monotonic()] * len(tasks)
        while not self._stop.is_set():
            now = time.monotonic()
            try:
                for i, (period, task) in enumerate(tasks):
                    if now >= due[i]:
                        due[i] = max(due[i] + period, now)
                        task(now)
            except Exception as exc:
                self._count("loop_errors")
                self.faults.report(place, exc)
            self._stop.wait(max(0.0, min(due) - time.monotonic()))
