"""``launch --plot`` draws only what the run had."""

from __future__ import annotations

from pathlib import Path

import pytest

from hil_bridge.plots.recording import plot_recording
from tests.hil_bridge.recording.bagmaker import demo_messages, write_bag


@pytest.mark.parametrize(("gliders", "mount", "panels"), [
    ((0, 1, 2), None, 1),  # swarm only: no empty forest or echo panel
    ((), 9, 2),  # sonar only: no empty swarm panel
    ((0, 1), 9, 3),
], ids=["swarm", "sonar", "both"])
def test_only_the_panels_the_run_had(tmp_path: Path, gliders: tuple[int, ...],
                                     mount: int | None, panels: int) -> None:
    msgs = [m for m in demo_messages(gliders=gliders, sonar_mount=mount)
            if gliders or m[0] != "/thermals"]
    bag = write_bag(tmp_path / "run.mcap", msgs)
    out = plot_recording(bag, tmp_path / "run.png")
    assert out["panels"] == panels
    assert out["echo"] == int(mount is not None)
    assert (tmp_path / "run.png").read_bytes()[:4] == b"\x89PNG"


def test_nothing_to_plot_is_an_error(tmp_path: Path) -> None:
    bag = write_bag(tmp_path / "clock.mcap", [m for m in demo_messages(sonar_mount=None)
                                               if m[0] == "/clock"])
    with pytest.raises(ValueError, match=r"clock\.mcap: nothing to plot"):
        plot_recording(bag, tmp_path / "x.png")
