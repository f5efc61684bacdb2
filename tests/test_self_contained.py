"""The repository carries what it tests: nothing reads ``../shared`` (which users do not have)."""

from __future__ import annotations

import re
import shutil
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
#: a path into the steering repository beside the project
SHARED_REF = re.compile(r"\.\./shared|\bshared/(spec|data|seeds)\b")
#: tests that read data files, run from a copy of the repository with nothing beside it
DATA_TESTS = (
    "tests/sim_core/world/test_world_ipp.py",
    "tests/sim_core/world/test_world_lpp.py",
    "tests/sim_core/soaring/test_soaring_law.py",
    "tests/sim_core/soaring/test_soaring_pinned.py",
)


def _tracked() -> list[str]:
    out = subprocess.run(["git", "ls-files"], cwd=ROOT, capture_output=True, text=True,
                         check=True)
    return out.stdout.split()


def test_no_tracked_file_points_at_shared() -> None:
    hits = []
    for name in _tracked():
        path = ROOT / name
        if path.suffix not in {".py", ".md", ".yaml", ".yml", ".toml", ".cfg", ""} or (
            name == "tests/test_self_contained.py"
        ):
            continue
        for no, line in enumerate(path.read_text(errors="replace").splitlines(), 1):
            if SHARED_REF.search(line):
                hits.append(f"{name}:{no}: {line.strip()}")
    assert not hits, "files that point at ../shared:\n" + "\n".join(hits)


def test_data_tests_pass_in_a_copy_with_nothing_beside_it(tmp_path: Path) -> None:
    repo = tmp_path / "alone" / "echoloop"
    for name in _tracked():
        dest = repo / name
        dest.parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(ROOT / name, dest)
    assert not (repo.parent / "shared").exists()
    # same source and file stamps in the copy, so numba's on-disk cache of the soaring kernels
    # is valid there: the copy loads them instead of compiling them again
    kernels = Path("sim_core", "soaring", "kernels", "__pycache__")
    for cached in (ROOT / kernels).glob("*.nb[ic]"):
        dest = repo / kernels / cached.name
        dest.parent.mkdir(exist_ok=True)
        shutil.copy2(cached, dest)
    proc = subprocess.run(
        [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", *DATA_TESTS],
        cwd=repo, capture_output=True, text=True, timeout=300,
    )
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-2000:]
    assert " passed" in proc.stdout
