"""Co-segmentation of voxel grids (its evaluation against per-voxel part labels:
:mod:`primkit.segmentation.evaluation`).

A voxel input (binvox) has no faces to label, so its co-segmentation labels voxels: every
occupied voxel goes to its nearest present cuboid (:func:`label_voxels`, the rule of
:mod:`primkit.segmentation.meshes` applied at the voxel centres; :class:`VoxelSegmentation`). Ground truth comes as one part label per
occupied voxel, for example PartNet's part boxes turned into voxel labels for the ShapeNetVox32
chairs (``../shared/data/partnet_chair_boxes/voxlabels.npz``: ``-1`` empty, ``0`` back, ``1``
seat, ``2`` leg/base, ``3`` arm, indexed like :func:`primkit.io.read_voxels`' occupancy).

:func:`primkit.segmentation.evaluation.evaluate_voxels` scores a collection against them.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .. import geometry, io, primitives
from ..model import parts
from ..primitives.palette import part_colors
from . import graphcut, meshes
from .meshes import SegmentationFiles

__all__ = [
    "VoxelSegmentation",
    "segment_voxels",
    "voxel_centres",
    "label_voxels",
]


def voxel_centres(grid: io.VoxelGrid) -> tuple[np.ndarray, np.ndarray]:
    """Centres of the occupied voxels in the grid's model coordinates.

    Returns ``(centres (n, 3) float, index (n, 3) int)``, in ``np.argwhere`` order.
    """
    index = np.argwhere(np.asarray(grid.occupancy, bool))
    res = grid.resolution
    return grid.translate + (index + 0.5) * (grid.scale / res), index


def label_voxels(grid: io.VoxelGrid, cuboids: primitives.Cuboids, *, labelling=None) -> np.ndarray:
    """Primitive index of each occupied voxel: with ``labelling="nearest"`` the nearest present
    cuboid of its centre; with ``"graphcut"`` or None (the default) a graph cut over the occupied
    voxels' 6-neighbourhood started from it (:mod:`primkit.segmentation.graphcut`; a
    :class:`~primkit.segmentation.graphcut.Labelling` also sets the smoothness).

    ``cuboids`` are in the grid's model coordinates (an abstraction's ``cuboids``, in the input's
    frame). Returns ``(R, R, R) int``, -1 for empty voxels.
    """
    centres, index = voxel_centres(grid)
    out = np.full(np.asarray(grid.occupancy).shape, -1, np.int64)
    if len(index):
        labels = meshes.point_labels(centres, cuboids)
        how = graphcut.as_labelling(labelling)
        if how.method_for("voxels") == "graphcut":
            edges, contact, mass = graphcut.voxel_graph(index)
            labels = graphcut.graphcut_labels(centres[:, None, :], edges, contact, mass, cuboids, labels,
                                              how.weight("voxels"))
        out[tuple(index.T)] = labels
    return out


@dataclass(frozen=True, eq=False)
class VoxelSegmentation:
    """The co-segmentation of one voxel grid by its abstraction.

    Attributes
    ----------
    name, source : str
    grid : io.VoxelGrid
        The input grid (model coordinates).
    labels : (R, R, R) int
        Primitive index of each occupied voxel, -1 for empty voxels (indexed like ``grid.occupancy``).
    cuboids : primitives.Cuboids
        The abstraction, in the grid's model coordinates.
    part_names : list of str
    """

    name: str
    source: str
    grid: io.VoxelGrid
    labels: np.ndarray
    cuboids: primitives.Cuboids
    part_names: list = field(default_factory=list)
    #: with a labeller in the model (:mod:`primkit.segmentation.labeller`): each occupied voxel's label, an
    #: index into ``label_names`` (-1: none), and the labeller's names; None without one
    named: np.ndarray | None = None
    label_names: list | None = None

    def part_sizes(self) -> np.ndarray:
        """Voxels assigned to each index: ``(m,) int``."""
        occupied = self.labels[self.labels >= 0]
        return np.bincount(occupied, minlength=self.cuboids.count)

    def boundary_mesh(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The voxels' surface split by part, in model coordinates, for pictures and ``.ply``
        output: ``(vertices (n, 3) float, faces (f, 3) int, face_labels (f,) int)`` (faces between
        two parts' voxels are kept, so each part is a closed block)."""
        vs, fs, ls, offset = [], [], [], 0
        size = self.grid.scale / self.grid.resolution
        for k in np.unique(self.labels[self.labels >= 0]):
            v, f = geometry.voxel_boundary_mesh(self.labels == k, voxel_size=size, origin=self.grid.translate)
            vs.append(v)
            fs.append(f + offset)
            ls.append(np.full(len(f), k, np.int64))
            offset += len(v)
        if not vs:
            return np.zeros((0, 3)), np.zeros((0, 3), np.int64), np.zeros(0, np.int64)
        return np.vstack(vs), np.vstack(fs), np.concatenate(ls)

    def semantic_labels(self) -> tuple[list, np.ndarray]:
        """``(names, codes)``: the distinct part names and each voxel's 1-based name code (-1 empty):
        the labeller's (``named``) when the model has one, else its index's name
        (:func:`primkit.model.parts.label_codes`, the same codes on every shape of a model)."""
        return meshes.semantic_codes(self.labels, self.part_names, self.named, self.label_names)

    def save(self, folder, *, semantic: bool = False, overwrite: bool = False) -> SegmentationFiles:
        """Write ``<name>.voxlabels.npy`` (``(R, R, R) int16``: the part index of each occupied voxel,
        or with ``semantic`` the 1-based code of its name; -1 empty) and ``<name>.parts.ply`` (the
        voxels' surface coloured by part). Returns the :class:`SegmentationFiles` written."""
        folder = Path(folder)
        folder.mkdir(parents=True, exist_ok=True)
        paths = SegmentationFiles(labels=folder / f"{self.name}.voxlabels.npy", mesh=folder / f"{self.name}.parts.ply")
        io.refuse_existing([paths.labels, paths.mesh], overwrite)
        labels = self.semantic_labels()[1] if semantic else self.labels
        io.write_array(paths.labels, labels.astype(np.int16), overwrite=overwrite)
        v, f, lab = self.boundary_mesh()
        io.write_mesh(paths.mesh, v, f, face_colors=part_colors(self.cuboids.count)[lab], overwrite=overwrite)
        return paths


def segment_voxels(grid: io.VoxelGrid, cuboids: primitives.Cuboids, *, name: str = "shape", source: str = "",
                   part_names=None, labelling=None) -> VoxelSegmentation:
    """Co-segment one voxel grid by its abstraction (cuboids in the grid's model coordinates;
    ``labelling`` as in :func:`label_voxels`)."""
    names = list(part_names) if part_names is not None else parts.default_part_names(cuboids.count)
    return VoxelSegmentation(name, source, grid, label_voxels(grid, cuboids, labelling=labelling), cuboids, names)
