"""The live recorder: every bus topic (or some) into an MCAP bag (:mod:`hil_bridge.recording.bag`
format, written by :class:`hil_bridge.recording.bag_writer.BagWriter`).

:class:`Recorder` is launchable-like (``start``, ``stop``, ``stats``, ``failure``); the launch
runner starts one for ``--record`` and ``echoloop bag record`` runs one alone.
"""

from __future__ import annotations

import logging
import struct
import threading
import time
from collections.abc import Iterable
from pathlib import Path
from typing import IO, Any

from mcap.well_known import MessageEncoding

from hil_bridge.bus.codec import decode_topic_header, encode, topic_frame, validate_topic
from hil_bridge.bus.domain import current as current_domain
from hil_bridge.bus.faults import Faults
from hil_bridge.bus.messages import Diagnostics
from hil_bridge.bus.transport import Transport, open_transport
from hil_bridge.errors import CodecError, HilError
from hil_bridge.outputs import AtomicOutput
from hil_bridge.recording.bag_writer import (
    COMPRESSIONS,
    MAX_CHANNELS,
    BagWriter,
    ChannelLimitError,
)

__all__ = ["Recorder"]

log = logging.getLogger(__name__)


class Recorder:
    """Record bus topics into an MCAP file; launchable: ``start()``, ``stop()``, ``stats()``,
    ``failure()``.

    ``Recorder(path, topics=None, *, bus=None, chunk_size=65536, flush_period_s=1.0,
    compression="zstd", overwrite=False, diagnostics_period_s=1.0)``; ``topics=None`` records
    every topic. The file is written as a temporary file beside ``path``
    (``.STEM.XXXX.part.mcap``) and renamed onto ``path`` by :meth:`stop` (an existing ``path``
    is refused unless ``overwrite``); a recorder killed without warning leaves the temporary
    file, readable to its last flushed chunk and repaired by ``echoloop bag recover``.

    A recorder never fails in silence: a write error (disk full, file size limit, I/O error) or
    the channel limit is reported to its :attr:`faults` (:mod:`hil_bridge.bus.faults`), so
    :meth:`failure` returns the place and the reason; it is logged at once, sent on
    ``/diagnostics`` (counter ``failed`` = 1) and ends in the run summary (non-zero exit of
    ``echoloop launch`` and ``bag record``); what arrives afterwards is counted
    (``lost_after_error``), and what was written stays readable. ``wait_for(n, timeout)``
    blocks until ``n`` messages are written (for tests and tools).
    """

    def __init__(
        self,
        path: str | Path,
        topics: Iterable[str] | None = None,
        *,
        bus: str | None = None,
        chunk_size: int = 64 * 1024,
        flush_period_s: float = 1.0,
        compression: str = "zstd",
        overwrite: bool = False,
        diagnostics_period_s: float = 1.0,
        max_channels: int = MAX_CHANNELS,
        name: str = "recorder",
    ) -> None:
        self.path = Path(path)
        self.topics = None if topics is None else [validate_topic(t) for t in topics]
        self.bus = bus if bus is not None else current_domain().bus_url
        self.name = name
        if not flush_period_s > 0:
            raise ValueError(f"flush_period_s must be > 0, got {flush_period_s}")
        if compression not in COMPRESSIONS:
            raise ValueError(
                f"unknown compression {compression!r}; expected one of {sorted(COMPRESSIONS)}"
            )
        if diagnostics_period_s < 0:
            raise ValueError(f"diagnostics_period_s must be >= 0, got {diagnostics_period_s}")
        self.chunk_size = chunk_size
        self.flush_period_s = flush_period_s
        self.compression = compression
        self.overwrite = overwrite
        self.diagnostics_period_s = diagnostics_period_s
        self.max_channels = max_channels
        self._output: AtomicOutput | None = None
        self._transport: Transport | None = None
        self._thread: threading.Thread | None = None
        self._stopping = threading.Event()
        self._cond = threading.Condition()
        self._lock = threading.Lock()
        self._stopped = False
        self._bag: BagWriter | None = None
        self._counters = {"messages": 0, "bytes": 0, "decode_errors": 0, "flushes": 0,
                          "lost_after_error": 0, "not_recorded": 0}
        self._diag_seq = 0
        #: what went wrong (write errors, the channel limit, the final rename)
        self.faults = Faults(name)

    def start(self) -> Recorder:
        """Open the file and the transport, subscribe, start the writer thread (idempotent)."""
        with self._lock:
            if self._thread is not None or self._stopped:
                return self
            output = AtomicOutput(self.path, overwrite=self.overwrite)
            transport = open_transport(self.bus)
            try:
                prefixes = [b""] if self.topics is None else [topic_frame(t) for t in self.topics]
                for prefix in prefixes:
                    transport.subscribe(prefix)
                stream = open(output.tmp, "wb")
            except BaseException:
                transport.close()
                output.discard()
                raise
            try:
                # the MCAP header is on disk before start() returns: the file is a readable
                # (empty) recording from then on, even if the process is killed
                bag = BagWriter(stream, chunk_size=self.chunk_size,
                                 compression=self.compression,
                                 message_encoding=MessageEncoding.MessagePack, as_json=False,
                                 max_channels=self.max_channels)
                stream.flush()
            except BaseException:
                stream.close()
                transport.close()
                output.discard()
                raise
            self._output, self._transport, self._bag = output, transport, bag
            self._thread = threading.Thread(
                target=self._run, args=(transport, stream, bag), name=f"{self.name}-rec",
                daemon=True,
            )
            self._thread.start()
        return self

    @property
    def error(self) -> str | None:
        """Why the recording is incomplete (its first failure, with the place), or None."""
        return self.faults.failure()

    def failure(self, *, final: bool = False) -> str | None:
        """Why the recording is incomplete (first failure), or None."""
        return self.faults.failure(final=final)

    def _fail(self, where: str, reason: str, transport: Transport) -> None:
        with self._cond:
            first = self.error is None
            self.faults.report(where, reason)  # logged, one line
            self._cond.notify_all()
        if first:
            self._publish_diagnostics(transport)

    def _publish_diagnostics(self, transport: Transport) -> None:
        if self.diagnostics_period_s <= 0:
            return
        counters = {k: v for k, v in self.stats().items()
                    if isinstance(v, int | float) and not isinstance(v, bool)}
        msg = Diagnostics(stamp_ns=time.monotonic_ns(), node=self.name, counters=counters)
        try:
            transport.publish(encode("/diagnostics", msg, seq=self._diag_seq,
                                     pub_ns=time.monotonic_ns(), src=f"{self.name}#recorder"))
            self._diag_seq += 1
        except HilError:
            log.debug("%s: diagnostics not sent", self.name, exc_info=True)

    def _run(self, transport: Transport, stream: IO[bytes], bag: BagWriter) -> None:
        # log_time: Unix-epoch ns that never steps back (wall anchor + monotonic offset)
        wall0, mono0 = time.time_ns(), time.monotonic_ns()
        dirty = False
        writing = True
        next_flush = time.monotonic() + self.flush_period_s
        next_diag = time.monotonic() + self.diagnostics_period_s
        try:
            while not self._stopping.is_set():
                frames = transport.recv(timeout=max(0.0, min(0.1, next_flush - time.monotonic())))
                if frames is not None:
                    recv_ns = wall0 + (time.monotonic_ns() - mono0)
                    try:
                        topic, header = decode_topic_header(frames)
                    except CodecError:
                        self._counters["decode_errors"] += 1
                        continue
                    payload = bytes(frames[2])
                    if not writing:
                        self._counters["lost_after_error"] += 1
                        continue
                    try:
                        bag.add(topic, header, payload, recv_ns)
                    except ChannelLimitError as exc:
                        self._counters["not_recorded"] += 1
                        self._fail("channels", str(exc), transport)
                        continue
                    dirty = True
                    with self._cond:
                        self._counters["messages"] += 1
                        self._counters["bytes"] += len(payload)
                        self._cond.notify_all()
                now = time.monotonic()
                if dirty and writing and now >= next_flush:
                    bag.writer.flush()
                    self._counters["flushes"] += 1
                    dirty = False
                if now >= next_flush:
                    next_flush = now + self.flush_period_s
                if self.diagnostics_period_s > 0 and now >= next_diag:
                    self._publish_diagnostics(transport)
                    next_diag = now + self.diagnostics_period_s
            if writing:
                bag.writer.finish()
        except (OSError, ValueError, struct.error) as exc:
            # disk full, a file size limit (EFBIG), an I/O error, or the writer's own limits
            writing = False
            self._fail(f"writing {self.path}", f"{type(exc).__name__}: {exc}", transport)
            self._drain_after_error(transport)
        except BaseException as exc:
            self._fail(f"writing {self.path}", f"{type(exc).__name__}: {exc}", transport)
            raise
        finally:
            try:
                stream.close()
            except OSError as exc:  # the last buffered bytes could not be written
                self._fail(f"closing {self.path}", f"{type(exc).__name__}: {exc}", transport)
            with self._cond:
                self._cond.notify_all()

    def _drain_after_error(self, transport: Transport) -> None:
        """After a write error: keep receiving until stopped, counting what is not recorded,
        and keep reporting on ``/diagnostics``."""
        next_diag = time.monotonic() + self.diagnostics_period_s
        while not self._stopping.is_set():
            if transport.recv(timeout=0.1) is not None:
                self._counters["lost_after_error"] += 1
            if self.diagnostics_period_s > 0 and time.monotonic() >= next_diag:
                self._publish_diagnostics(transport)
                next_diag = time.monotonic() + self.diagnostics_period_s

    def wait_for(self, n: int, timeout: float) -> bool:
        """True once ``n`` messages were recorded; False after ``timeout`` s or a failure."""
        with self._cond:
            return self._cond.wait_for(
                lambda: self._counters["messages"] >= n or self.error is not None, timeout
            ) and self._counters["messages"] >= n

    def stop(self) -> None:
        """Stop receiving, finish the file (summary + index), rename it onto ``path``, close
        everything. Idempotent. A file that could not be renamed (``path`` appeared meanwhile)
        stays at its temporary name, reported by :meth:`failure`."""
        with self._lock:
            if self._stopped:
                return
            self._stopped = True
            thread, transport, output = self._thread, self._transport, self._output
        self._stopping.set()
        if transport is not None:
            transport.wakeup()
        if thread is not None:
            thread.join()
        if output is not None:
            try:
                output.commit()
            except OSError as exc:
                self.faults.report(f"renaming onto {self.path}",
                                   f"{exc}; the recording is in {output.tmp}")
        if transport is not None:
            transport.close()

    def stats(self) -> dict[str, Any]:
        """Counters: ``messages``, ``bytes``, ``decode_errors``, ``flushes``, ``channels``,
        ``src_shared`` (messages recorded without their own ``src`` channel),
        ``not_recorded`` (channel limit), ``lost_after_error``, ``failed`` (0/1), plus
        ``path`` and ``error``."""
        with self._cond:
            out: dict[str, Any] = dict(self._counters)
            error = self.error
        bag = self._bag
        out["channels"] = len(bag.channels) if bag is not None else 0
        out["src_shared"] = bag.src_shared if bag is not None else 0
        out["failed"] = int(error is not None)
        out["error"] = error or ""
        out["path"] = str(self.path)
        return out
