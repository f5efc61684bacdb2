"""Serial fault injection without root or kernel modules: a frame-aware pty proxy.

:class:`FaultInjector` applies faults to a byte stream, one decision per frame (the bytes up to
and including each ``0x00``), from a seeded ``numpy`` Generator, so the same seed and the same
frames give the same faults whatever the read sizes were. Per frame, in this order:

* ``drop``: the frame vanishes;
* ``bit_flip``: one random bit of the frame (delimiter excluded) is inverted;
* ``truncate``: the frame is cut at a random point and its delimiter kept;
* ``garbage``: 1..``garbage_max`` random bytes are inserted before the frame;
* ``duplicate``: the (possibly damaged) frame is sent twice.

:class:`SerialFaultProxy` sits between a device (any URL or pty path, e.g. the mock head's)
and a new pty for the host, running one injector per direction. ``unplug()`` closes the host
pty and removes its symlink (the host's reads fail as when a USB adapter is pulled);
``replug()`` brings a fresh pty back under the same symlink. With ``unplug_every_s > 0`` it
does so on its own schedule. It is a launchable (``Cls(name, *, bus, **params)``); ``bus`` is
accepted for the launch contract only.
"""

from __future__ import annotations

import collections
import threading
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np

from drivers.serial.device_port import SerialDevicePort
from drivers.serial.ptyport import PtyPort
from hil_bridge.bus.faults import Faults
from sim_core.config import from_dict
from sim_core.rng import derive_rng

__all__ = ["FaultInjector", "SerialFaultProxy", "SerialFaults"]


@dataclass(frozen=True, slots=True)
class SerialFaults:
    """Per-frame fault probabilities (each in [0, 1]) and which directions they hit."""

    drop: float = 0.0
    bit_flip: float = 0.0
    truncate: float = 0.0
    garbage: float = 0.0
    duplicate: float = 0.0
    garbage_max: int = 32
    directions: Literal["both", "to_host", "to_device"] = "both"

    def __post_init__(self) -> None:
        for name in ("drop", "bit_flip", "truncate", "garbage", "duplicate"):
            p = getattr(self, name)
            if not 0.0 <= p <= 1.0:
                raise ValueError(f"fault probability {name}={p!r} must be in [0, 1]")
        if self.garbage_max < 1:
            raise ValueError(f"garbage_max {self.garbage_max!r} must be >= 1")


class FaultInjector:
    """Streaming per-frame fault injection (module docstring); ``process`` never raises."""

    def __init__(self, faults: SerialFaults, rng: np.random.Generator) -> None:
        self.faults = faults
        self.rng = rng
        self._buf = bytearray()
        self.counts = collections.Counter[str]()

    def process(self, data: bytes) -> bytes:
        """Bytes to forward for ``data``; an unterminated tail waits for its ``0x00``."""
        self._buf += data
        out = bytearray()
        while True:
            end = self._buf.find(0)
            if end < 0:
                break
            frame = bytes(self._buf[:end + 1])
            del self._buf[:end + 1]
            out += self._frame(frame)
        return bytes(out)

    def flush(self) -> bytes:
        """The buffered unterminated tail, unmodified (e.g. before an unplug)."""
        tail, self._buf = bytes(self._buf), bytearray()
        return tail

    def _frame(self, frame: bytes) -> bytes:
        f, rng = self.faults, self.rng
        self.counts["frames"] += 1
        draws = rng.random(5)
        if draws[0] < f.drop:
            self.counts["dropped"] += 1
            return b""
        body = bytearray(frame)
        if draws[1] < f.bit_flip and len(body) > 1:
            pos = int(rng.integers(0, len(body) - 1))
            body[pos] ^= 1 << int(rng.integers(0, 8))
            self.counts["bit_flips"] += 1
        if draws[2] < f.truncate and len(body) > 2:
            cut = int(rng.integers(1, len(body) - 1))
            body = body[:cut] + b"\x00"
            self.counts["truncated"] += 1
        if draws[3] < f.garbage:
            n = int(rng.integers(1, f.garbage_max + 1))
            body[:0] = rng.integers(0, 256, size=n, dtype=np.uint8).tobytes()
            self.counts["garbage"] += 1
        if draws[4] < f.duplicate:
            body.extend(bytes(body))
            self.counts["duplicated"] += 1
        return bytes(body)


class SerialFaultProxy:
    """Device <-> faults <-> host pty (module docstring). ``faults`` are the faults it injects;
    ``fault_record`` what went wrong in the proxy itself (a thread that died: ``failure()``)."""

    def __init__(
        self,
        name: str = "serial_faults",
        *,
        bus: str = "",
        upstream: str,
        link: str | None = None,
        baudrate: int = 921600,
        seed: int = 0,
        unplug_every_s: float = 0.0,
        unplug_for_s: float = 0.5,
        **faults: Any,
    ) -> None:
        self.name = name
        self.bus = bus
        self.faults = from_dict(SerialFaults, faults)
        if unplug_every_s < 0 or unplug_for_s <= 0:
            raise ValueError(f"unplug_every_s {unplug_every_s!r} must be >= 0 and unplug_for_s "
                             f"{unplug_for_s!r} > 0")
        self.upstream_url = upstream
        self.link = link
        self.baudrate = int(baudrate)
        self.seed = seed
        self.unplug_every_s = float(unplug_every_s)
        self.unplug_for_s = float(unplug_for_s)
        d = self.faults.directions
        none = SerialFaults()
        self.to_host = FaultInjector(self.faults if d in ("both", "to_host") else none,
                                     derive_rng(seed, "serial_proxy", "to_host"))
        self.to_device = FaultInjector(self.faults if d in ("both", "to_device") else none,
                                       derive_rng(seed, "serial_proxy", "to_device"))
        self.pty: PtyPort | None = None
        self._upstream: SerialDevicePort | None = None
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        self._started = False
        self._stopped = False
        self.unplugs = 0
        self.fault_record = Faults(name)

    @property
    def path(self) -> str:
        """What the host opens: the symlink if given, else the current pty slave path."""
        if self.pty is None:
            return self.link or ""
        return str(self.pty.link) if self.pty.link is not None else self.pty.path

    def start(self) -> None:
        if self._started:
            return
        self._started = True
        self._upstream = SerialDevicePort(self.upstream_url, self.baudrate)
        self.pty = PtyPort(self.link)
        loops = [(self._host_to_device, "down"), (self._device_to_host, "up")]
        if self.unplug_every_s > 0:
            loops.append((self._unplug_loop, "unplug"))
        for target, suffix in loops:
            t = threading.Thread(target=self.fault_record.guarded(f"{suffix} loop", target),
                                 name=f"{self.name}-{suffix}", daemon=True)
            self._threads.append(t)
            t.start()

    def stop(self) -> None:
        if self._stopped:
            return
        self._stopped = True
        self._stop.set()
        if self.pty is not None:
            self.pty.wake()
        if self._upstream is not None:
            self._upstream.wake()
        for t in self._threads:
            t.join(timeout=5.0)
        if self.pty is not None:
            self.pty.close()
        if self._upstream is not None:
            self._upstream.close()

    close = stop

    def __enter__(self) -> SerialFaultProxy:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def unplug(self) -> None:
        """Make the host-side device vanish (its symlink too)."""
        if self.pty is not None and self.pty.plugged:
            self.pty.unplug()
            self.to_host.flush()
            self.to_device.flush()
            self.unplugs += 1

    def replug(self) -> None:
        """Bring the host-side device back under the same symlink."""
        if self.pty is not None:
            self.pty.replug()

    def failure(self, *, final: bool = False) -> str | None:
        """Why the proxy failed (one of its threads ended by an exception), or None."""
        return self.fault_record.failure(final=final)

    def stats(self) -> dict[str, Any]:
        out: dict[str, Any] = {"unplugs": self.unplugs}
        out.update({f"to_host_{k}": v for k, v in dict(self.to_host.counts).items()})
        out.update({f"to_device_{k}": v for k, v in dict(self.to_device.counts).items()})
        return out

    def _host_to_device(self) -> None:
        pty, up = self.pty, self._upstream
        if pty is None or up is None:
            raise ValueError(f"{self.name}: not started")
        while not self._stop.is_set():
            data = pty.read(4096, 0.05)
            if data:
                out = self.to_device.process(data)
                if out:
                    up.write(out)

    def _device_to_host(self) -> None:
        pty, up = self.pty, self._upstream
        if pty is None or up is None:
            raise ValueError(f"{self.name}: not started")
        while not self._stop.is_set():
            data = up.read(4096, 0.05)
            if data:
                out = self.to_host.process(data)
                if out:
                    pty.write(out)

    def _unplug_loop(self) -> None:
        while not self._stop.wait(self.unplug_every_s):
            self.unplug()
            if self._stop.wait(self.unplug_for_s):
                return
            self.replug()
