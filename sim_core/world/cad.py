"""CAD-template dressing of a GMT3 skeleton (seed 000 §2A.3).

The L-system gives the first-level branch positions on the trunk; a user-supplied template (a
leaf cluster, optionally a branch mesh) is placed on every non-vertical skeleton branch of level
``on_level``:

* template: a leaf cluster mesh (OBJ/STL read by ``hil_bridge.files.world``, here as a
  :class:`Mesh` of arrays) in its frame: +x along the branch (outwards), up = ``up_axis``
  (Blender OBJ: ``"y"``), the branch root at the template origin;
* rotation about z to the branch azimuth plus a random twist ``U(0, twist_max_deg)`` (the seed's
  ``rand_a``);
* scale by level: the template's x-extent is scaled to the branch length, which shrinks by the
  L-system ratios level by level (the seed's ``1/(tmp_i·ns + 1)`` plays the same role);
* leaves: each template face (``leaf_from="faces"``) becomes a leaf with centre = face centroid,
  normal = face normal rotated with the template (the seed forgets to rotate it; we do not),
  radius = equivalent disc sqrt(area/π); or each vertex (``"vertices"``) with its vertex normal
  and a radius drawn from the species' leaf-radius distribution.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from sim_core.world.geometry import rotz
from sim_core.world.trees import GMT3Tree, TreeGeometry, _leaf_radii

__all__ = ["CadTree", "Mesh", "Template", "make_template"]

F64 = NDArray[np.float64]


@dataclass(frozen=True, eq=False)
class Mesh:
    """A triangle mesh as the arrays a template uses (read from OBJ/STL by
    ``hil_bridge.files.world.load_mesh``), in the file's own axes.

    Attributes:
        vertices: (V, 3) vertex positions.
        vertex_normals: (V, 3) vertex normals.
        face_centers: (F, 3) triangle centroids.
        face_normals: (F, 3) triangle normals.
        face_areas: (F,) triangle areas.
        edges: (E, 2) vertex indices of the unique edges.
    """

    vertices: F64
    vertex_normals: F64
    face_centers: F64
    face_normals: F64
    face_areas: F64
    edges: NDArray[np.int64]


@dataclass(frozen=True, eq=False)
class Template:
    """A template in its own frame converted to z up (arrays read-only by convention).

    Attributes:
        points: (K, 3) leaf centres (face centroids or vertices).
        normals: (K, 3) unit normals.
        areas: (K,) face areas (zeros for vertex leaves).
        edges: (E, 2, 3) branch-mesh edges (empty without a branch template).
        length: x-extent of the template (the branch length it represents).
        leaf_from: whether the leaves are the leaf mesh's ``faces`` or its ``vertices``.
    """

    points: F64
    normals: F64
    areas: F64
    edges: F64
    length: float
    leaf_from: Literal["faces", "vertices"] = "faces"


def _to_z_up(v: F64, up_axis: str) -> F64:
    if up_axis == "z":
        return v
    return np.stack([v[:, 0], -v[:, 2], v[:, 1]], axis=1)  # y up -> z up


def make_template(
    leaf: Mesh,
    branch: Mesh | None = None,
    *,
    leaf_from: Literal["faces", "vertices"] = "faces",
    up_axis: Literal["y", "z"] = "y",
    source: str = "<mesh>",
) -> Template:
    """The template of a leaf (and branch) mesh; ``ValueError`` naming ``source`` (the leaf
    mesh's file) when it has no usable leaves or no extent along +x."""
    if leaf_from == "faces":
        pts = np.asarray(leaf.face_centers, dtype=np.float64)
        nrm = np.asarray(leaf.face_normals, dtype=np.float64)
        areas = np.asarray(leaf.face_areas, dtype=np.float64)
    else:
        pts = np.asarray(leaf.vertices, dtype=np.float64)
        nrm = np.asarray(leaf.vertex_normals, dtype=np.float64)
        areas = np.zeros(pts.shape[0])
    good = np.all(np.isfinite(nrm), axis=1) & (np.linalg.norm(nrm, axis=1) > 0.5)
    pts, nrm, areas = _to_z_up(pts[good], up_axis), _to_z_up(nrm[good], up_axis), areas[good]
    if pts.shape[0] == 0:
        raise ValueError(f"template {source}: no usable leaf faces/vertices")
    edges = np.zeros((0, 2, 3))
    all_x = [pts[:, 0]]
    if branch is not None:
        verts = _to_z_up(np.asarray(branch.vertices, dtype=np.float64), up_axis)
        edges = verts[np.asarray(branch.edges)]
        all_x.append(verts[:, 0])
    xs = np.concatenate(all_x)
    length = float(xs.max() - min(xs.min(), 0.0))
    if not length > 0:
        raise ValueError(f"template {source}: needs a positive extent along +x (the branch axis)")
    return Template(pts, nrm / np.linalg.norm(nrm, axis=1, keepdims=True), areas, edges, length,
                    leaf_from)


@dataclass(frozen=True)
class CadTree:
    """A GMT3 skeleton dressed with a CAD template (see module docstring)."""

    skeleton: GMT3Tree
    template: Template
    on_level: int = 1
    twist_max_deg: float = 15.0

    def __post_init__(self) -> None:
        if self.on_level < 1:
            raise ValueError(f"on_level must be >= 1, got {self.on_level}")

    @property
    def unit_m(self) -> float:
        return self.skeleton.unit_m

    def with_growth_level(self, level: int) -> CadTree:
        return dataclasses.replace(self, skeleton=self.skeleton.with_growth_level(level))

    def grow(self, rng: np.random.Generator, *, branches: bool = False) -> TreeGeometry:
        tpl = self.template
        skel, scale = self.skeleton.skeleton(rng)
        use = (skel.level == self.on_level) & ~skel.main_axis
        use &= np.hypot(skel.vec[:, 0], skel.vec[:, 1]) > 1e-9
        start, vec = skel.start[use] * scale, skel.vec[use] * scale
        b = start.shape[0]
        az = np.arctan2(vec[:, 1], vec[:, 0]) + np.radians(
            rng.uniform(0.0, self.twist_max_deg, size=b)
        )
        s = np.linalg.norm(vec, axis=1) / tpl.length  # (B,)
        R = rotz(az)  # (B, 3, 3)
        k = tpl.points.shape[0]
        centers = (start[:, None, :] + s[:, None, None] * np.einsum("bij,kj->bki", R, tpl.points))
        normals = np.einsum("bij,kj->bki", R, tpl.normals)
        if tpl.leaf_from == "faces":
            radii = np.sqrt(tpl.areas[None, :] * s[:, None] ** 2 / np.pi)
            radii = np.maximum(radii, 1e-3).reshape(-1)
        else:
            sk = self.skeleton
            radii = _leaf_radii(rng, sk.leaf_radius_mean_m, sk.leaf_radius_sd_m, b * k)
        geo = TreeGeometry(centers.reshape(-1, 3), normals.reshape(-1, 3), radii)
        if branches:
            seg_s = [skel.start * scale]
            seg_e = [skel.end * scale]
            seg_r = [skel.radius * scale]
            if tpl.edges.shape[0]:
                e = start[:, None, None, :] + s[:, None, None, None] * np.einsum(
                    "bij,epj->bepi", R, tpl.edges
                )
                seg_s.append(e[:, :, 0].reshape(-1, 3))
                seg_e.append(e[:, :, 1].reshape(-1, 3))
                seg_r.append(np.full(e.shape[0] * e.shape[1], float(skel.radius.min() * scale)))
            geo = dataclasses.replace(
                geo,
                seg_start=np.concatenate(seg_s),
                seg_end=np.concatenate(seg_e),
                seg_radius=np.concatenate(seg_r),
            )
        return geo
