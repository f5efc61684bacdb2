"""A launchable node that reports what its process's garbage collector holds."""

from __future__ import annotations

import gc
from typing import Any


class HeapReporter:
    """``HeapReporter(name, *, bus)``: its stats say how many objects were frozen when it was
    built and when it started (``gc.get_freeze_count()``), how many a full collection walks
    now (generation 2, the frozen ones left out), and whether what it made in ``start()`` and
    what it made once running are among those."""

    def __init__(self, name: str, *, bus: str) -> None:
        self.name, self.bus = name, bus
        self.frozen_when_built = gc.get_freeze_count()
        self.frozen_when_started = -1
        self._at_start: list[list[int]] = []
        self._running: list[list[int]] = []

    def start(self) -> None:
        self.frozen_when_started = gc.get_freeze_count()
        self._at_start = [[i] for i in range(1000)]

    def stop(self) -> None:
        """Nothing runs."""

    def stats(self) -> dict[str, Any]:
        if not self._running:
            self._running = [[i] for i in range(1000)]  # the run's own survivors
        gc.collect(1)  # they reach generation 2, as survivors do over a long run
        walked = {id(o) for o in gc.get_objects(2)}
        return {"frozen_when_built": self.frozen_when_built,
                "frozen_when_started": self.frozen_when_started,
                "full_collection_walks": len(walked),
                "walks_start_objects": id(self._at_start[0]) in walked,
                "walks_run_objects": id(self._running[0]) in walked}
