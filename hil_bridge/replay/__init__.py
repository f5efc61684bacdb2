"""Trajectory replay: a logged flight driven through the world, and the software pinger.

``trajectory`` builds the launch description of ``echoloop replay FILE`` (a server whose
scene flies one vehicle along the log) and holds :class:`Pinger`, the node that pings sonars
at a fixed rate and counts the echoes (launch files name it ``hil_bridge.replay:Pinger``).

May import: ``hil_bridge.recording``, ``hil_bridge.bus``, ``hil_bridge.files``,
``hil_bridge.errors`` and ``sim_core``; the server is named by its entry string, not imported.
"""

from hil_bridge.replay.trajectory import Pinger, build_replay_launch

__all__ = ["Pinger", "build_replay_launch"]
