"""pyserial URL handlers of echoloop (``sonarsim://``), found via ``protocol_<scheme>`` modules.

:func:`register` appends this package to ``serial.protocol_handler_packages`` (idempotent), after
which ``serial.serial_for_url("sonarsim://?seed=3")`` returns an in-process mock sonar head.
"""

from __future__ import annotations

import serial

__all__ = ["SCHEMES", "register"]

#: schemes implemented here (module ``protocol_<scheme>``)
SCHEMES = ("sonarsim",)


def register() -> None:
    """Make pyserial's ``serial_for_url`` find the handlers of this package."""
    if __name__ not in serial.protocol_handler_packages:
        serial.protocol_handler_packages.append(__name__)
