"""``echoloop mavlink px4 [RUN OPTIONS]`` and ``echoloop mavlink rangefinder [RUN OPTIONS]``.

Each is ``echoloop run ENTRY --name NAME``: the node alone against a bus (the domain's, or
``--bus``), e.g. beside a launch, or on the computer a flight controller is plugged into;
every option of ``echoloop run`` applies (``--param vehicle_id=7``,
``--param 'link=serial:///dev/ttyACM0?baud=921600'``).
"""

from __future__ import annotations

from hil_bridge.cli.run import node_commands

ENTRIES = {
    "px4": ("drivers.mavlink.px4:Px4Hil", "PX4's simulator interface (SITL on TCP 4560 + N, "
                                          "HITL on USB serial)"),
    "rangefinder": ("drivers.mavlink.rangefinder:MavlinkRangefinder",
                    "sonar echoes as DISTANCE_SENSOR/OBSTACLE_DISTANCE for any MAVLink "
                    "autopilot"),
}


def main(argv: list[str] | None = None) -> int:
    return node_commands("echoloop mavlink", "Stock autopilots in the loop over MAVLink.",
                         ENTRIES, argv)
