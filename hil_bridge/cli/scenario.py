"""``echoloop scenario fig6|fig7|table1``: the seed 000 sonar scenarios as PNGs and tables.

Examples::

    echoloop scenario fig6 --out out/fig6
    echoloop scenario fig7 --out out/fig7 --seed 3 --json
    echoloop scenario table1 --out out/table1 --fidelity fast --repeat 3
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path
from typing import Any

import numpy as np

from hil_bridge.outputs import atomic_output, check_output
from sim_core.sonar import FIDELITIES, Echo, EchoParams, synthesize
from sim_core.sonar.scenarios import (
    TABLE1_BEAMWIDTHS_DEG,
    TABLE1_POSITIONS,
    TABLE1_SEED_SECONDS,
    Ping,
    fig6_scene,
    fig7_scene,
    maple_cluster,
    table1_setups,
)
from sim_core.world import Leaves

__all__ = ["main", "run_pings", "table1_markdown", "time_table1"]


def run_pings(
    leaves: Leaves, pings: list[Ping], params: EchoParams, fidelity: str
) -> tuple[list[Echo], list[float]]:
    """Echo and wall-clock seconds of each ping."""
    echoes, seconds = [], []
    for ping in pings:
        t0 = time.perf_counter()
        echoes.append(synthesize(leaves, ping.beam, params, fidelity=fidelity))
        seconds.append(time.perf_counter() - t0)
    return echoes, seconds


def time_table1(
    fidelity: str, *, seed: int = 0, repeat: int = 1, params: EchoParams | None = None
) -> tuple[dict[str, dict[int, list[float]]], dict[str, dict[int, list[int]]]]:
    """Table 1 cells: seconds[setup][factor][T-1] (best of ``repeat``) and leaves in beam."""
    params = EchoParams() if params is None else params
    seconds: dict[str, dict[int, list[float]]] = {
        "circular": {k: [] for k in TABLE1_POSITIONS},
        "fixed": {b: [] for b in TABLE1_BEAMWIDTHS_DEG},
    }
    leaves_in: dict[str, dict[int, list[int]]] = {
        s: {k: [] for k in cells} for s, cells in seconds.items()
    }
    for trees in range(1, 6):
        forest = maple_cluster(trees, seed=seed)
        for setup, cells in table1_setups(forest).items():
            for factor, pings in cells.items():
                best = float("inf")
                for _ in range(repeat):
                    echoes, secs = run_pings(forest.leaves, pings, params, fidelity)
                    best = min(best, float(sum(secs)))
                seconds[setup][factor].append(best)
                leaves_in[setup][factor].append(int(sum(e.leaves_in_beam for e in echoes)))
    return seconds, leaves_in


def table1_markdown(seconds: dict[str, dict[int, list[float]]], label: str) -> str:
    """Table 1 in the paper's shape: cells "ours ms (seed s)"."""
    lines = []
    for setup, head in (("circular", "I. Circular path: positions"),
                        ("fixed", "II. Fixed position: beamwidth (deg)")):
        lines.append(f"| {head} | " + " | ".join(f"T = {t}" for t in range(1, 6)) + " |")
        lines.append("|---" * 6 + "|")
        for factor in sorted(seconds[setup]):
            cells = [
                f"{seconds[setup][factor][t] * 1e3:.1f} ms ({TABLE1_SEED_SECONDS[setup][factor][t]}"
                " s)"
                for t in range(5)
            ]
            lines.append(f"| {factor} | " + " | ".join(cells) + " |")
        lines.append("")
    return f"{label}: measured total time, seed MATLAB in parentheses\n\n" + "\n".join(lines)


def _summary(pings: list[Ping], echoes: list[Echo], seconds: list[float]) -> list[dict[str, Any]]:
    return [
        {
            "ping": p.label,
            "position": [round(float(x), 3) for x in p.beam.position],
            "beamwidth_deg": round(float(np.degrees(p.beam.beamwidth_rad)), 2),
            "leaves_in_beam": e.leaves_in_beam,
            "seconds": s,
            "error_bound": e.error_bound,
        }
        for p, e, s in zip(pings, echoes, seconds, strict=True)
    ]


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(
        prog="echoloop scenario", description="Run a seed 000 sonar scenario (Figs 6-7, Table 1)."
    )
    parser.add_argument("name", choices=["fig6", "fig7", "table1"])
    parser.add_argument("--out", type=Path, required=True, help="output directory")
    parser.add_argument("--seed", type=int, default=0, help="forest / beamwidth seed")
    parser.add_argument("--fidelity", default="fast", choices=sorted(FIDELITIES))
    parser.add_argument("--repeat", type=int, default=1, help="table1: best of this many runs")
    parser.add_argument("--json", action="store_true", help="print a JSON summary")
    parser.add_argument("--overwrite", action="store_true",
                        help="replace the scenario's files if they exist in --out")
    args = parser.parse_args(argv)
    if args.seed < 0:
        raise ValueError(f"--seed must be >= 0, got {args.seed}")
    if args.repeat < 1:
        raise ValueError(f"--repeat must be >= 1, got {args.repeat}")
    if args.out.exists() and not args.out.is_dir():
        raise ValueError(f"--out {args.out}: exists and is not a directory")
    names = {"fig6": ["fig6.png"], "fig7": ["fig7.png"], "table1": ["table1.png", "table1.md"]}
    for name in names[args.name]:  # refuse before computing anything
        check_output(args.out / name, overwrite=args.overwrite)
    from hil_bridge.plots import sonar as plots

    params = EchoParams()
    result: dict[str, Any] = {"scenario": args.name, "fidelity": args.fidelity}
    if args.name == "fig6":
        leaves, pings = fig6_scene(seed=args.seed)
        echoes, secs = run_pings(leaves, pings, params, args.fidelity)
        png = args.out / "fig6.png"
        with atomic_output(png, overwrite=args.overwrite) as tmp:
            plots.plot_fig6(leaves, pings, echoes, params, tmp)
        result.update(pings=_summary(pings, echoes, secs), figure=str(png))
    elif args.name == "fig7":
        forest, pings, _ = fig7_scene(seed=args.seed)
        echoes, secs = run_pings(forest.leaves, pings, params, args.fidelity)
        png = args.out / "fig7.png"
        with atomic_output(png, overwrite=args.overwrite) as tmp:
            plots.plot_fig7(forest.leaves, pings, echoes, params, tmp)
        result.update(pings=_summary(pings, echoes, secs), figure=str(png))
    else:
        seconds, leaves_in = time_table1(args.fidelity, seed=args.seed, repeat=args.repeat)
        png, md = args.out / "table1.png", args.out / "table1.md"
        with atomic_output(png, overwrite=args.overwrite) as tmp:
            plots.plot_table1(seconds, args.fidelity, tmp)
        with atomic_output(md, overwrite=args.overwrite) as tmp:
            tmp.write_text(table1_markdown(seconds, args.fidelity) + "\n", encoding="utf-8")
        result.update(seconds=seconds, leaves_in_beam=leaves_in, figure=str(png), table=str(md))
    if args.json:
        print(json.dumps(result))
    else:
        print(f"wrote {result['figure']}" + (f" and {result['table']}" if "table" in result
                                            else ""))
    return 0
