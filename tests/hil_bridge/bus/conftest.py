"""Bus fixtures for these tests: ``bus_url`` (mem and zmq) and the socket-leak guard."""

from tests.hil_bridge.busfixtures import _no_socket_leaks, bus_url

__all__ = ["_no_socket_leaks", "bus_url"]
