"""The device end of a pseudo-terminal, for mocks and the fault proxy (no root needed).

:class:`PtyPort` holds the master side of ``os.openpty()``; the host opens the slave path — or
the stable symlink ``link`` pointing at it — exactly as it would open ``/dev/ttyUSB0``. The
slave is put in raw mode and kept open by the port itself, so bytes written before the host
opens it are buffered (pyserial flushes them on open) and the host may close and re-open it.

``unplug()`` closes both sides and removes the symlink: the host's reads fail the way they do
when a USB adapter is pulled. ``replug()`` creates a new pty and points the symlink at it.

The symlink never replaces a file that is not a symlink, nor one another live port owns (two
runs in one domain: ownership is a lock held beside the link,
:func:`hil_bridge.bus.domain.hold_link`, released when the port closes or its process dies); a
symlink left by a killed run is replaced,
even when its pty number has since been given to another program.
"""

from __future__ import annotations

import contextlib
import errno
import os
import select
import threading
import tty
from pathlib import Path

from hil_bridge.bus.domain import hold_link

__all__ = ["PtyPort"]


class PtyPort:
    """Master side of a pty with an optional stable symlink to its slave (see module doc)."""

    def __init__(self, link: str | Path | None = None) -> None:
        self.link = Path(link) if link is not None else None
        if self.link is not None:
            if self.link.exists() and not self.link.is_symlink():
                raise ValueError(f"link {str(self.link)!r} exists and is not a symlink; refusing "
                                 "to replace it")
        self._owner = -1 if self.link is None else hold_link(self.link)
        self._lock = threading.Lock()
        self._master = -1
        self._slave = -1
        self._gen = 0
        self.path = ""
        self._wake_r, self._wake_w = os.pipe()
        os.set_blocking(self._wake_r, False)
        self._closed = False
        self.replug()

    @property
    def plugged(self) -> bool:
        return self._master >= 0

    def replug(self) -> None:
        """Create a fresh pty (and re-point the symlink); no-op if already plugged."""
        with self._lock:
            if self._closed:
                raise ValueError("PtyPort is closed")
            if self._master >= 0:
                return
            master, slave = os.openpty()
            tty.setraw(slave)
            os.set_blocking(master, False)
            self._master, self._slave = master, slave
            self._gen += 1
            self.path = os.ttyname(slave)
            if self.link is not None:
                tmp = self.link.with_name(f".{self.link.name}.{os.getpid()}.tmp")
                with contextlib.suppress(FileNotFoundError):
                    tmp.unlink()
                os.symlink(self.path, tmp)
                os.replace(tmp, self.link)

    def unplug(self) -> None:
        """Close both pty sides and remove the symlink (the host sees the device vanish)."""
        with self._lock:
            self._unplug_locked()
        os.write(self._wake_w, b"u")

    def _unplug_locked(self) -> None:
        if self._master < 0:
            return
        if self.link is not None:
            with contextlib.suppress(FileNotFoundError):
                if os.readlink(self.link) == self.path:
                    self.link.unlink()
        os.close(self._master)
        os.close(self._slave)
        self._master = self._slave = -1

    def close(self) -> None:
        """Unplug for good and release every fd (idempotent)."""
        with self._lock:
            if self._closed:
                return
            self._unplug_locked()
            self._closed = True
            if self._owner >= 0:
                os.close(self._owner)
                self._owner = -1
        os.write(self._wake_w, b"c")
        os.close(self._wake_r)
        os.close(self._wake_w)

    def wake(self) -> None:
        """Interrupt a blocked :meth:`read` (it returns b"")."""
        with self._lock:
            if not self._closed:
                os.write(self._wake_w, b"w")

    def read(self, max_bytes: int, timeout: float) -> bytes:
        """Up to ``max_bytes`` written by the host, waiting at most ``timeout`` s; b"" if none."""
        with self._lock:
            if self._closed:
                return b""
            fd, gen, wake = self._master, self._gen, self._wake_r
        if fd < 0:
            select.select([wake], [], [], timeout)
            self._drain_wake()
            return b""
        try:
            ready, _, _ = select.select([fd, wake], [], [], timeout)
        except (OSError, ValueError):
            return b""
        if wake in ready:
            self._drain_wake()
        if fd not in ready:
            return b""
        with self._lock:
            if gen != self._gen or self._master < 0:
                return b""
            try:
                return os.read(fd, max_bytes)
            except OSError as exc:
                if exc.errno in (errno.EAGAIN, errno.EIO, errno.EINTR):
                    return b""
                raise

    def write(self, data: bytes, timeout: float = 0.5) -> int:
        """Write to the host; returns the bytes accepted (fewer if the pty is full or gone)."""
        view = memoryview(data)
        done = 0
        while done < len(view):
            with self._lock:
                fd = self._master
                if fd < 0:
                    return done
                try:
                    done += os.write(fd, view[done:])
                    continue
                except BlockingIOError:
                    pass
                except OSError as exc:
                    if exc.errno in (errno.EIO, errno.EBADF):
                        return done
                    raise
            try:
                _, ready, _ = select.select([], [fd], [], timeout)
            except (OSError, ValueError):
                return done
            if not ready:
                return done
        return done

    def _drain_wake(self) -> None:
        with self._lock:
            if self._closed:
                return
            with contextlib.suppress(BlockingIOError):
                os.read(self._wake_r, 4096)
