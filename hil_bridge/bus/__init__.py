"""The bus: what every node speaks, with no knowledge of the server, recordings or launches.

Holds the messages (frozen dataclasses) and their msgpack codec, QoS profiles, sequence
tracking, the node API (publishers, subscriptions, timers, executor), the transports behind
``open_transport(url)`` (``mem://``, ZeroMQ ``tcp://``/``ipc://``), the XSUB/XPUB proxy, the sim
clock, CURVE security, domains (ports, links, temp names per ``ECHOLOOP_DOMAIN``) and the
statistics every tool keeps of a topic.

May import: ``hil_bridge.errors``, ``hil_bridge.outputs``, ``hil_bridge.files`` and ``sim_core``.
The ``replay://`` transport is named in the backend table by string and lives in ``recording``.
"""
