"""Seeded randomness: one :class:`numpy.random.Generator` per subsystem, derived from one seed.

Every stochastic function in :mod:`sim_core` takes ``rng`` as an argument; entry points take a
keyword-only ``seed``. Generators are PCG64 seeded from a :class:`numpy.random.SeedSequence`
(as Gymnasium's ``np_random``). Independent streams are addressed by a *key path*, so that the
stream of, say, tree 7 of species 2 never depends on how many other trees were drawn::

    rng = derive_rng(seed, "forest", species_idx, tree_idx)

Same seed and key path give a bit-identical stream; a different key gives an independent one.
"""

from __future__ import annotations

import zlib

import numpy as np

__all__ = ["derive_rng", "derive_seed_sequence", "make_rng", "spawn"]

SeedLike = int | np.random.SeedSequence | None


def _key_to_int(key: int | str) -> int:
    if isinstance(key, bool) or not isinstance(key, int | str):
        raise TypeError(f"rng key must be an int or a str, got {key!r}")
    if isinstance(key, str):
        return zlib.crc32(key.encode("utf-8"))
    if key < 0:
        raise ValueError(f"rng key must be a non-negative int, got {key}")
    return key


def _check_seed(seed: SeedLike) -> None:
    if seed is None or isinstance(seed, np.random.SeedSequence):
        return
    if isinstance(seed, bool) or not isinstance(seed, int | np.integer):
        raise TypeError(f"seed must be an int or None, got {seed!r}")
    if seed < 0:
        raise ValueError(f"seed must be a non-negative int, got {seed}")


def make_rng(seed: SeedLike = None) -> np.random.Generator:
    """Return a PCG64 generator for ``seed`` (``None``: fresh OS entropy)."""
    _check_seed(seed)
    ss = seed if isinstance(seed, np.random.SeedSequence) else np.random.SeedSequence(seed)
    return np.random.Generator(np.random.PCG64(ss))


def derive_seed_sequence(seed: SeedLike, *key: int | str) -> np.random.SeedSequence:
    """SeedSequence for the stream addressed by ``key`` under ``seed``.

    ``seed=None`` draws fresh entropy (the key still separates streams of that one draw only
    if the caller keeps the returned sequence). Strings in ``key`` map through CRC-32.
    """
    _check_seed(seed)
    ints = tuple(_key_to_int(k) for k in key)
    if isinstance(seed, np.random.SeedSequence):
        return np.random.SeedSequence(seed.entropy, spawn_key=tuple(seed.spawn_key) + ints)
    return np.random.SeedSequence(seed, spawn_key=ints)


def derive_rng(seed: SeedLike, *key: int | str) -> np.random.Generator:
    """Generator for the stream addressed by ``key`` under ``seed`` (see module docstring)."""
    return np.random.Generator(np.random.PCG64(derive_seed_sequence(seed, *key)))


def spawn(rng: np.random.Generator, n: int) -> list[np.random.Generator]:
    """``n`` independent child generators of ``rng`` (``Generator.spawn``)."""
    if n < 0:
        raise ValueError(f"n must be >= 0, got {n}")
    return rng.spawn(n)
