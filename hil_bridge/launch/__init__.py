"""Launch: a launch file (plain data) run by a runner that starts, watches and judges nodes.

``spec`` (the launch file: load, validate, which entries may run), ``runner`` (run it, watch
every launchable's ``failure()``, judge the exit status), ``monitor`` (the bus monitor's
topic statistics), ``expect`` (``--expect`` expressions) and ``pytest_plugin`` (the
``echoloop_launch`` fixture). ``python -m hil_bridge.launch FILE`` is ``echoloop launch FILE``.

May import: ``hil_bridge.tools``, ``hil_bridge.recording``, ``hil_bridge.bus``,
``hil_bridge.files``, ``hil_bridge.errors``, ``hil_bridge.outputs`` and ``sim_core``; nodes are
named by entry strings and imported at run time, never at import time.
"""

from hil_bridge.launch.runner import (
    EXIT_AFTER_RUN,
    EXIT_DISCONNECTED,
    EXIT_EXPECT,
    EXIT_FAILED,
    EXIT_OK,
    LaunchSpec,
    NodeSpec,
    RunSummary,
    load,
    run,
)

__all__ = [
    "EXIT_AFTER_RUN",
    "EXIT_DISCONNECTED",
    "EXIT_EXPECT",
    "EXIT_FAILED",
    "EXIT_OK",
    "LaunchSpec",
    "NodeSpec",
    "RunSummary",
    "load",
    "run",
]
