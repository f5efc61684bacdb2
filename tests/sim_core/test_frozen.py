"""The compiled kernels keep one version per input type: what their warm-up compiles is what a
caller's read-only or writable arrays use (sim_core/frozen.py)."""

from __future__ import annotations

import numpy as np

from sim_core import flight
from sim_core.flight import FlightModel, FlightParams
from sim_core.frozen import readonly
from sim_core.soaring import kernels
from sim_core.soaring.law import Law
from sim_core.sonar import precull
from sim_core.world import ball


def _versions() -> dict[str, int]:
    funcs = {"flight_rhs": kernels.flight_rhs, "flight_stage": kernels.flight_stage,
             "flight_finish": kernels.flight_finish, "sink_many": kernels.sink_many,
             "ball": ball._rows,
             "precull": precull._precull}
    return {name: len(f.signatures) for name, f in funcs.items()}


def _ro(a: np.ndarray) -> np.ndarray:
    b = np.array(a)
    b.flags.writeable = False
    return b


def test_readonly_is_a_view_that_cannot_write() -> None:
    a = np.arange(4.0)
    v = readonly(a)
    assert np.shares_memory(a, v) and not v.flags.writeable and a.flags.writeable


def test_read_only_and_writable_inputs_use_the_version_the_warm_up_compiled() -> None:
    flight.warm_up()
    ball.warm_up()
    precull.warm_up()
    before = _versions()
    law = Law()
    model = FlightModel.from_params([FlightParams()] * 3, glide=[True, False, True],
                                    polar=(law.Sink_A, law.Sink_B, law.Sink_C), g=law.g)
    y = np.tile(np.array([[0.0], [0.0], [100.0], [0.0], [0.0], [10.0]]), (1, 3))
    u = np.tile(np.array([[0.1], [10.0]]), (1, 3))
    for yy, uu in ((y, u), (_ro(y), _ro(u)), (np.broadcast_to(y[:, :1], y.shape), u)):
        for wind in (lambda xy: np.zeros(xy.shape[1:]),
                     lambda xy: np.broadcast_to(0.5, xy.shape[1:])):  # a read-only updraft
            model.step(yy, uu, 0.02, substeps=2, updraft=wind)
        model.derivative(yy, uu, np.broadcast_to(0.3, (3,)))
        model.outputs(yy, uu)
    c = np.random.default_rng(0).uniform(-1.0, 1.0, (64, 3))
    out = (np.empty(64, np.intp), np.empty(64), np.empty(64), np.empty((64, 3)), np.empty(64))
    for arr in (c, _ro(c)):
        bounds = ball.block_bounds(arr)
        ball.ball_rows(arr, _ro(bounds), _ro(np.zeros(3)), 0.8)
        for rows in (None, _ro(np.arange(10, dtype=np.intp))):
            precull.precull(arr, arr, _ro(np.ones(64)), rows, np.zeros(3),
                            _ro(np.array([1.0, 0.0, 0.0])), r_min2=0.0, reach2=1.0, cone=True,
                            cos_reach=0.5, out=out)
    assert _versions() == before
