"""An independent DroneCAN peer for tests: the ``dronecan`` package's own node, on the package's
own ``mcast`` driver, playing a flight controller.

``python -m drivers.mocks.dronecan_peer --bus N --seconds S`` runs one in a process of its own
and prints what it saw as JSON. It is node ``--node-id`` (10) and runs the package's dynamic
node-ID allocator (``CentralizedServer``, with its ``NodeMonitor``), so an anonymous node on the
bus is given an ID; it asks every node it sees for ``GetNodeInfo``; it records every
``NodeStatus``, every ``range_sensor.Measurement`` (sensor id, reading type, range) and its
allocation table (the IDs it granted). With ``--servo-hz`` it broadcasts
``actuator.ArrayCommand`` (actuators 1-4, unitless) at that rate, aileron ``--aileron`` and the
rest neutral. With ``--garbage`` it first sends what a noisy bus carries: a multi-frame
transfer whose CRC fails, one whose toggle bit is wrong, and a message of a data type no DSDL
of the package defines.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from typing import Any

__all__ = ["main"]


def _garbage(node: Any, dronecan: Any) -> None:
    """Three transfers a receiver must drop: bad CRC, bad toggle, unknown type."""
    from dronecan import transport

    cmd = dronecan.uavcan.equipment.actuator.ArrayCommand()
    cmd.commands = [dronecan.uavcan.equipment.actuator.Command(actuator_id=k, command_type=0,
                                                               command_value=0.5)
                    for k in (1, 2, 3, 4)]
    for damage in ("crc", "toggle"):
        tr = transport.Transfer(payload=cmd, source_node_id=node.node_id, transfer_id=7,
                                transfer_priority=20, service_not_message=False)
        frames = tr.to_frames()
        assert len(frames) > 1
        first = bytearray(frames[0].bytes)
        if damage == "crc":
            first[0] ^= 0xFF  # the transfer CRC's first byte
            frames[0].bytes = first
        else:
            last = bytearray(frames[1].bytes)
            last[-1] ^= 0x20  # the toggle bit of the second frame
            frames[1].bytes = last
        for f in frames:
            node.can_driver.send(f.message_id, f.bytes, extended=True)
    # a message of data type 12345, which no DSDL of the package defines: one frame
    unknown = (20 << 24) | (12345 << 8) | node.node_id
    node.can_driver.send(unknown, bytes([0x01, 0x02, 0xC0 | 3]), extended=True)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m drivers.mocks.dronecan_peer",
                                description="A DroneCAN flight controller stand-in.")
    p.add_argument("--bus", type=int, default=0, help="mcast bus (239.65.82.BUS)")
    p.add_argument("--seconds", type=float, default=5.0)
    p.add_argument("--node-id", type=int, default=10)
    p.add_argument("--servo-hz", type=float, default=0.0)
    p.add_argument("--aileron", type=float, default=0.5)
    p.add_argument("--garbage", action="store_true")
    args = p.parse_args(argv)

    import dronecan
    from dronecan.app.dynamic_node_id import CentralizedServer
    from dronecan.app.node_monitor import NodeMonitor

    node = dronecan.make_node(f"mcast:{args.bus}", node_id=args.node_id)
    monitor = NodeMonitor(node)
    allocator = CentralizedServer(node, monitor)
    report: dict[str, Any] = {"node_status": {}, "node_info": {}, "measurements": [],
                              "allocations": []}

    def on_status(e: Any) -> None:
        src = str(e.transfer.source_node_id)
        report["node_status"][src] = report["node_status"].get(src, 0) + 1
        if src not in report["node_info"]:
            report["node_info"][src] = None

            def on_info(r: Any, src: str = src) -> None:
                if r is not None:
                    report["node_info"][src] = {
                        "name": r.response.name.decode(),
                        "unique_id": bytes(r.response.hardware_version.unique_id).hex()}
            node.request(dronecan.uavcan.protocol.GetNodeInfo.Request(), int(src), on_info)

    def on_measurement(e: Any) -> None:
        m = e.message
        report["measurements"].append({"src": e.transfer.source_node_id,
                                       "sensor_id": m.sensor_id, "reading": m.reading_type,
                                       "range": m.range, "t_us": m.timestamp.usec})

    node.add_handler(dronecan.uavcan.protocol.NodeStatus, on_status)
    node.add_handler(dronecan.uavcan.equipment.range_sensor.Measurement, on_measurement)

    if args.garbage:
        _garbage(node, dronecan)
    period = 1.0 / args.servo_hz if args.servo_hz > 0 else None
    due = time.monotonic()
    end = time.monotonic() + args.seconds
    while time.monotonic() < end:
        node.spin(0)
        if period is not None and time.monotonic() >= due:
            due += period
            cmd = dronecan.uavcan.equipment.actuator.ArrayCommand()
            values = (args.aileron, 0.0, -1.0, 0.0)  # throttle -1: idle
            cmd.commands = [dronecan.uavcan.equipment.actuator.Command(
                actuator_id=k + 1, command_type=0, command_value=v)
                for k, v in enumerate(values)]
            node.broadcast(cmd)
        time.sleep(0.002)
    report["allocations"] = [{"node_id": nid, "unique_id": bytes(uid).hex()}
                             for uid, nid in allocator.get_allocation_table()
                             if uid is not None and nid != args.node_id]
    allocator.close()
    print(json.dumps(report))
    sys.stdout.flush()
    node.can_driver.proc.terminate()  # the package's driver keeps a process of its own
    return 0


if __name__ == "__main__":
    sys.exit(main())
