"""A tiled, unbounded forest: tiles are built on demand around a query point and cached.

A tile ``(i, j)`` of side ``tile_size_m`` owns the trees whose *base* lies in
``[i·s, (i+1)·s) × [j·s, (j+1)·s)``; it holds their leaves, which may spill into neighbouring
tiles. ``leaves_near(point, r)`` therefore visits every tile within ``r`` plus the maximum crown
reach of ``point``. Tile content is a pure function of (spec, seed, tile) — candidates are drawn
per cell from their own streams and the minimum-distance merge is resolved locally and exactly —
so building a region tile by tile gives the same trees and leaves as a one-shot build of it.
Built tiles sit in an LRU cache bounded in bytes (leaf arrays and the boxes of the gather's
leaf blocks, plus k-d trees where a caller built one). A tile missing
from the cache comes from ``source`` (default :meth:`TiledForest.build`): a runner may put a store
shared between processes in front of the build (``hil_bridge.server.shared_tiles``); ``sim_core``
itself
never does I/O. Tiles outside a bounded forest's domain own no trees and are never visited.
"""

from __future__ import annotations

import math
from collections import OrderedDict
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from sim_core.world.ball import ball_rows, block_bounds
from sim_core.world.forest import Forest, ForestEngine
from sim_core.world.ipp import Box
from sim_core.world.leaves import Leaves
from sim_core.world.spec import ForestFiles, ForestSpec

__all__ = ["Tile", "TileKey", "TileSource", "TiledForest"]

#: bytes charged per cached tile on top of its arrays (Python objects, tree rows)
TILE_OVERHEAD_BYTES = 1024


TileKey = tuple[int, int]


@dataclass(frozen=True, eq=False)
class Tile:
    """The trees a tile owns: their ``leaves`` (tree ids local to the tile, in tree order) and
    one row per tree: ``tree_xy`` (T, 2) m, ``tree_species`` (T,) names, ``tree_height`` (T,) m."""

    leaves: Leaves
    tree_xy: NDArray[np.float64]
    tree_species: NDArray[np.str_]
    tree_height: NDArray[np.float64]

    @property
    def n_trees(self) -> int:
        return int(self.tree_xy.shape[0])


#: where a tile missing from the cache comes from: ``source(tile) -> Tile``
TileSource = Callable[[TileKey], Tile]


class TiledForest:
    """On-demand forest tiles around a query point, deterministic per (seed, tile).

    Args:
        spec: the forest; ``domain`` may be ``None`` (unbounded) or a box (tiles outside empty).
        seed: the forest seed (the same trees as ``build_forest(spec, seed=seed)``).
        files: what the files ``spec`` names hold (:class:`~sim_core.world.spec.ForestFiles`;
            none needed when it names none).
        tile_size_m: tile side, metres.
        max_cache_bytes: LRU bound on the bytes of cached tiles (a single query may still touch
            more; the tiles it needs are built, used and then evicted oldest-first).
        source: gives a tile missing from the cache (default :meth:`build`); it must return
            exactly what :meth:`build` would.
    """

    def __init__(
        self,
        spec: ForestSpec,
        *,
        seed: int,
        files: ForestFiles | None = None,
        tile_size_m: float = 50.0,
        max_cache_bytes: int = 256 * 1024 * 1024,
        source: TileSource | None = None,
    ) -> None:
        if not (math.isfinite(tile_size_m) and tile_size_m > 0):
            raise ValueError(f"tile_size_m must be > 0, got {tile_size_m}")
        if max_cache_bytes < 0:
            raise ValueError(f"max_cache_bytes must be >= 0, got {max_cache_bytes}")
        self.engine = ForestEngine(spec, seed=seed, files=files)
        self.tile_size_m = float(tile_size_m)
        self.max_cache_bytes = int(max_cache_bytes)
        self.reach_m = self.engine.crown_bound()
        self.source: TileSource = self.build if source is None else source
        dom = spec.domain
        self._range = None if dom is None else (*self.tile_of(dom[0], dom[1]),
                                                *self.tile_of(dom[2], dom[3]))
        self._cache: OrderedDict[TileKey, Tile] = OrderedDict()
        #: per cached tile gathered from or ensured, the boxes of its leaf blocks
        #: (:func:`~sim_core.world.ball.block_bounds`)
        self._bounds: dict[TileKey, NDArray[np.float64]] = {}
        self._bytes: dict[TileKey, int] = {}
        self._total = 0
        self.tiles_built = 0
        self.cache_hits = 0
        self.evictions = 0

    # --- tiles --------------------------------------------------------------------------------
    def tile_of(self, x: float, y: float) -> tuple[int, int]:
        s = self.tile_size_m
        return (math.floor(x / s), math.floor(y / s))

    def tile_box(self, tile: tuple[int, int]) -> Box:
        s = self.tile_size_m
        i, j = tile
        return (i * s, j * s, (i + 1) * s, (j + 1) * s)

    def build(self, tile: TileKey) -> Tile:
        """Tile ``tile`` built afresh (not cached): a pure function of (spec, seed, tile)."""
        cands = self.engine.kept_in(self.tile_box(tile))
        forest = self.engine.assemble(cands)
        for k in range(forest.n_trees):
            reach = 0.0
            sel = forest.leaves.tree_id == k
            if sel.any():
                d = forest.leaves.centers[sel, :2] - forest.tree_xy[k]
                reach = float(np.hypot(d[:, 0], d[:, 1]).max())
            if reach > self.reach_m:
                raise ValueError(
                    f"tree of species {forest.tree_species[k]!r} at {forest.tree_xy[k].tolist()} "
                    f"reaches {reach:.2f} m > max_crown_radius_m = {self.reach_m:.2f} m; "
                    "raise forest.max_crown_radius_m"
                )
        self.tiles_built += 1
        return Tile(forest.leaves, forest.tree_xy, forest.tree_species, forest.tree_height)

    def tile(self, tile: TileKey) -> Leaves:
        """Leaves of the trees owned by ``tile`` (tree ids local to the tile), cached."""
        return self._get(tile).leaves

    def ensure(self, tile: TileKey) -> Tile:
        """Tile ``tile`` cached and boxed for the gather (so a later query does not pay for
        building it, nor for its boxes)."""
        got = self._get(tile)
        self._boxes(tile, got)
        self._account(tile, got)
        self._evict()
        return got

    def forget(self, tile: TileKey) -> None:
        """Drop ``tile`` from the cache (it is fetched from ``source`` again when needed)."""
        if self._cache.pop(tile, None) is not None:
            self._bounds.pop(tile, None)
            self._total -= self._bytes.pop(tile)

    def _get(self, tile: TileKey) -> Tile:
        hit = self._cache.get(tile)
        if hit is not None:
            self._cache.move_to_end(tile)
            self.cache_hits += 1
            return hit
        got = self.source(tile)
        self._cache[tile] = got
        self._account(tile, got)
        self._evict()
        return got

    def _boxes(self, tile: TileKey, got: Tile) -> NDArray[np.float64]:
        """The boxes of ``got``'s leaf blocks: built the first time, kept while it is cached
        (not for a tile evicted on arrival)."""
        bounds = self._bounds.get(tile)
        if bounds is None:
            bounds = block_bounds(got.leaves.centers)
            if tile in self._cache:
                self._bounds[tile] = bounds
        return bounds

    def _account(self, tile: TileKey, got: Tile) -> None:
        if tile in self._cache:
            boxes = self._bounds.get(tile)
            new = (got.leaves.nbytes + (0 if boxes is None else boxes.nbytes)
                   + TILE_OVERHEAD_BYTES)
            self._total += new - self._bytes.get(tile, 0)
            self._bytes[tile] = new

    def _evict(self) -> None:
        while self._cache and self._total > self.max_cache_bytes:
            old, _ = self._cache.popitem(last=False)
            self._bounds.pop(old, None)
            self._total -= self._bytes.pop(old)
            self.evictions += 1

    @property
    def cache_bytes(self) -> int:
        """Bytes held by the cached tiles (leaf arrays and their blocks' boxes, built k-d trees,
        a fixed overhead)."""
        return self._total

    @property
    def cached_tiles(self) -> list[TileKey]:
        return list(self._cache)

    # --- queries ------------------------------------------------------------------------------
    def tiles_near(self, point: ArrayLike, radius_m: float) -> list[TileKey]:
        """Tiles that may hold leaves within ``radius_m`` of ``point`` (crown reach included;
        tiles outside a bounded domain own no tree and are left out)."""
        p = np.asarray(point, dtype=np.float64)
        if p.shape != (3,) or not np.all(np.isfinite(p)):
            raise ValueError(f"point must be a finite (3,) array, got {p.tolist()}")
        if not (math.isfinite(radius_m) and radius_m >= 0):
            raise ValueError(f"radius_m must be a finite distance >= 0, got {radius_m!r}")
        reach = radius_m + self.reach_m
        i0, j0 = self.tile_of(p[0] - reach, p[1] - reach)
        i1, j1 = self.tile_of(p[0] + reach, p[1] + reach)
        if self._range is not None:
            i0, j0 = max(i0, self._range[0]), max(j0, self._range[1])
            i1, j1 = min(i1, self._range[2]), min(j1, self._range[3])
        out = []
        for i in range(i0, i1 + 1):
            for j in range(j0, j1 + 1):
                x0, y0, x1, y1 = self.tile_box((i, j))
                dx = max(x0 - p[0], 0.0, p[0] - x1)
                dy = max(y0 - p[1], 0.0, p[1] - y1)
                if math.hypot(dx, dy) <= reach:
                    out.append((i, j))
        return out

    def leaves_near(self, point: ArrayLike, radius_m: float) -> Leaves:
        """Leaves whose centre is within ``radius_m`` of ``point (3,)`` (metres, world frame).

        Tree ids in the result are renumbered to be unique within it (tile by tile). Each tile's
        leaves are tested by :func:`~sim_core.world.ball.ball_rows` (compiled; blocks of leaves
        beyond the ball skipped by their boxes): the leaves keep their order, tile after tile in
        :meth:`tiles_near`'s order.
        """
        p = np.asarray(point, dtype=np.float64)
        parts: list[Leaves] = []
        offset = 0
        for t in self.tiles_near(p, radius_m):
            tile = self._get(t)
            leaves = tile.leaves
            bounds = self._boxes(t, tile)
            self._account(t, tile)  # a tile evicted on arrival stays out
            rows = ball_rows(leaves.centers, bounds, p, radius_m)
            if rows.shape[0]:
                parts.append(Leaves(leaves.centers.take(rows, axis=0),
                                    leaves.normals.take(rows, axis=0),
                                    leaves.radii.take(rows),
                                    leaves.tree_id.take(rows) + offset))
            offset += tile.tree_xy.shape[0]
        self._evict()
        return Leaves.concat(parts)

    def trees_in_tiles(self, tiles: list[TileKey]) -> Forest:
        """The trees owned by ``tiles`` assembled tile by tile (through the cache)."""
        xy, sp, hs, parts = [], [], [], []
        offset = 0
        for t in tiles:
            tile = self._get(t)
            parts.append(
                Leaves(tile.leaves.centers, tile.leaves.normals, tile.leaves.radii,
                       tile.leaves.tree_id + offset)
            )
            xy.append(tile.tree_xy)
            sp.append(tile.tree_species)
            hs.append(tile.tree_height)
            offset += tile.tree_xy.shape[0]
        leaves = Leaves.concat(parts)
        tree_xy = np.concatenate(xy) if xy else np.zeros((0, 2))
        species = np.concatenate(sp) if sp else np.zeros(0, dtype=np.str_)
        heights = np.concatenate(hs) if hs else np.zeros(0)
        return Forest(leaves, tree_xy, species, heights, tuple(self.engine.names))
