"""The simulation server: the node that owns the scene, the clock, physics and echoes.

``sim_server`` (:class:`SimServer`: topics, commands, the tick loop, publishing), ``fleet``
(vehicles' flight and pose history), ``sonars`` (pings in at the pose of emission, echoes out),
``emission`` (that pose, a ping stamped after the newest tick waiting for the tick covering it),
``echo_compute`` (one echo: request, job, result and their computation), ``echo_service`` and
``echo_pool`` (the scheduler and its workers: thread, process or a deadline-aware pool),
``shared_tiles`` (forest tiles in shared memory for the workers) and ``lockstep`` (the gate
that holds the clock for hardware in lockstep).

May import: ``hil_bridge.recording`` (trajectories from flight logs), ``hil_bridge.bus``,
``hil_bridge.files``, ``hil_bridge.errors``, ``hil_bridge.outputs`` and ``sim_core``.
Launch files name the server ``hil_bridge.server:SimServer``.
"""

from hil_bridge.server.sim_server import SimServer

__all__ = ["SimServer"]
