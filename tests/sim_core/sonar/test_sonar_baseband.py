"""Echo envelope (sim_core.sonar.baseband.envelope_db) against a closed form."""

from __future__ import annotations

import numpy as np


def test_envelope_db_of_a_tone_burst_is_its_amplitude() -> None:
    from sim_core.sonar.baseband import envelope_db

    fs, n = 400e3, 4000
    t = np.arange(n) / fs
    x = np.where((t > 2e-3) & (t < 8e-3), 0.01 * np.cos(2 * np.pi * 70e3 * t), 0.0)
    db = envelope_db(x, floor_db=-200.0)
    inside = (t > 3e-3) & (t < 7e-3)
    np.testing.assert_allclose(db[inside], -40.0, atol=0.05)  # 20 log10(0.01)
    assert db[: int(1e-3 * fs)].max() < -60.0 and db.min() >= -200.0
