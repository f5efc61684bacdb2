"""Tools around a running bus: topic list/echo/hz, the live view, a loopback flood, sweeps.

``topic`` (topic monitor and statistics), ``live`` (the browser live view over Foxglove's
WebSocket), ``flood`` (a bounded malformed-message flood for fault tests) and ``sweep``
(swarm parameter sweeps over local processes or Dask).

May import: ``hil_bridge.recording``, ``hil_bridge.bus``, ``hil_bridge.files``,
``hil_bridge.errors``, ``hil_bridge.outputs`` and ``sim_core``.
"""
