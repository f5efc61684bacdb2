"""Forest tiles shared by the echo workers of one server: one file per tile in shared memory.

A tile is a pure function of (forest spec, seed, tile), so whichever worker first needs a tile
builds it and publishes it here; every other worker maps the same pages read-only instead of
building its own copy. A file is written under a temporary name and renamed into place, so a
reader never sees half a tile (two workers racing write the same bytes; the rename is atomic).
The directory is the server's :meth:`hil_bridge.bus.domain.Domain.shared_dir` (``/dev/shm`` on
Linux: RAM); the server removes it when it stops (:meth:`SharedTiles.remove_all`), and a run
that was killed leaves a directory the next :func:`sweep_stale` in that domain removes.

Layout of a tile file (native byte order): a 64-byte header (``b"ELTILE01"``, leaves M and trees
T as int64), then centres (M, 3) f8, normals (M, 3) f8, radii (M,) f8, tree_xy (T, 2) f8,
tree_height (T,) f8, tree_id (M,) i4 and species (T,) i4 (index into the forest's species).
"""

from __future__ import annotations

import contextlib
import os
import shutil
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

from hil_bridge.bus.domain import Domain, shared_root
from sim_core.world.leaves import Leaves
from sim_core.world.tiles import Tile, TileKey

__all__ = ["SharedTiles", "stores_of", "sweep_stale"]

_MAGIC = b"ELTILE01"
_HEADER = 64
_TAG = "tiles"
#: every kind of store a server shares with its children (the echo nodes' pose ring is "poses")
_TAGS = (_TAG, "poses")


class SharedTiles:
    """The tile files in ``directory`` for a forest whose species are ``names`` (in order).

    :meth:`create` makes a fresh directory for a server (its owner); workers open the same
    ``directory``. Counters: ``published`` (files this process wrote), ``mapped`` (tiles this
    process mapped from a file).
    """

    def __init__(self, directory: str | os.PathLike[str], names: Sequence[str]) -> None:
        self.directory = Path(directory)
        self.names = tuple(names)
        self._index = {n: i for i, n in enumerate(self.names)}
        self.published = 0
        self.mapped = 0

    @classmethod
    def create(cls, domain: Domain, names: Sequence[str]) -> SharedTiles:
        """A fresh, empty store in ``domain`` (stale stores of dead processes are removed)."""
        sweep_stale(domain)
        return cls(domain.shared_dir(_TAG), names)

    def path(self, tile: TileKey) -> Path:
        return self.directory / f"{tile[0]}_{tile[1]}.tile"

    def publish(self, tile: TileKey, content: Tile) -> int:
        """Write ``content`` as ``tile`` unless it is already there; returns the file's bytes."""
        path = self.path(tile)
        if path.exists():
            return path.stat().st_size
        leaves = content.leaves
        m, t = len(leaves), content.n_trees
        header = np.zeros(_HEADER // 8, dtype=np.int64)
        header[1:3] = (m, t)
        head = bytearray(header.tobytes())
        head[:8] = _MAGIC
        species = np.asarray([self._index[str(s)] for s in content.tree_species], dtype=np.int32)
        parts = (leaves.centers, leaves.normals, leaves.radii, content.tree_xy,
                 content.tree_height, leaves.tree_id, species)
        tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
        with open(tmp, "wb") as f:
            f.write(head)
            for a in parts:
                f.write(np.ascontiguousarray(a).tobytes())
        os.replace(tmp, path)
        self.published += 1
        return path.stat().st_size

    def load(self, tile: TileKey) -> Tile | None:
        """Tile ``tile`` mapped read-only from its file, or None if nobody published it."""
        try:
            raw = np.memmap(self.path(tile), dtype=np.uint8, mode="r")
        except FileNotFoundError:
            return None
        if raw.size < _HEADER or bytes(raw[:8]) != _MAGIC:
            raise ValueError(f"{self.path(tile)}: not a tile file")
        m, t = (int(v) for v in raw[8:24].view(np.int64))
        out: list[np.ndarray] = []
        at = _HEADER
        for dtype, shape in ((np.float64, (m, 3)), (np.float64, (m, 3)), (np.float64, (m,)),
                             (np.float64, (t, 2)), (np.float64, (t,)), (np.int32, (m,)),
                             (np.int32, (t,))):
            n = int(np.prod(shape)) * np.dtype(dtype).itemsize
            out.append(np.asarray(raw[at:at + n]).view(dtype).reshape(shape))
            at += n
        centers, normals, radii, tree_xy, height, tree_id, species = out
        self.mapped += 1
        names = np.asarray(self.names, dtype=np.str_)
        return Tile(Leaves(centers, normals, radii, tree_id), tree_xy,
                    names[species] if t else np.zeros(0, dtype=np.str_), height)

    def source(
        self, build: Callable[[TileKey], Tile], built: list[tuple[TileKey, int]]
    ) -> Callable[[TileKey], Tile]:
        """A :class:`~sim_core.world.tiles.TiledForest` ``source``: the published tile, else
        ``build`` it, publish it (appending ``(tile, bytes)`` to ``built``) and map it."""

        def fetch(tile: TileKey) -> Tile:
            got = self.load(tile)
            if got is None:
                built.append((tile, self.publish(tile, build(tile))))
                got = self.load(tile)
            if got is None:
                raise FileNotFoundError(self.path(tile))
            return got

        return fetch

    def remove(self, tile: TileKey) -> None:
        """Unlink ``tile``'s file (processes that mapped it keep their pages until they let go)."""
        self.path(tile).unlink(missing_ok=True)

    def remove_all(self) -> None:
        """Remove the store's directory and every file in it, and the domain's directory of
        stores if that leaves it empty (idempotent)."""
        shutil.rmtree(self.directory, ignore_errors=True)
        with contextlib.suppress(OSError):
            self.directory.parent.rmdir()


def _pid_of(store: Path) -> int | None:
    parts = store.name.split("-")
    if len(parts) != 3 or parts[0] not in _TAGS or not parts[1].isdigit():
        return None
    return int(parts[1])


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def sweep_stale(domain: Domain) -> list[Path]:
    """Remove the tile stores (and pose rings) in ``domain`` whose process is gone (a killed
    run's); returns what was removed."""
    base = shared_root() / domain.token
    removed: list[Path] = []
    if not base.is_dir():
        return removed
    for store in base.iterdir():
        pid = _pid_of(store)
        if pid is not None and not _alive(pid):
            shutil.rmtree(store, ignore_errors=True)
            removed.append(store)
    return removed


def stores_of(pid: int) -> list[Path]:
    """Tile stores (and pose rings) of process ``pid`` that still exist, in any domain (the
    test suite's leak guard)."""
    root = shared_root()
    return sorted(s for s in root.glob("*/*-*") if _pid_of(s) == pid)
