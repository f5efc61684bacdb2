"""sim_core: the simulated world of echoloop (forests, foliage echoes, thermal-soaring swarms).

Pure, vectorised, seeded numpy/scipy: functions take and return arrays, dataclasses, dicts and
strings; no file I/O (readers and writers are ``hil_bridge.files``), no plotting
(``hil_bridge.plots``), no clocks, no processes. Randomness always comes from an explicit
:class:`numpy.random.Generator` (see :mod:`sim_core.rng`).
"""
