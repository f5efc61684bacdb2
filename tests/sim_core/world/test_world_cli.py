"""``echoloop forest generate``: the binding CLI contract (npz keys, --json keys, exit codes)."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest

from hil_bridge.cli import main


def test_generate_preset_npz_json_and_plot(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out, png = tmp_path / "f.npz", tmp_path / "f.png"
    rc = main(["forest", "generate", "--preset", "seed000-fig5d", "--seed", "3",
               "--out", str(out), "--plot", str(png), "--json"])
    assert rc == 0
    summary = json.loads(capsys.readouterr().out)
    assert set(summary) == {"trees", "leaves", "species", "seconds"}
    assert summary["species"] == {"maple": 4, "hazelnut": 1} and summary["trees"] == 5
    with np.load(out) as data:
        assert data["centers"].shape == (summary["leaves"], 3)
        assert data["normals"].shape == (summary["leaves"], 3)
        assert data["radii"].shape == (summary["leaves"],)
        assert data["tree_id"].shape == (summary["leaves"],)
        assert data["tree_xy"].shape == (5, 2)
        assert sorted(data["tree_species"].tolist()) == ["hazelnut"] + ["maple"] * 4
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_generate_scene_yaml_is_deterministic(tmp_path: Path) -> None:
    scene = tmp_path / "scene.yaml"
    scene.write_text(
        "domain: [0, 0, 30, 30]\nmin_distance_m: 4\n"
        "species:\n  - {name: b, tree: hazelnut-bush, growth_level: 1, rate: 0.02}\n"
    )
    for name in ("a", "b"):
        assert main(["forest", "generate", "--scene", str(scene), "--seed", "9",
                     "--out", str(tmp_path / f"{name}.npz")]) == 0
    with np.load(tmp_path / "a.npz") as a, np.load(tmp_path / "b.npz") as b:
        assert np.array_equal(a["centers"], b["centers"]) and a["tree_xy"].shape[0] > 3


@pytest.mark.parametrize(
    ("scene", "message"),
    [
        ("species: [{name: a, rate: -1}]", "rate must be an intensity >= 0"),
        ("species: [{name: a, kernels: [{peak: -0.4, center: [5, 5], div: [5, 6]}]}]",
         "peak must be an intensity >= 0"),
        ("species: [{name: a, tree: tree4, grammar: GRAMMAR, positions: [[0, 0]]}]",
         r"bad.l\+\+:5 \(rule 'A'\): unbalanced '\['"),
        ("species: [{name: a, positions: [[0, 0]], template: {leaf: TEMPLATE}}]",
         "template .*missing.obj: cannot read"),
        ("domain: [0, 0, 1000, 1000]\nspecies: [{name: a, rate: 5}]", "huge intensity"),
        ("species: [{name: a, colour: red, rate: 1}]", "unknown key"),
    ],
    ids=["negative-rate", "negative-peak", "bad-grammar", "bad-template", "huge", "unknown-key"],
)
def test_bad_input_exits_nonzero_with_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], scene: str, message: str
) -> None:
    grammar = tmp_path / "bad.l++"
    grammar.write_text("3\n15\n60\nfA\nA=[f*\n@\n")
    text = scene.replace("GRAMMAR", str(grammar)).replace("TEMPLATE", str(tmp_path / "missing.obj"))
    path = tmp_path / "scene.yaml"
    path.write_text(text)
    rc = main(["forest", "generate", "--scene", str(path), "--out", str(tmp_path / "x.npz")])
    err = capsys.readouterr().err
    assert rc != 0
    assert len(err.strip().splitlines()) == 1
    assert re.search(message, err), err
    assert not (tmp_path / "x.npz").exists()


def test_unknown_preset_and_usage_errors(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    rc = main(["forest", "generate", "--preset", "nope", "--out", str(tmp_path / "x.npz")])
    err = capsys.readouterr().err
    assert rc == 1 and "unknown preset 'nope'" in err and len(err.strip().splitlines()) == 1
    with pytest.raises(SystemExit) as exc:
        main(["forest", "generate", "--out", str(tmp_path / "x.npz")])  # no --preset/--scene
    assert exc.value.code == 2
    assert main(["forest", "generate", "--scene", str(tmp_path / "none.yaml"),
                 "--out", str(tmp_path / "x.npz")]) == 1
    assert "cannot read" in capsys.readouterr().err
    assert main(["forest", "presets"]) == 0
    assert "seed001-fig9" in capsys.readouterr().out.split()
