"""``echoloop dronecan node [RUN OPTIONS]``: the DroneCAN node alone.

It is ``echoloop run drivers.dronecan.node:DroneCanNode --name dronecan``: the node against a
bus (the domain's, or ``--bus``), beside a running launch or on the computer a flight
controller's CAN adapter is plugged into; every option of ``echoloop run`` applies
(``--param vehicle_id=7``, ``--param 'interface=slcan:/dev/ttyACM0?baud=1000000'``,
``--param node_id=42``). docs/dronecan.md says how to wire and set up the flight controller.
"""

from __future__ import annotations

from hil_bridge.cli.run import node_commands

ENTRIES = {
    "node": ("drivers.dronecan.node:DroneCanNode",
             "echoloop as DroneCAN peripherals: echo ranges, air data, GNSS out; servos in"),
}


def main(argv: list[str] | None = None) -> int:
    return node_commands("echoloop dronecan", "A stock flight controller on CAN (DroneCAN).",
                         ENTRIES, argv, node_name="dronecan")
