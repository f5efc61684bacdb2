"""The architecture holds by tool, not by hope: import-linter's contracts (pyproject.toml), no
module past the size of one idea, and the package docstrings that say what each folder holds."""

from __future__ import annotations

import importlib
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("sim_core", "hil_bridge", "drivers")
MAX_LINES = 600
#: modules allowed past MAX_LINES, and why (none: the soaring kernels, once one file of 695
#: lines so that numba's per-file cache could not go stale, are cached as one unit of files,
#: sim_core/soaring/kernels/cache.py)
LONGER: dict[str, int] = {}


def test_import_contracts_are_kept() -> None:
    lint = Path(sys.executable).with_name("lint-imports")
    proc = subprocess.run([str(lint), "--no-cache"], cwd=ROOT, capture_output=True, text=True,
                          timeout=300)
    assert proc.returncode == 0, proc.stdout[-4000:] + proc.stderr[-2000:]
    assert "0 broken" in proc.stdout or " broken" not in proc.stdout, proc.stdout[-4000:]


def _modules() -> list[Path]:
    return sorted(p for pkg in PACKAGES for p in (ROOT / pkg).rglob("*.py"))


def test_no_module_is_over_one_ideas_size() -> None:
    long = {rel: n for p in _modules()
            if (n := len(p.read_text(encoding="utf-8").splitlines()))
            > LONGER.get(rel := str(p.relative_to(ROOT)), MAX_LINES)}
    assert not long, f"modules over {MAX_LINES} lines (split each along its ideas): {long}"


@pytest.mark.parametrize("package", sorted({
    ".".join(p.relative_to(ROOT).parent.parts) for p in _modules() if p.name == "__init__.py"
}))
def test_every_package_says_what_it_holds(package: str) -> None:
    doc = importlib.import_module(package).__doc__
    assert doc and len(doc.split()) >= 5, f"{package} has no docstring saying what it holds"
