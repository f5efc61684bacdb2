"""sim_core is the pure world: no module of it imports threads, processes or clocks."""

from __future__ import annotations

import ast
from pathlib import Path

SIM_CORE = Path(__file__).resolve().parents[2] / "sim_core"
#: top-level modules whose import would bring threads, processes or wall-clock time
FORBIDDEN = {"threading", "_thread", "multiprocessing", "concurrent", "subprocess", "asyncio",
             "time", "datetime", "sched"}


def _imports(path: Path) -> set[str]:
    tree = ast.parse(path.read_text(encoding="utf-8"), str(path))
    names: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names.update(alias.name.split(".")[0] for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names.add(node.module.split(".")[0])
    return names


def test_the_scan_sees_imports_anywhere_in_a_module(tmp_path: Path) -> None:
    probe = tmp_path / "probe.py"
    probe.write_text("def f():\n    from concurrent.futures import ThreadPoolExecutor\n"
                     "    import time as clock\n")
    assert _imports(probe) == {"concurrent", "time"}


def test_sim_core_imports_no_threads_processes_or_clocks() -> None:
    modules = sorted(SIM_CORE.rglob("*.py"))
    assert len(modules) > 30
    hits = {str(p.relative_to(SIM_CORE)): sorted(_imports(p) & FORBIDDEN) for p in modules}
    assert not {k: v for k, v in hits.items() if v}
