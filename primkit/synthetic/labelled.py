"""The labelled shape: one watertight mesh whose faces carry part indices, the categories' fixed
part names and groups, and :func:`assemble`, the union with provenance that makes one."""

from __future__ import annotations

import operator
from dataclasses import dataclass

import numpy as np
import trimesh

from .solids import checked, union

__all__ = ["CATEGORIES", "PART_NAMES", "PART_GROUPS", "LabelledShape", "assemble"]


CATEGORIES = ("chair", "table", "airplane", "animal")


_LEGS = ("leg_front_left", "leg_front_right", "leg_back_left", "leg_back_right")


PART_NAMES: dict[str, tuple[str, ...]] = {
    "chair": ("seat", "back", *_LEGS, "arm_left", "arm_right", "column", "star_base"),
    "table": ("top", *_LEGS, "pedestal", "foot"),
    "airplane": (
        "fuselage",
        "wing_left",
        "wing_right",
        "tail_left",
        "tail_right",
        "fin",
        "engine_left_inner",
        "engine_right_inner",
        "engine_left_outer",
        "engine_right_outer",
    ),
    "animal": ("torso", "head", "neck", *_LEGS, "tail"),
}


PART_GROUPS: dict[str, dict[str, str]] = {
    "chair": {
        "seat": "seat",
        "back": "back",
        **{leg: "legs" for leg in _LEGS},
        "arm_left": "arms",
        "arm_right": "arms",
        "column": "base",
        "star_base": "base",
    },
    "table": {"top": "top", **{leg: "legs" for leg in _LEGS}, "pedestal": "base", "foot": "base"},
    "airplane": {
        "fuselage": "fuselage",
        "wing_left": "wings",
        "wing_right": "wings",
        "tail_left": "tail",
        "tail_right": "tail",
        "fin": "tail",
        "engine_left_inner": "engines",
        "engine_right_inner": "engines",
        "engine_left_outer": "engines",
        "engine_right_outer": "engines",
    },
    "animal": {
        "torso": "torso",
        "head": "head",
        "neck": "neck",
        **{leg: "legs" for leg in _LEGS},
        "tail": "tail",
    },
}


@dataclass(frozen=True, eq=False)
class LabelledShape:
    """One generated shape: a watertight mesh whose faces are labelled with part indices.

    Attributes
    ----------
    category : str
      One of :data:`CATEGORIES`.
    vertices : (n, 3) float64
      In the canonical frame (+Y up, +X front, bbox centred, longest side 1).
    faces : (f, 3) int64
      Triangles, counter-clockwise seen from outside.
    face_labels : (f,) int64
      ``face_labels[i]`` indexes ``part_names``: the part face ``i`` belongs to.
    part_names : tuple of str
      The category's fixed part names (:data:`PART_NAMES`); absent parts have no faces.
    part_groups : dict of str to str
      Part name to coarse group (:data:`PART_GROUPS`).
    attributes : dict
      The generating attributes, JSON-serialisable plain values, in the units used before
      normalisation.
    seed : int or None
      The seed the shape was generated from.
    """

    category: str
    vertices: np.ndarray
    faces: np.ndarray
    face_labels: np.ndarray
    part_names: tuple[str, ...]
    part_groups: dict[str, str]
    attributes: dict
    seed: int | None

    def __post_init__(self):
        if self.vertices.ndim != 2 or self.vertices.shape[1] != 3:
            raise ValueError("`vertices` must be (n, 3) float")
        if self.faces.ndim != 2 or self.faces.shape[1] != 3:
            raise ValueError("`faces` must be (f, 3) int")
        if self.face_labels.shape != (len(self.faces),):
            raise ValueError("`face_labels` must be (f,) int, one label per face")

    @property
    def present_parts(self) -> tuple[str, ...]:
        """Names of the parts that own at least one face, in ``part_names`` order."""
        present = np.unique(self.face_labels)
        return tuple(self.part_names[i] for i in present)

    def part_faces(self, name: str) -> np.ndarray:
        """Indices of the faces of part ``name``: (k,) int64, empty if the part is absent."""
        return np.flatnonzero(self.face_labels == self.part_names.index(name))

    def to_trimesh(self) -> trimesh.Trimesh:
        """The mesh as a :class:`trimesh.Trimesh`, unprocessed (face order kept)."""
        return trimesh.Trimesh(self.vertices.copy(), self.faces.copy(), process=False)


_EDGES_PER_EXTENT = 15  # longest edge after refinement: the bbox's longest side over this


_SLIVER_VOLUME = 1e-5  # loose union pieces below this fraction of the main one are dropped


def assemble(category: str, parts: dict[str, list], attributes: dict, seed) -> LabelledShape:
    """Union the parts, label faces by provenance and normalise into the canonical frame.

    ``parts`` maps a part name to the solids that make it up (unioned into one original first).
    """
    names = PART_NAMES[category]
    id_to_label = {}
    originals = []
    for name, solids in parts.items():
        original = checked(union(solids), name).as_original()
        id_to_label[original.original_id()] = names.index(name)
        originals.append(original)
    solid = checked(union(originals), f"the {category}")
    pieces = solid.decompose()
    if len(pieces) > 1:
        # Where two surfaces nearly touch, the union can leave a loose sliver of almost no
        # volume; drop those. Anything bigger means the parts do not overlap: a bug.
        volumes = np.array([piece.volume() for piece in pieces])
        kept = [piece for piece, v in zip(pieces, volumes) if v > _SLIVER_VOLUME * volumes.max()]
        if len(kept) != 1:
            raise RuntimeError(f"the parts of the {category} do not form one connected solid")
        solid = kept[0]

    # Split long edges (big flat faces come out of the hulls as a few slivers) so triangles
    # have comparable sizes; provenance survives refinement.
    bbox = np.asarray(solid.bounding_box(), dtype=float)
    solid = solid.refine_to_length(float((bbox[3:] - bbox[:3]).max()) / _EDGES_PER_EXTENT)
    mesh = solid.to_mesh64()
    vertices = np.asarray(mesh.vert_properties, dtype=np.float64)[:, :3]
    faces = np.asarray(mesh.tri_verts, dtype=np.int64)
    merge_from = np.asarray(mesh.merge_from_vert, dtype=np.int64)
    if len(merge_from):  # vertices split by properties; we only keep positions, so merge them
        remap = np.arange(len(vertices))
        remap[merge_from] = np.asarray(mesh.merge_to_vert, dtype=np.int64)
        faces = remap[faces]
        used, faces = np.unique(faces, return_inverse=True)
        faces = faces.reshape(-1, 3)
        vertices = vertices[used]
    # run_index counts triangle-vertex indices (3 per triangle), with a final end marker.
    run_index = np.asarray(mesh.run_index, dtype=np.int64) // 3
    run_labels = np.array([id_to_label[int(i)] for i in mesh.run_original_id], dtype=np.int64)
    face_labels = np.repeat(run_labels, np.diff(run_index))
    if len(face_labels) != len(faces):
        raise RuntimeError("manifold3d provenance does not cover every face")

    lo, hi = vertices.min(axis=0), vertices.max(axis=0)
    vertices = (vertices - (lo + hi) / 2.0) / (hi - lo).max()
    return LabelledShape(
        category=category,
        vertices=np.ascontiguousarray(vertices),
        faces=np.ascontiguousarray(faces),
        face_labels=face_labels,
        part_names=names,
        part_groups=dict(PART_GROUPS[category]),
        attributes=attributes,
        seed=None if seed is None else operator.index(seed),
    )
