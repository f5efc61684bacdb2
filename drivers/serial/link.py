"""Serial links from a URL: a reader and a writer thread, reconnect with back-off, raw capture.

``open_link(url)`` accepts everything pyserial's ``serial_for_url`` does — a device path
(``/dev/ttyUSB0``, a pty slave or a symlink to one), ``loop://``, ``socket://host:port``,
``rfc2217://...`` — plus ``sonarsim://?...`` (an in-process mock sonar head). The framing layer
above never knows which.

:class:`Link` contract:

1. ``start()`` returns at once; the reader thread opens the port and keeps it open. When the
   port fails (unplugged device, closed pty, reset socket) the link closes it and re-opens it
   with exponential back-off (``backoff_initial_s`` doubling to ``backoff_max_s``); each
   successful re-open counts in ``reconnects``. The drop is reported to the link's ``faults``
   as a recoverable fault and the re-open as its recovery (:mod:`hil_bridge.bus.faults`), so a
   port that dropped and never came back fails the run it was in. A ``ValueError`` on open
   (bad URL option or baud rate) is a configuration error: the link sets ``failed`` and stops
   trying.
2. ``send(data)`` never blocks: it queues the bytes for the writer thread (bounded by
   ``tx_queue_bytes``; overflow and bytes sent while disconnected are dropped and counted).
3. Received bytes go to ``on_bytes(data)`` on the reader thread; an exception raised by the
   callback is counted (``callback_errors``) and reported to ``faults`` (unrecoverable: a bug
   of the link's owner), never ends the thread.
4. With ``capture=PREFIX`` every byte read goes to ``PREFIX.rx.bin`` and every byte written to
   ``PREFIX.tx.bin``, byte-exact and in order, across reconnects; ``PREFIX.index.tsv`` has one
   line per read/write/open/close with a monotonic timestamp (format in docs/serial.md).
   Existing capture files are refused at construction unless ``overwrite``; the files appear
   (renamed from temporary files) when the link stops.
5. ``stop()`` is idempotent, joins both threads and closes the port and capture files.
6. :meth:`Link.report` says whether the port was ever open and its state when the link stopped
   (the run summary's ``links``, :func:`hil_bridge.launch.runner.collect_links`).
"""

from __future__ import annotations

import collections
import logging
import threading
import time
import urllib.parse
from collections.abc import Callable
from pathlib import Path
from typing import Any, BinaryIO, TextIO

import serial

from hil_bridge.bus.faults import Faults
from hil_bridge.errors import TransportTimeout
from hil_bridge.outputs import AtomicOutput, check_output

__all__ = ["KNOWN_SCHEMES", "PORT_ERRORS", "URL_HANDLERS", "Capture", "Link", "capture_paths",
           "check_capture", "check_url", "open_link"]

log = logging.getLogger(__name__)

#: echoloop's own URL schemes -> the package holding each one's pyserial handler module
#: ``protocol_<scheme>``. pyserial imports that module by name when a URL of the scheme is opened,
#: so the handler (a device mock) is never imported by the host side until it is used.
URL_HANDLERS = {"sonarsim": "drivers.urlhandlers"}


def _register_url_handlers() -> None:
    """Put the packages of :data:`URL_HANDLERS` on pyserial's search list (idempotent)."""
    for package in URL_HANDLERS.values():
        if package not in serial.protocol_handler_packages:
            serial.protocol_handler_packages.append(package)


_register_url_handlers()

try:
    import termios

    _TERMIOS_ERRORS: tuple[type[Exception], ...] = (termios.error,)
except ImportError:  # not a POSIX system
    _TERMIOS_ERRORS = ()

#: what a port closed or yanked under a read/write may raise (pyserial, termios, the OS)
PORT_ERRORS: tuple[type[Exception], ...] = (
    OSError, ValueError, TypeError, AttributeError, *_TERMIOS_ERRORS)

#: URL schemes pyserial ships plus ours; a path without ``scheme://`` is an OS serial device.
KNOWN_SCHEMES = frozenset({"loop", "socket", "rfc2217", "spy", "alt", "hwgrep", "cp2110",
                           *URL_HANDLERS})


def check_url(url: str) -> str:
    """Return ``url`` or raise ValueError when its scheme is not one :func:`open_link` knows."""
    if not isinstance(url, str) or not url:
        raise ValueError(f"serial port {url!r}: expected a device path or a URL")
    if "://" in url:
        scheme = urllib.parse.urlsplit(url).scheme.lower()
        if scheme not in KNOWN_SCHEMES:
            raise ValueError(
                f"serial URL scheme {scheme!r} unknown; expected a device path or one of "
                f"{sorted(KNOWN_SCHEMES)}"
            )
    return url


def capture_paths(prefix: str | Path) -> tuple[Path, Path, Path]:
    """The three files of a capture: ``PREFIX.rx.bin``, ``PREFIX.tx.bin``, ``PREFIX.index.tsv``."""
    prefix = Path(prefix)
    return (prefix.with_name(prefix.name + ".rx.bin"), prefix.with_name(prefix.name + ".tx.bin"),
            prefix.with_name(prefix.name + ".index.tsv"))


def check_capture(prefix: str | Path, *, overwrite: bool = False) -> None:
    """Refuse a capture whose files exist (unless ``overwrite``), before anything is opened."""
    for path in capture_paths(prefix):
        check_output(path, overwrite=overwrite)


class Capture:
    """Byte-exact capture of both directions of a link (see docs/serial.md for the format).

    The three files are written through temporary files renamed at :meth:`close`
    (:class:`~hil_bridge.outputs.AtomicOutput`); existing ones are refused unless
    ``overwrite``."""

    def __init__(self, prefix: str | Path, url: str, *, overwrite: bool = False) -> None:
        check_capture(prefix, overwrite=overwrite)
        self.rx_path, self.tx_path, self.index_path = capture_paths(prefix)
        self._outputs: list[AtomicOutput] = []
        try:
            for path in (self.rx_path, self.tx_path, self.index_path):
                self._outputs.append(AtomicOutput(path, overwrite=overwrite))
        except BaseException:
            for out in self._outputs:
                out.discard()
            raise
        rx, tx, index = (out.tmp for out in self._outputs)
        self._lock = threading.Lock()
        self._rx: BinaryIO = open(rx, "wb")
        self._tx: BinaryIO = open(tx, "wb")
        self._index: TextIO = open(index, "w", encoding="utf-8")
        self._offsets = {"rx": 0, "tx": 0}
        self._index.write(
            f"# echoloop serial capture v1 url={url} start_unix_ns={time.time_ns()} "
            f"start_mono_ns={time.monotonic_ns()}\n"
            "# mono_ns\tkind\toffset\tlength\n"
        )

    def data(self, kind: str, data: bytes) -> None:
        """Append ``data`` read (``kind="rx"``) or written (``"tx"``)."""
        with self._lock:
            if self._index.closed:
                return
            (self._rx if kind == "rx" else self._tx).write(data)
            offset = self._offsets[kind]
            self._offsets[kind] = offset + len(data)
            self._index.write(f"{time.monotonic_ns()}\t{kind}\t{offset}\t{len(data)}\n")

    def event(self, kind: str) -> None:
        """Record an ``open`` or ``close`` of the port."""
        with self._lock:
            if not self._index.closed:
                self._index.write(
                    f"{time.monotonic_ns()}\t{kind}\t{self._offsets['rx']}\t{self._offsets['tx']}\n"
                )

    def close(self) -> None:
        """Close the files and rename them into place (idempotent)."""
        with self._lock:
            for f in (self._rx, self._tx, self._index):
                f.close()
            for out in self._outputs:
                out.commit()


class Link:
    """A reconnecting serial link (contract in the module docstring); ``faults`` is its owner's
    :class:`~hil_bridge.bus.faults.Faults` (default a record of its own, named ``name``)."""

    def __init__(
        self,
        url: str,
        *,
        baudrate: int = 921600,
        on_bytes: Callable[[bytes], None] | None = None,
        on_connect: Callable[[], None] | None = None,
        on_disconnect: Callable[[], None] | None = None,
        capture: str | Path | None = None,
        overwrite: bool = False,
        backoff_initial_s: float = 0.05,
        backoff_max_s: float = 2.0,
        read_timeout_s: float = 0.05,
        tx_queue_bytes: int = 1 << 20,
        name: str = "link",
        faults: Faults | None = None,
    ) -> None:
        self.url = check_url(url)
        if capture is not None:
            check_capture(capture, overwrite=overwrite)
        self._overwrite = overwrite
        if int(baudrate) <= 0:
            raise ValueError(f"baudrate {baudrate!r} must be a positive integer")
        if not 0 < backoff_initial_s <= backoff_max_s:
            raise ValueError(
                f"backoff_initial_s {backoff_initial_s!r} must be > 0 and <= backoff_max_s "
                f"{backoff_max_s!r}"
            )
        self.baudrate = int(baudrate)
        self.name = name
        self.faults = faults if faults is not None else Faults(name)
        #: where a drop of this port is reported (recoverable) and its re-open recovers it
        self.fault_place = f"serial link {self.url}"
        self._on_bytes = on_bytes
        self._on_connect = on_connect
        self._on_disconnect = on_disconnect
        self._capture_prefix = capture
        self.capture: Capture | None = None
        self._backoff = (float(backoff_initial_s), float(backoff_max_s))
        self._read_timeout = float(read_timeout_s)
        self._tx_limit = int(tx_queue_bytes)
        self._ser: Any = None
        self._stop = threading.Event()
        self._connected = threading.Event()
        self._state_cv = threading.Condition()
        self._tx_cv = threading.Condition()
        self._tx_queue: collections.deque[bytes] = collections.deque()
        self._tx_queued = 0
        self._threads: list[threading.Thread] = []
        self._started = False
        self._stopped = False
        self.last_error: BaseException | None = None
        #: True after a configuration error (ValueError) on open: the link gave up
        self.failed = False
        self.bytes_rx = 0
        self.bytes_tx = 0
        self.opens = 0
        self.open_failures = 0
        self.read_errors = 0
        self.write_errors = 0
        self.tx_dropped_bytes = 0
        self.callback_errors = 0
        self._connected_at_stop = False

    # ---- lifecycle -------------------------------------------------------------------------

    def start(self) -> Link:
        """Start the reader/writer threads (non-blocking); returns self."""
        if self._started:
            return self
        self._started = True
        if self._capture_prefix is not None:
            self.capture = Capture(self._capture_prefix, self.url, overwrite=self._overwrite)
        for target, suffix in ((self._read_loop, "rx"), (self._write_loop, "tx")):
            t = threading.Thread(target=target, name=f"{self.name}-{suffix}", daemon=True)
            self._threads.append(t)
            t.start()
        return self

    def stop(self) -> None:
        """Stop both threads, close the port and capture files (idempotent)."""
        if self._stopped:
            return
        self._stopped = True
        self._stop.set()
        with self._tx_cv:
            self._tx_cv.notify_all()
        ser = self._ser
        if ser is not None and hasattr(ser, "cancel_read"):
            try:
                ser.cancel_read()
            except (OSError, ValueError, TypeError):
                log.debug("%s: cancel_read failed", self.name, exc_info=True)
        for t in self._threads:
            t.join(timeout=5.0)
        self._connected_at_stop = self.connected
        self._close_port()
        if self.capture is not None:
            self.capture.close()

    close = stop

    def __enter__(self) -> Link:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    @property
    def connected(self) -> bool:
        return self._connected.is_set()

    @property
    def port(self) -> Any:
        """The open pyserial port object (None while disconnected)."""
        return self._ser

    @property
    def reconnects(self) -> int:
        """Successful re-opens after the first open."""
        return max(0, self.opens - 1)

    def wait_connected(self, timeout: float) -> bool:
        """Block until the port is open (True) or ``timeout`` seconds pass (False)."""
        return self._connected.wait(timeout)

    def wait_for(self, predicate: Callable[[Link], bool], timeout: float) -> bool:
        """Block until ``predicate(link)`` holds after an open/close (or now); False on timeout."""
        with self._state_cv:
            return self._state_cv.wait_for(lambda: predicate(self), timeout)

    def _notify_state(self) -> None:
        with self._state_cv:
            self._state_cv.notify_all()

    def report(self) -> dict[str, Any]:
        """``{"kind": "serial", "target", "connected" (ever), "state" (now, or when stopped),
        "reconnects", "error" (the last open/read/write error)}``."""
        now = self._connected_at_stop if self._stopped else self.connected
        return {
            "kind": "serial", "target": self.url, "connected": self.opens > 0,
            "state": "connected" if now else ("failed" if self.failed else "disconnected"),
            "reconnects": self.reconnects,
            "error": "" if self.last_error is None else str(self.last_error),
        }

    def stats(self) -> dict[str, int | bool]:
        return {
            "connected": self.connected,
            "bytes_rx": self.bytes_rx,
            "bytes_tx": self.bytes_tx,
            "reconnects": self.reconnects,
            "open_failures": self.open_failures,
            "read_errors": self.read_errors,
            "write_errors": self.write_errors,
            "tx_dropped_bytes": self.tx_dropped_bytes,
            "callback_errors": self.callback_errors,
        }

    # ---- sending ---------------------------------------------------------------------------

    def send(self, data: bytes) -> bool:
        """Queue ``data`` for writing; False (and counted) if dropped."""
        if not data:
            return True
        with self._tx_cv:
            if self._stop.is_set() or not self._connected.is_set() or (
                self._tx_queued + len(data) > self._tx_limit
            ):
                self.tx_dropped_bytes += len(data)
                return False
            self._tx_queue.append(bytes(data))
            self._tx_queued += len(data)
            self._tx_cv.notify()
        return True

    def tx_pending(self) -> int:
        """Bytes queued but not yet written."""
        with self._tx_cv:
            return self._tx_queued

    def _write_loop(self) -> None:
        while True:
            with self._tx_cv:
                while not self._tx_queue and not self._stop.is_set():
                    self._tx_cv.wait()
                if self._stop.is_set():
                    return
                data = self._tx_queue.popleft()
                self._tx_queued -= len(data)
            ser = self._ser
            if ser is None:
                with self._tx_cv:
                    self.tx_dropped_bytes += len(data)
                continue
            try:
                n = ser.write(data)
            except PORT_ERRORS as exc:
                # a port closed under us (unplug) or by the reader's reconnect
                with self._tx_cv:
                    self.write_errors += 1
                    self.tx_dropped_bytes += len(data)
                self.last_error = exc
                continue
            written = len(data) if n is None else int(n)
            self.bytes_tx += written
            if self.capture is not None:
                self.capture.data("tx", data[:written])

    # ---- receiving -------------------------------------------------------------------------

    def _open_port(self) -> bool:
        try:
            ser = serial.serial_for_url(self.url, baudrate=self.baudrate,
                                        timeout=self._read_timeout, write_timeout=2.0)
        except OSError as exc:  # SerialException: absent or busy device, refused socket
            self.open_failures += 1
            self.last_error = exc
            return False
        except ValueError as exc:  # a bad URL option or baud rate: retrying cannot help
            self.open_failures += 1
            self.last_error = exc
            self.failed = True
            log.error("%s: cannot open %s: %s", self.name, self.url, exc)
            self._notify_state()
            return False
        self._ser = ser
        self.opens += 1
        if self.opens > 1:  # before anyone can see it connected: a re-open is the recovery
            self.faults.recovered(self.fault_place)
        if self.capture is not None:
            self.capture.event("open")
        self._connected.set()
        self._notify_state()
        if self.opens > 1:
            log.info("%s: %s re-opened (reconnect %d)", self.name, self.url, self.reconnects)
        self._call(self._on_connect)
        return True

    def _close_port(self) -> None:
        ser, self._ser = self._ser, None
        was_connected = self._connected.is_set()
        self._connected.clear()
        with self._tx_cv:
            self.tx_dropped_bytes += self._tx_queued
            self._tx_queue.clear()
            self._tx_queued = 0
        if ser is not None:
            try:
                ser.close()
            except (OSError, ValueError):
                log.debug("%s: close failed", self.name, exc_info=True)
            if self.capture is not None:
                self.capture.event("close")
        self._notify_state()
        if was_connected:
            self._call(self._on_disconnect)

    def _call(self, fn: Callable[..., None] | None, *args: Any) -> None:
        """Run a user callback; what it raises is counted (``callback_errors``) and logged."""
        if fn is None:
            return
        try:
            fn(*args)
        except Exception as exc:
            self.callback_errors += 1
            self.faults.report(f"link callback {getattr(fn, '__name__', fn)}", exc)

    def _read_loop(self) -> None:
        delay = self._backoff[0]
        warned = False
        while not self._stop.is_set() and not self.failed:
            if self._ser is None:
                if self._open_port():
                    delay = self._backoff[0]
                    warned = False
                    continue
                if not warned:
                    log.warning("%s: cannot open %s (%s); retrying with back-off",
                                self.name, self.url, self.last_error)
                    warned = True
                self._stop.wait(delay)
                delay = min(delay * 2.0, self._backoff[1])
                continue
            ser = self._ser
            try:
                waiting = ser.in_waiting
                data = ser.read(min(max(1, waiting), 65536))
            except PORT_ERRORS as exc:
                if self._stop.is_set():
                    break
                self.read_errors += 1
                self.last_error = exc
                self.faults.report(self.fault_place, exc, recoverable=True)  # reconnecting
                self._close_port()
                continue
            if not data:
                continue
            self.bytes_rx += len(data)
            if self.capture is not None:
                self.capture.data("rx", data)
            self._call(self._on_bytes, data)


def open_link(url: str, *, connect_timeout_s: float = 5.0, **kwargs: Any) -> Link:
    """Start a :class:`Link` on ``url`` and wait until the port is open.

    Raises the last open error (an ``OSError``/``ValueError``) or :class:`TransportTimeout`
    when the port cannot be opened within ``connect_timeout_s``; other keywords go to
    :class:`Link`.
    """
    link = Link(url, **kwargs).start()
    if link.wait_for(lambda lk: lk.connected or lk.failed, connect_timeout_s) and link.connected:
        return link
    link.stop()
    err = link.last_error
    if isinstance(err, (OSError, ValueError)):
        raise err
    raise TransportTimeout(f"serial port {url!r} not open after {connect_timeout_s} s")
