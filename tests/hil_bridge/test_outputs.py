"""Outputs are refused when they exist or are an input, and appear whole or not at all."""

from __future__ import annotations

from pathlib import Path

import pytest

from hil_bridge.errors import OutputExistsError
from hil_bridge.outputs import atomic_output


def _leftovers(d: Path) -> list[str]:
    return sorted(p.name for p in d.iterdir() if ".part" in p.name)


def test_writes_through_a_temp_file_and_renames(tmp_path: Path) -> None:
    out = tmp_path / "sub" / "x.bin"
    with atomic_output(out) as tmp:
        assert tmp.parent == out.parent and tmp != out
        tmp.write_bytes(b"data")
        assert not out.exists()
    assert out.read_bytes() == b"data"
    assert _leftovers(out.parent) == []


def test_existing_output_is_refused_unless_overwrite(tmp_path: Path) -> None:
    out = tmp_path / "x.bin"
    out.write_bytes(b"old")
    with pytest.raises(OutputExistsError, match=r"x\.bin: exists; pass --overwrite"):
        with atomic_output(out):
            pytest.fail("must not get here")
    assert out.read_bytes() == b"old"
    with atomic_output(out, overwrite=True) as tmp:
        tmp.write_bytes(b"new")
    assert out.read_bytes() == b"new"


def test_failure_leaves_the_old_file_and_no_temp(tmp_path: Path) -> None:
    out = tmp_path / "x.bin"
    out.write_bytes(b"old")
    with pytest.raises(RuntimeError, match="boom"), atomic_output(out, overwrite=True) as tmp:
        tmp.write_bytes(b"half")
        raise RuntimeError("boom")
    assert out.read_bytes() == b"old"
    assert _leftovers(tmp_path) == []


def test_own_input_is_refused_even_with_overwrite(tmp_path: Path) -> None:
    src = tmp_path / "in.mcap"
    src.write_bytes(b"input")
    link = tmp_path / "alias.mcap"
    link.symlink_to(src)
    for target in (src, link, tmp_path / "." / "in.mcap"):
        with pytest.raises(ValueError, match="is also an input"):
            with atomic_output(target, overwrite=True, inputs=[src]):
                pytest.fail("must not get here")
    assert src.read_bytes() == b"input"


def test_symlink_is_replaced_not_followed(tmp_path: Path) -> None:
    victim = tmp_path / "victim.txt"
    victim.write_bytes(b"keep")
    link = tmp_path / "out.txt"
    link.symlink_to(victim)
    with pytest.raises(OutputExistsError):
        with atomic_output(link):
            pass
    dangling = tmp_path / "dangling.txt"
    dangling.symlink_to(tmp_path / "nowhere")
    with pytest.raises(OutputExistsError):
        with atomic_output(dangling):
            pass
    with atomic_output(link, overwrite=True) as tmp:
        tmp.write_bytes(b"new")
    assert not link.is_symlink() and link.read_bytes() == b"new"
    assert victim.read_bytes() == b"keep"


def test_directory_is_not_an_output(tmp_path: Path) -> None:
    with pytest.raises(IsADirectoryError, match="is a directory"):
        with atomic_output(tmp_path, overwrite=True):
            pass
