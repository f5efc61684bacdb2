"""What autopilots send the simulation server: bank/airspeed commands and control surfaces.

:class:`AutopilotInputs` checks, holds and counts them for :class:`~hil_bridge.server.sim_server.
SimServer` (its bus callbacks call in, its tick loop takes what each tick flies):

- **Commands** (``GliderCmd``, swarm gliders and commanded vehicles). One is *rejected* (counted,
  the last good one held) if a value is non-finite, ``|bank_cmd| >= pi/2`` or ``airspeed_cmd``
  is outside (0, 3 * max speed]; otherwise it is clipped to the glider's (the law's) or
  vehicle's envelope (``cmd_clipped``) and held until the next good one. Commands for path and
  6-DoF vehicles are counted in ``cmd_ignored``.
- **Control surfaces** (``SurfaceCmd``, 6-DoF vehicles): one with ``hold`` answers its step and
  changes nothing (``surfaces_held``); rejected (``surfaces_rejected``) when a
  value is non-finite or out of its range (aileron, elevator, rudder in [-1, 1], throttle in
  [0, 1]); a good one is held (``surfaces_applied``).

Either registers its glider (its first message, even a rejected one). ``cmd_effect_ticks``: for
each good input, the tick it was first flown in minus the next tick due when it arrived, plus
one; ``cmd_apply_ms``: the wall time from its arrival to the publish of the first state that
flies it.
"""

from __future__ import annotations

import math
import threading
import time
from collections import deque
from collections.abc import Callable, Iterable
from typing import Any

from hil_bridge.bus.messages import GliderCmd, SurfaceCmd
from hil_bridge.bus.stats import percentiles
from sim_core.scene import Scene

__all__ = ["COUNTERS", "AutopilotInputs"]

COUNTERS = ("cmd_received", "cmd_applied", "cmd_rejected", "cmd_clipped", "cmd_ignored",
            "surfaces_received", "surfaces_applied", "surfaces_rejected", "surfaces_held")
_REJECT_BANK = math.pi / 2


class AutopilotInputs:
    """The held inputs of every glider and vehicle of ``scene``; ``registered``: the autopilots
    registered up front; ``ticks()``: the number of ticks published so far."""

    def __init__(self, scene: Scene, registered: Iterable[int], ticks: Callable[[], int]) -> None:
        self._scene = scene
        self._vehicles = {v.id: v for v in scene.spec.vehicles}
        self._ticks = ticks
        self._lock = threading.Lock()
        self._c = dict.fromkeys(COUNTERS, 0)
        self._registered: set[int] = {int(a) for a in registered}
        self._cmd: dict[int, tuple[float, float]] = {}
        self._surfaces: dict[int, tuple[float, float, float, float]] = {}
        #: id -> (the tick due when its newest good input arrived, arrival ns), until flown
        self._pending: dict[int, tuple[int, int]] = {}
        self._flying: list[int] = []
        self._effect_ticks: deque[int] = deque(maxlen=10000)
        self._apply_ms: deque[float] = deque(maxlen=10000)

    def registered(self) -> list[int]:
        """The registered gliders and vehicles, sorted."""
        with self._lock:
            return sorted(self._registered)

    def on_cmd(self, gid: int, msg: GliderCmd) -> bool:
        """Take a command for ``gid``; False when its vehicle takes none (ignored, not an
        autopilot's answer)."""
        due = self._ticks()
        with self._lock:
            self._c["cmd_received"] += 1
            vehicle = self._vehicles.get(gid)
            if vehicle is not None and not vehicle.commanded:
                self._c["cmd_ignored"] += 1
                return False
            self._registered.add(gid)
            checked = self._check(gid, msg.bank_cmd, msg.airspeed_cmd)
            if checked is None:
                self._c["cmd_rejected"] += 1
                return True
            bank, speed, clipped = checked
            self._cmd[gid] = (bank, speed)
            self._pending.setdefault(gid, (due, time.monotonic_ns()))
            self._c["cmd_applied"] += 1
            self._c["cmd_clipped"] += int(clipped)
        return True

    def on_surfaces(self, gid: int, msg: SurfaceCmd) -> None:
        """Take the control surfaces of 6-DoF vehicle ``gid``."""
        u = (float(msg.aileron), float(msg.elevator), float(msg.throttle), float(msg.rudder))
        good = (all(math.isfinite(x) for x in u) and max(abs(u[0]), abs(u[1]), abs(u[3])) <= 1
                and 0.0 <= u[2] <= 1.0)
        due = self._ticks()
        with self._lock:
            self._c["surfaces_received"] += 1
            self._registered.add(gid)
            if msg.hold:
                self._c["surfaces_held"] += 1
                return
            if not good:
                self._c["surfaces_rejected"] += 1
                return
            self._surfaces[gid] = u
            self._pending.setdefault(gid, (due, time.monotonic_ns()))
            self._c["surfaces_applied"] += 1

    def _check(self, gid: int, bank: float, speed: float) -> tuple[float, float, bool] | None:
        """Reject (None) or clip a command to glider/vehicle ``gid``'s envelope."""
        vehicle = self._vehicles.get(gid)
        if vehicle is None:
            law = self._scene.law  # a glider: the scene has a swarm
            bank_lo, bank_hi = float(law.bankMin), float(law.bankMax)
            v_lo, v_hi = float(law.forwardSpeedMin), float(law.forwardSpeedMax)
        else:
            bank_lo, bank_hi = -vehicle.bank_max_rad, vehicle.bank_max_rad
            v_lo, v_hi = vehicle.speed_min_mps, vehicle.speed_max_mps
        b, v = float(bank), float(speed)
        if not (math.isfinite(b) and math.isfinite(v)):
            return None
        if abs(b) >= _REJECT_BANK or not 0 < v <= 3 * v_hi:
            return None
        bc = min(max(b, bank_lo), bank_hi)
        vc = min(max(v, v_lo), v_hi)
        return bc, vc, (bc != b or vc != v)

    def for_tick(self, tick: int) -> tuple[dict[int, tuple[float, float]],
                                            dict[int, tuple[float, float, float, float]]]:
        """The held good commands and surfaces that tick ``tick`` flies (and their effect
        latency)."""
        with self._lock:
            for arrived, arrived_ns in self._pending.values():
                self._effect_ticks.append(tick - arrived + 1)
                self._flying.append(arrived_ns)
            self._pending.clear()
            return dict(self._cmd), dict(self._surfaces)

    def published(self, published_ns: int) -> None:
        """The states flying the inputs taken since the last call were published then."""
        with self._lock:
            self._apply_ms.extend((published_ns - a) / 1e6 for a in self._flying)
            self._flying.clear()

    def stats(self) -> dict[str, Any]:
        """Counters, ``registered``, ``cmd_effect_ticks`` and ``cmd_apply_ms`` percentiles."""
        with self._lock:
            out: dict[str, Any] = dict(self._c)
            out["registered"] = sorted(self._registered)
            effect, apply_ms = list(self._effect_ticks), list(self._apply_ms)
        out["cmd_effect_ticks"] = percentiles(effect)
        out["cmd_apply_ms"] = percentiles(apply_ms)
        return out
