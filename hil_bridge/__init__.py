"""hil_bridge: the echoloop bus (ROS 2-style topics over ZeroMQ), the simulation server and tools.

Sub-packages, each a layer that imports only the layers below it (``importlinter`` contracts in
``pyproject.toml`` enforce it; ``docs/architecture.md`` draws it):

- ``cli`` — the ``echoloop`` command line;
- ``launch`` — launch files run by a runner, the bus monitor, ``--expect``, the pytest plugin;
- ``server``, ``replay``, ``tools``, ``plots`` — the simulation server (tick loop, fleet, sonars,
  echo service), trajectory replay, topic tools / live view / flood / sweeps, and figures;
- ``recording`` — MCAP bags, the recorder, scan and recovery, flight-log readers, exports;
- ``bus`` — messages, codec, QoS, sequences, node API, transports, proxy, clock, security,
  domains;
- ``files`` — the file formats of the world (YAML configs, scene, forest, law and grid files,
  ``.npz`` leaves and forests, tree maps, L++ grammars, CAD meshes, traces) and the package data
  behind presets: every reader and writer ``sim_core`` does not have;
- ``errors``, ``outputs`` and ``lifetime`` — the error types, the never-clobber output files and
  a node process's life (the parent-death signal, its heap frozen once built) every layer may
  use.

Everything here may import ``sim_core`` (the pure world); nothing here imports ``drivers``.
"""
