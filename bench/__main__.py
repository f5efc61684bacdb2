"""Run the benchmarks and write their sections into BENCHMARKS.md.

``python -m bench`` runs every ``bench/bench_<name>.py``; ``python -m bench world sonar`` runs
only those and replaces only their sections, keeping the others. Each module exposes
``TITLE: str`` and ``run(out_dir: pathlib.Path) -> str`` (Markdown, figures written to out_dir).
"""

from __future__ import annotations

import argparse
import datetime as _dt
import importlib
import os
import platform
import re
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
DOC = ROOT / "BENCHMARKS.md"
FIG_DIR = ROOT / "docs" / "figures" / "bench"


def _available() -> list[str]:
    return sorted(p.stem.removeprefix("bench_") for p in Path(__file__).parent.glob("bench_*.py"))


def _machine() -> str:
    return (
        f"{platform.python_implementation()} {platform.python_version()} on "
        f"{platform.machine()}, {os.cpu_count()} logical cores, {platform.platform()}"
    )


#: iterations of the speed probe's loop (about 20-40 ms of CPU on the development machine)
PROBE_LOOPS = 200_000


def speed_probe(repeat: int = 5) -> float:
    """CPU milliseconds of a fixed pure-Python loop, median of ``repeat``: how fast this
    machine runs an interpreter at the moment (lower is faster). A shared machine's speed
    moves by tens of percent from hour to hour (another tenant on the same cores); each section
    records the probe before and after it, so that two runs of a section can be compared."""
    times = []
    for _ in range(repeat):
        t0 = time.process_time()
        acc = 0
        for i in range(PROBE_LOOPS):
            acc += i * i
        times.append(time.process_time() - t0)
    return 1e3 * sorted(times)[repeat // 2]


def _splice(doc: str, name: str, body: str) -> str:
    start, end = f"<!-- bench:{name} -->", f"<!-- /bench:{name} -->"
    block = f"{start}\n{body.strip()}\n{end}"
    pattern = re.compile(re.escape(start) + r".*?" + re.escape(end), re.S)
    if pattern.search(doc):
        return pattern.sub(lambda _m: block, doc)
    return doc.rstrip() + "\n\n" + block + "\n"


HEADER = """# Benchmarks

Written by `make bench` (`python -m bench`); each section can be refreshed alone with
`python -m bench NAME`. Times are wall-clock medians on a shared, noisy machine; every ratio
compares figures measured in the same run. These are not tests: nothing here asserts a time.
Each section's line says how fast the machine was around it: the *speed probe*, the CPU time
of a fixed pure-Python loop (median of 5; lower is faster), before and after the section.
"""


def main(argv: list[str] | None = None) -> int:
    names = _available()
    parser = argparse.ArgumentParser(prog="python -m bench", description=__doc__)
    parser.add_argument("only", nargs="*", metavar="NAME", help=f"sections to run: {names}")
    args = parser.parse_args(argv)
    unknown = sorted(set(args.only) - set(names))
    if unknown:
        parser.error(f"unknown benchmark(s) {unknown}; expected some of {names}")
    selected = args.only or names
    FIG_DIR.mkdir(parents=True, exist_ok=True)
    for name in selected:
        module = importlib.import_module(f"bench.bench_{name}")
        print(f"[bench] {name}: running", file=sys.stderr, flush=True)
        before = speed_probe()
        t0 = time.perf_counter()
        body = module.run(FIG_DIR)
        elapsed = time.perf_counter() - t0
        after = speed_probe()
        stamp = _dt.datetime.now(_dt.UTC).strftime("%Y-%m-%d %H:%M UTC")
        section = (
            f"## {module.TITLE}\n\n_Run {stamp} on {_machine()}; "
            f"section took {elapsed:.0f} s (`python -m bench {name}`); speed probe "
            f"{before:.1f} ms before, {after:.1f} ms after._\n\n{body.strip()}\n"
        )
        # re-read just before writing, so sections run concurrently do not erase each other
        doc = DOC.read_text(encoding="utf-8") if DOC.exists() else HEADER
        if not doc.startswith("# Benchmarks"):
            doc = HEADER + "\n" + doc
        DOC.write_text(_splice(doc, name, section), encoding="utf-8")
        print(f"[bench] {name}: done in {elapsed:.1f} s", file=sys.stderr, flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
