"""The device end of a serial link, as a program playing the device uses it (the mock sonar head,
the fault proxy's upstream side).

:class:`DevicePort` is what such a program needs of its port (read with a timeout, write, wake a
blocked read, close); a :class:`drivers.serial.ptyport.PtyPort` is one, and
:class:`SerialDevicePort` makes one of any pyserial URL or device (re-opened with back-off when
it fails). :class:`UartPacer` paces one direction to a baud rate: ptys and pipes move bytes at
once, a UART does not, so a mock paced by it shows the latencies of the real link.
"""

from __future__ import annotations

import threading
import time
from typing import Any, Protocol

import serial

from drivers.serial.link import PORT_ERRORS, check_url

__all__ = ["DevicePort", "SerialDevicePort", "UartPacer"]


class DevicePort(Protocol):
    """The device side of a serial link as a device program uses it."""

    def read(self, max_bytes: int, timeout: float) -> bytes: ...

    def write(self, data: bytes, timeout: float = 0.5) -> int: ...

    def wake(self) -> None: ...

    def close(self) -> None: ...


class SerialDevicePort:
    """A pyserial URL/device used as the device side; re-opened with back-off when it fails."""

    def __init__(self, url: str, baudrate: int) -> None:
        self.url = check_url(url)
        self.baudrate = baudrate
        self._ser: Any = serial.serial_for_url(url, baudrate=baudrate, timeout=0.05)
        self._lock = threading.Lock()
        self._closed = False
        self._retry_at = 0.0
        self.errors = 0

    def _port(self) -> Any:
        with self._lock:
            if self._closed:
                return None
            if self._ser is None and time.monotonic() >= self._retry_at:
                try:
                    self._ser = serial.serial_for_url(self.url, baudrate=self.baudrate,
                                                      timeout=0.05)
                except (OSError, ValueError):
                    self._retry_at = time.monotonic() + 0.2
            return self._ser

    def _fail(self, ser: Any) -> None:
        self.errors += 1
        with self._lock:
            if self._ser is ser and ser is not None:
                ser.close()
                self._ser = None
                self._retry_at = time.monotonic() + 0.2

    def read(self, max_bytes: int, timeout: float) -> bytes:
        ser = self._port()
        if ser is None:
            time.sleep(min(timeout, 0.05))  # nothing to wait on while the device is away
            return b""
        try:
            data: bytes = ser.read(max(1, min(max_bytes, ser.in_waiting or 1)))
        except PORT_ERRORS:
            self._fail(ser)
            return b""
        return data

    def write(self, data: bytes, timeout: float = 0.5) -> int:
        ser = self._port()
        if ser is None:
            return 0
        try:
            n = ser.write(data)
        except PORT_ERRORS:
            self._fail(ser)
            return 0
        return len(data) if n is None else int(n)

    def wake(self) -> None:
        ser = self._ser
        if ser is not None and hasattr(ser, "cancel_read"):
            ser.cancel_read()

    def close(self) -> None:
        with self._lock:
            self._closed = True
            if self._ser is not None:
                self._ser.close()
                self._ser = None


class UartPacer:
    """Pacing of one direction at ``baudrate`` (10 bit times per byte)."""

    def __init__(self, baudrate: int, enabled: bool) -> None:
        self.byte_s = 10.0 / baudrate
        self.enabled = enabled
        self.free_at = 0.0

    def done_at(self, n: int, now: float) -> float:
        """When ``n`` bytes starting no earlier than ``now`` have crossed the wire."""
        if not self.enabled:
            return now
        self.free_at = max(now, self.free_at) + n * self.byte_s
        return self.free_at
