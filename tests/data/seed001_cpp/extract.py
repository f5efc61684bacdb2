"""Per-tree statistics of the seed 001 C++ forest, read from its OFF+ mesh (README.md here).

Usage: ``python extract.py out.off+ points.csv trees.csv``. The mesh holds, in creation order,
each branch segment as a cylinder (its top and bottom circles are the non-leaf polygon faces,
top first) and each kept leaf as an 8-gon face flagged 1. A tree starts with the cylinder whose
bottom circle is centred at its (x, 0, z) from points.csv; everything created after it, up to
the next tree's, belongs to it. Lengths are in grammar units (segment length 1).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

COLUMNS = (
    "tree,species,x,z,leaves,segments,height,trunk_radius,mean_base_radius,median_base_radius,"
    "mean_top_over_base,mean_leaf_length,sd_leaf_length,min_leaf_length,max_leaf_length"
)


def read_mesh(path: Path) -> tuple[np.ndarray, list[np.ndarray], np.ndarray]:
    """Vertices (V, 3), non-leaf polygon faces (vertex ids), leaf faces (L, 8)."""
    with path.open("rb") as f:
        if f.readline().strip() != b"OFF":
            raise ValueError(f"{path}: not an OFF file")
        nv, nf, _ = map(int, f.readline().split())
        verts = np.array([f.readline().split()[:3] for _ in range(nv)], dtype=float)
        circles: list[np.ndarray] = []
        leaves: list[np.ndarray] = []
        for _ in range(nf):
            parts = f.readline().split()
            n = int(parts[0])
            if n == 3:
                continue
            ids = np.array(parts[1 : 1 + n], dtype=np.int64)
            (leaves if parts[-1] == b"1" else circles).append(ids)
    return verts, circles, np.array(leaves)


def main(off: Path, points: Path, out: Path) -> None:
    verts, circles, leaves = read_mesh(off)
    top, bottom = circles[0::2], circles[1::2]
    top_c = np.array([verts[t].mean(0) for t in top])
    bot_c = np.array([verts[b].mean(0) for b in bottom])
    base_r = np.array([np.linalg.norm(verts[b] - verts[b].mean(0), axis=1).mean() for b in bottom])
    top_r = np.array([np.linalg.norm(verts[t] - verts[t].mean(0), axis=1).mean() for t in top])
    cyl_first = np.array([min(t.min(), b.min()) for t, b in zip(top, bottom, strict=True)])
    leaf_first = leaves.min(axis=1)
    # template vertices 2 and 6 are (+-0.25, 0.3, 0): 0.5 apart per unit leaf length
    leaf_len = np.linalg.norm(verts[leaves[:, 2]] - verts[leaves[:, 6]], axis=1) / 0.5
    trees = np.loadtxt(points, delimiter=",", ndmin=2)
    at_ground = np.flatnonzero(np.abs(bot_c[:, 1]) < 1e-9)
    starts: list[int] = []
    for x, z, _ in trees:
        here = at_ground[(np.abs(bot_c[at_ground, 0] - x) < 1e-2)
                         & (np.abs(bot_c[at_ground, 2] - z) < 1e-2)]
        starts.append(int(here[here > (starts[-1] if starts else -1)][0]))
    bounds = [*cyl_first[starts].tolist(), verts.shape[0]]
    rows = []
    for i, (x, z, species) in enumerate(trees):
        cyl = (cyl_first >= bounds[i]) & (cyl_first < bounds[i + 1])
        leaf = (leaf_first >= bounds[i]) & (leaf_first < bounds[i + 1])
        values = (
            i + 1, int(species), x, z, int(leaf.sum()), int(cyl.sum()), top_c[cyl, 1].max(),
            base_r[starts[i]], base_r[cyl].mean(), np.median(base_r[cyl]),
            np.mean(top_r[cyl] / base_r[cyl]), leaf_len[leaf].mean(), leaf_len[leaf].std(),
            leaf_len[leaf].min(), leaf_len[leaf].max(),
        )
        rows.append(",".join(str(v) if isinstance(v, int) else f"{v:.6g}" for v in values))
    out.write_text(COLUMNS + "\n" + "\n".join(rows) + "\n", encoding="utf-8")


if __name__ == "__main__":
    main(*(Path(a) for a in sys.argv[1:4]))
