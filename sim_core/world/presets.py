"""Named forest presets (``echoloop forest generate --preset NAME``).

* ``single-maple`` — one seed 000 GMT3 maple at the origin.
* ``seed000-fig5d`` — seed 000 Fig 5(d): 4 maples + 1 bush on 20 × 20 m with the paper's
  intensities λ₁ = 0.4·exp(−(x−5)²/5 − (y−5)²/6) (maples) and λ₂ = 0.3·exp(−(x−15)²/3 −
  (y−15)²/6) (bush), each IPP conditioned on the figure's count. The hazelnut CAD file is missing
  from the seed, so the bush is the GMT3 ``hazelnut-bush`` shrub.
* ``seed001-fig9`` — seed 001 Figs 8-10: the 31-tree, 4-species map after 16 m thinning
  (the packaged tree map :data:`SEED001_TREE_MAP`, 1 unit = 1 m), species tree4..tree7.
* ``seed001-ipp`` — the same species drawn afresh: one IPP per species with the code's effective
  intensity λ*²·exp(−‖s−μ‖²/4000) on [0, 300]² m, merged with 16 m minimum distance.
* ``seed001-species`` — one tree of each seed 001 species in a row, 25 m apart (Fig 7).

The tree4..tree7 species grow from packaged grammars and ``seed001-fig9`` reads a packaged tree
map: their files are named here and read by the I/O layer
(``hil_bridge.files.world.load_forest_files``).
"""

from __future__ import annotations

from sim_core.world.spec import ForestSpec, KernelSpec, SpeciesSpec

__all__ = ["PRESETS", "SEED001_TREE_MAP", "get_preset", "preset_names"]

#: the packaged seed 001 tree map (``x, y, species``), named as a packaged table: a name with
#: no suffix and no directory
SEED001_TREE_MAP = "seed001_forest_points"


def _single_maple() -> ForestSpec:
    return ForestSpec(species=(SpeciesSpec("maple", tree="maple", positions=((0.0, 0.0),)),))


def _seed000_fig5d() -> ForestSpec:
    return ForestSpec(
        domain=(0.0, 0.0, 20.0, 20.0),
        species=(
            SpeciesSpec(
                "maple", tree="maple", count=4,
                kernels=(KernelSpec(peak=0.4, center=(5.0, 5.0), div=(5.0, 6.0)),),
            ),
            SpeciesSpec(
                "hazelnut", tree="hazelnut-bush", count=1,
                kernels=(KernelSpec(peak=0.3, center=(15.0, 15.0), div=(3.0, 6.0)),),
            ),
        ),
    )


_FG_SPECIES = ("tree4", "tree5", "tree6", "tree7")


def _seed001_fig9() -> ForestSpec:
    return ForestSpec(
        domain=(0.0, 0.0, 300.0, 300.0),
        species=tuple(SpeciesSpec(name, tree=name) for name in _FG_SPECIES),
        tree_map=SEED001_TREE_MAP,
    )


def _seed001_ipp() -> ForestSpec:
    # IPP_new.m: sig_fn = λ*·exp(−‖s−μ‖²/4000), kept with probability sig_fn/λ* after drawing at
    # rate λ*, i.e. the effective intensity λ*²·exp(...) (spec §2B.6 "code quirk").
    params = {
        "tree4": ((61.0, 91.0), 0.032),
        "tree5": ((62.0, 141.0), 0.0285),
        "tree6": ((71.0, 221.0), 0.0267),
        "tree7": ((205.0, 103.0), 0.0305),
    }
    return ForestSpec(
        domain=(0.0, 0.0, 300.0, 300.0),
        min_distance_m=16.0,
        species=tuple(
            SpeciesSpec(
                name, tree=name,
                kernels=(KernelSpec(peak=lam**2, center=mu, div=(4000.0, 4000.0)),),
            )
            for name, (mu, lam) in params.items()
        ),
    )


def _seed001_species() -> ForestSpec:
    return ForestSpec(
        species=tuple(
            SpeciesSpec(name, tree=name, positions=((25.0 * i, 0.0),))
            for i, name in enumerate(_FG_SPECIES)
        ),
    )


PRESETS = {
    "single-maple": _single_maple,
    "seed000-fig5d": _seed000_fig5d,
    "seed001-fig9": _seed001_fig9,
    "seed001-ipp": _seed001_ipp,
    "seed001-species": _seed001_species,
}


def preset_names() -> list[str]:
    return sorted(PRESETS)


def get_preset(name: str) -> ForestSpec:
    """The named :class:`ForestSpec`; unknown names raise ``ValueError`` listing the presets."""
    try:
        factory = PRESETS[name]
    except KeyError:
        raise ValueError(f"unknown preset {name!r}; expected one of {preset_names()}") from None
    return factory()
