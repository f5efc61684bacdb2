"""pyserial URL handler ``sonarsim://``: a mock sonar head (``MockSonarHead``) in-process.

``serial.serial_for_url("sonarsim://?seed=3&rate_hz=20&encoding=iq16")`` (once
:mod:`drivers.serial.link` is imported: it registers the handler package) returns a port whose
far end is a mock sonar head running on its own threads, so driver code is byte-identical
against the mock and a real head. Query options are
:class:`~drivers.mocks.sonar_head_config.SonarHeadConfig` fields (``rate_hz``, ``beamwidth``
(deg or ``random``), ``encoding``, ``channels``, ``seed``, ``throttle``, ...); ``baudrate``
defaults to the port's. An unknown option raises ``ValueError`` naming it.

The pipe between host and mock holds at most ``fifo`` bytes per direction (default 4096, like
a UART FIFO plus driver buffer); a host write blocks while the mock drains it at the baud rate.
"""

from __future__ import annotations

import dataclasses
import threading
import time
import urllib.parse
from typing import Any

from serial.serialutil import PortNotOpenError, SerialBase, SerialException, SerialTimeoutException

from drivers.mocks.sonar_head import MockSonarHead
from drivers.mocks.sonar_head_config import SonarHeadConfig

__all__ = ["BytePipe", "Serial", "parse_sonarsim_url"]

_FIELDS = {f.name: f.type for f in dataclasses.fields(SonarHeadConfig)}


def _value(text: str) -> Any:
    low = text.lower()
    if low in ("true", "false"):
        return low == "true"
    if low in ("none", "null"):
        return None
    for conv in (int, float):
        try:
            return conv(text)
        except ValueError:
            continue
    return text


def parse_sonarsim_url(url: str) -> dict[str, Any]:
    """Mock parameters from ``sonarsim://?k=v&...``; raises ValueError on unknown keys."""
    parts = urllib.parse.urlsplit(url)
    if parts.scheme.lower() != "sonarsim":
        raise ValueError(f"{url!r}: expected a URL of the form 'sonarsim://?key=value&...'")
    params: dict[str, Any] = {}
    for key, values in urllib.parse.parse_qs(parts.query, keep_blank_values=True).items():
        if key not in _FIELDS and key != "fifo":
            raise ValueError(f"sonarsim option {key!r} unknown; expected one of "
                             f"{sorted([*_FIELDS, 'fifo'])}")
        params[key] = _value(values[-1])
    return params


class _Fifo:
    """A bounded byte FIFO with blocking get/put and wake-up."""

    def __init__(self, capacity: int) -> None:
        self.capacity = capacity
        self.buf = bytearray()
        self.cv = threading.Condition()
        self.closed = False
        self.woken = False

    def put(self, data: bytes, timeout: float | None) -> int:
        view = memoryview(data)
        done = 0
        deadline = None if timeout is None else time.monotonic() + timeout
        with self.cv:
            while done < len(view):
                if self.closed:
                    return done
                room = self.capacity - len(self.buf)
                if room > 0:
                    take = min(room, len(view) - done)
                    self.buf += view[done:done + take]
                    done += take
                    self.cv.notify_all()
                    continue
                left = None if deadline is None else deadline - time.monotonic()
                if left is not None and left <= 0:
                    return done
                self.cv.wait(left)
        return done

    def get(self, max_bytes: int, timeout: float | None) -> bytes:
        with self.cv:
            self.cv.wait_for(lambda: self.buf or self.closed or self.woken, timeout)
            self.woken = False
            data = bytes(self.buf[:max_bytes])
            del self.buf[:max_bytes]
            if data:
                self.cv.notify_all()
            return data

    def wake(self) -> None:
        with self.cv:
            self.woken = True
            self.cv.notify_all()

    def close(self) -> None:
        with self.cv:
            self.closed = True
            self.cv.notify_all()


class BytePipe:
    """Two bounded FIFOs: host -> device and device -> host. ``device`` is the mock's port."""

    def __init__(self, capacity: int = 4096) -> None:
        self.to_device = _Fifo(capacity)
        self.to_host = _Fifo(capacity)
        self.device = _DeviceEnd(self)

    def close(self) -> None:
        self.to_device.close()
        self.to_host.close()


class _DeviceEnd:
    def __init__(self, pipe: BytePipe) -> None:
        self._pipe = pipe

    def read(self, max_bytes: int, timeout: float) -> bytes:
        return self._pipe.to_device.get(max_bytes, timeout)

    def write(self, data: bytes, timeout: float = 0.5) -> int:
        return self._pipe.to_host.put(data, timeout)

    def wake(self) -> None:
        self._pipe.to_device.wake()

    def close(self) -> None:
        self._pipe.close()


class Serial(SerialBase):
    """pyserial port whose far end is an in-process MockSonarHead."""

    is_open: bool

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        self._pipe: BytePipe | None = None
        self.mock: MockSonarHead | None = None
        super().__init__(*args, **kwargs)

    def open(self) -> None:
        if self.is_open:
            raise SerialException("Port is already open.")
        if self._port is None:
            raise SerialException("Port must be configured before it can be used.")
        params = parse_sonarsim_url(self._port)
        fifo = int(params.pop("fifo", 4096))
        if fifo <= 0:
            raise ValueError(f"sonarsim option fifo={fifo!r} must be > 0")
        params.setdefault("baudrate", int(self._baudrate))
        self._pipe = BytePipe(fifo)
        self.mock = MockSonarHead("sonarsim", device=self._pipe.device, **params)
        self.mock.start()
        self.is_open = True

    def close(self) -> None:
        if self.is_open:
            self.is_open = False
            if self.mock is not None:
                self.mock.stop()
            if self._pipe is not None:
                self._pipe.close()
        super().close()

    def _reconfigure_port(self) -> None:
        if not isinstance(self._baudrate, int) or not 0 < self._baudrate < 2**32:
            raise ValueError(f"invalid baudrate: {self._baudrate!r}")

    def _pipe_or_raise(self) -> BytePipe:
        if not self.is_open or self._pipe is None:
            raise PortNotOpenError()
        return self._pipe

    @property
    def in_waiting(self) -> int:
        return len(self._pipe_or_raise().to_host.buf)

    def read(self, size: int = 1) -> bytes:
        pipe = self._pipe_or_raise()
        timeout = self._timeout
        deadline = None if timeout is None else time.monotonic() + timeout
        out = bytearray()
        while len(out) < size:
            left = None if deadline is None else max(0.0, deadline - time.monotonic())
            data = pipe.to_host.get(size - len(out), left)
            if not data:
                break
            out += data
        return bytes(out)

    def write(self, data: bytes) -> int:
        pipe = self._pipe_or_raise()
        data = bytes(data)
        n = pipe.to_device.put(data, self._write_timeout)
        if n < len(data):
            if pipe.to_device.closed:
                raise SerialException("sonarsim: port closed")
            raise SerialTimeoutException("Write timeout")
        return n

    def cancel_read(self) -> None:
        if self._pipe is not None:
            self._pipe.to_host.wake()

    def reset_input_buffer(self) -> None:
        pipe = self._pipe_or_raise()
        with pipe.to_host.cv:
            pipe.to_host.buf.clear()
            pipe.to_host.cv.notify_all()

    def reset_output_buffer(self) -> None:
        pipe = self._pipe_or_raise()
        with pipe.to_device.cv:
            pipe.to_device.buf.clear()
            pipe.to_device.cv.notify_all()

    @property
    def out_waiting(self) -> int:
        return len(self._pipe_or_raise().to_device.buf)

    def _update_break_state(self) -> None:
        self._pipe_or_raise()

    def _update_rts_state(self) -> None:
        self._pipe_or_raise()

    def _update_dtr_state(self) -> None:
        self._pipe_or_raise()

    @property
    def cts(self) -> bool:
        self._pipe_or_raise()
        return True

    @property
    def dsr(self) -> bool:
        self._pipe_or_raise()
        return True

    @property
    def ri(self) -> bool:
        self._pipe_or_raise()
        return False

    @property
    def cd(self) -> bool:
        self._pipe_or_raise()
        return True
