"""What the tests of real firmware share: the ``arduplane`` binary ``ECHOLOOP_ARDUPILOT_SITL``
names (built by the user, outside this repository), the mark that skips them without it, and
how a firmware or launch process is stopped."""

from __future__ import annotations

import os
import signal
import subprocess

import pytest

SITL = os.environ.get("ECHOLOOP_ARDUPILOT_SITL", "")

#: skips a test where no arduplane binary is named
needs_sitl = pytest.mark.skipif(not (SITL and os.access(SITL, os.X_OK)),
                                reason="ECHOLOOP_ARDUPILOT_SITL does not name an arduplane binary")


def stop(proc: subprocess.Popen[str]) -> None:
    """SIGTERM, a minute's grace, then SIGKILL."""
    if proc.poll() is None:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(timeout=60)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
