"""``echoloop forest``: generate procedural forests (sim_core.world).

    echoloop forest generate (--preset NAME | --scene FILE.yaml) [--seed N] --out FILE.npz
                             [--plot FILE.png] [--json]
    echoloop forest presets

The ``.npz`` holds ``centers (M,3)``, ``normals (M,3)``, ``radii (M,)``, ``tree_id (M,)``,
``tree_xy (T,2)``, ``tree_species (T,)`` (and ``tree_height (T,)``). ``--json`` prints one JSON
object: ``trees``, ``leaves``, ``species`` (name -> tree count), ``seconds``.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

from hil_bridge.outputs import atomic_output, check_output

__all__ = ["main"]


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="echoloop forest", description=__doc__.split("\n")[0])
    sub = parser.add_subparsers(dest="action", required=True)
    gen = sub.add_parser("generate", help="build a forest and save its leaves as .npz")
    src = gen.add_mutually_exclusive_group(required=True)
    src.add_argument(
        "--preset", metavar="NAME", help="a named forest (see 'echoloop forest presets')"
    )
    src.add_argument("--scene", metavar="FILE.yaml", type=Path, help="a ForestSpec YAML file")
    gen.add_argument("--seed", type=int, default=0, help="forest seed (default 0)")
    gen.add_argument("--out", type=Path, required=True, metavar="FILE.npz", help="output file")
    gen.add_argument("--plot", type=Path, metavar="FILE.png", help="also write a forest figure")
    gen.add_argument("--json", action="store_true", help="print a JSON summary on stdout")
    gen.add_argument("--overwrite", action="store_true", help="replace existing outputs")
    sub.add_parser("presets", help="list the preset names")
    return parser


def main(argv: list[str]) -> int:
    args = _parser().parse_args(argv)
    from hil_bridge.files.world import load_forest_files, load_forest_spec, save_forest
    from sim_core.world import build_forest, get_preset, preset_names

    if args.action == "presets":
        for name in preset_names():
            print(name)
        return 0
    if args.seed < 0:
        raise ValueError(f"--seed must be >= 0, got {args.seed}")
    if args.out.suffix != ".npz":
        raise ValueError(f"--out must name a .npz file, got {str(args.out)!r}")
    inputs = [args.scene] if args.scene is not None else []
    for out in (args.out, args.plot):
        if out is not None:  # refuse before building anything
            check_output(out, overwrite=args.overwrite, inputs=inputs)
    spec = get_preset(args.preset) if args.preset else load_forest_spec(args.scene)
    t0 = time.perf_counter()
    try:
        forest = build_forest(spec, seed=args.seed, files=load_forest_files(spec))
    except ValueError as exc:  # the spec cannot be built (e.g. a huge intensity): name its file
        if args.scene is None:
            raise
        raise ValueError(f"{args.scene}: {exc}") from None
    seconds = time.perf_counter() - t0
    with atomic_output(args.out, overwrite=args.overwrite, inputs=inputs) as tmp:
        save_forest(forest, tmp)
    if args.plot is not None:
        from hil_bridge.plots.world import plot_forest

        with atomic_output(args.plot, overwrite=args.overwrite, inputs=inputs) as tmp:
            plot_forest(forest, tmp, title=args.preset or args.scene.name)
    counts = forest.species_counts()
    summary = {
        "trees": forest.n_trees,
        "leaves": len(forest.leaves),
        "species": counts,
        "seconds": round(seconds, 4),
    }
    if args.json:
        print(json.dumps(summary))
    else:
        listed = ", ".join(f"{k}: {v}" for k, v in counts.items())
        print(
            f"{forest.n_trees} trees ({listed}), {len(forest.leaves)} leaves in {seconds:.2f} s "
            f"-> {args.out}",
            file=sys.stderr,
        )
    return 0
