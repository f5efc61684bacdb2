"""sim_core: the simulated world of echoloop (forests, foliage echoes, thermal-soaring swarms).

Pure, vectorised, seeded numpy/scipy: no I/O beyond explicit load/save helpers, no clocks,
no threads. Randomness always comes from an explicit :class:`numpy.random.Generator`
(see :mod:`sim_core.rng`).
"""
