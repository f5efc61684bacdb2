"""Launchable nodes that die on purpose, each in one of the ways a node process can die."""

from __future__ import annotations

import logging
import os
import signal
import threading
from typing import Any

log = logging.getLogger(__name__)


class Crasher:
    """``Crasher(name, *, bus, how, after_s=0.3)``: ``how`` in ``abort`` (os.abort), ``sigkill``
    (as the OOM killer does), ``exit`` (os._exit(3)), ``raise`` (an exception that ends the
    process's main thread is not possible from here, so: raise in ``start()``), ``none``."""

    def __init__(self, name: str, *, bus: str, how: str, after_s: float = 0.3) -> None:
        self.name, self.bus, self.how, self.after_s = name, bus, how, after_s
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name=f"crash-{name}", daemon=True)

    def start(self) -> None:
        if self.how == "raise":
            raise RuntimeError(f"{self.name} refuses to start")
        self._thread.start()

    def _run(self) -> None:
        if self._stop.wait(self.after_s) or self.how == "none":
            return
        log.warning("%s: about to die by %s", self.name, self.how)
        if self.how == "abort":
            os.abort()
        elif self.how == "sigkill":
            os.kill(os.getpid(), signal.SIGKILL)
        elif self.how == "exit":
            os._exit(3)

    def stop(self) -> None:
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(5.0)

    def stats(self) -> dict[str, Any]:
        return {"how": self.how, "pid": os.getpid()}
