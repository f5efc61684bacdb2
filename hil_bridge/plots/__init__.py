"""Figures: matplotlib plots of recordings, forests, echoes and swarm runs.

Plotting is I/O (it writes image files), so it lives here and not in ``sim_core``.

May import: ``hil_bridge.recording``, ``hil_bridge.bus``, ``hil_bridge.files``,
``hil_bridge.outputs``, ``hil_bridge.errors`` and ``sim_core``.
"""
