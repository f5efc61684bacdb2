"""Command supervision of the CAN adapter: what it publishes for a glider whose commands stop.

Per glider, evaluated at ``heartbeat_hz`` (``cmd_state`` in the bridge heartbeat and in
``/diagnostics``; the state :func:`next_cmd_state` gives):

``WAITING``  no command yet, less than ``failsafe_after_s`` since start: nothing is published;
``FRESH``    the last command is at most ``cmd_timeout_s`` old;
``HOLD``     older than ``cmd_timeout_s``: the last command is re-published (hold last);
``FAILSAFE`` older than ``failsafe_after_s`` (or never any), or the autopilot's heartbeat
             reports ``FAULT``: the failsafe command is published — wings level
             (``failsafe_bank_rad`` = 0) at best-glide speed (``failsafe_airspeed_mps``, default
             :func:`best_glide_speed` of the seed polar = 11.36 m/s). The next command frame
             ends it.

Ages are wall seconds, or sim seconds in lockstep (:class:`drivers.can.adapter.AutopilotAdapter`).
"""

from __future__ import annotations

import math

from sim_core.soaring.law import Law

__all__ = ["AP_FAULT", "CMD_STATES", "best_glide_speed", "next_cmd_state"]

#: cmd_state values (BRIDGE_HEARTBEAT.cmd_state, the DBC's value table).
CMD_STATES = {"WAITING": 0, "FRESH": 1, "HOLD": 2, "FAILSAFE": 3}
#: The ap_mode of an AUTOPILOT_HEARTBEAT that reports a fault (the DBC's value table).
AP_FAULT = 3


def best_glide_speed(law: Law | None = None) -> float:
    """Airspeed of the best glide ratio of the law's polar, m/s: sqrt(Sink_C / Sink_A).

    The sink polar is A v² + B v + C (< 0); the glide ratio v / |sink| peaks where
    d/dv (A v + B + C / v) = 0, i.e. v² = C / A. Seed law: sqrt(2.3782 / 0.01843) = 11.36 m/s.
    """
    law = law if law is not None else Law()
    return math.sqrt(law.Sink_C / law.Sink_A)


def next_cmd_state(
    *, has_cmd: bool, age_s: float, ap_fault: bool, cmd_timeout_s: float, failsafe_after_s: float
) -> int:
    """The ``CMD_STATES`` value of a glider whose last command (or, without one, the start of
    supervision) is ``age_s`` old; ``ap_fault``: its live autopilot reports ``FAULT``."""
    if ap_fault:
        return CMD_STATES["FAILSAFE"]
    if has_cmd and age_s <= cmd_timeout_s:
        return CMD_STATES["FRESH"]
    if age_s <= failsafe_after_s:
        return CMD_STATES["HOLD"] if has_cmd else CMD_STATES["WAITING"]
    return CMD_STATES["FAILSAFE"]
