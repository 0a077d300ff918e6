"""The co-segmentation rule on point clouds: each point to its nearest present cuboid
(:func:`primkit.segmentation.meshes.point_labels`), written as a label per point."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .. import io, primitives
from ..model import parts
from ..primitives.palette import part_colors
from . import graphcut
from .meshes import SegmentationFiles, point_labels, semantic_codes

__all__ = ["PointSegmentation", "segment_points"]


@dataclass(frozen=True, eq=False)
class PointSegmentation:
    """The co-segmentation of one point cloud by its abstraction.

    Attributes
    ----------
    name, source : str
    points : (n, 3) float
        The input's points, in its own frame.
    labels : (n,) int
        Primitive index of each point (-1 when no part is present).
    cuboids : primitives.Cuboids
        The abstraction, in the points' frame.
    part_names : list of str
    """

    name: str
    source: str
    points: np.ndarray
    labels: np.ndarray
    cuboids: primitives.Cuboids
    part_names: list = field(default_factory=list)
    #: with a labeller in the model (:mod:`primkit.segmentation.labeller`): each point's label, an
    #: index into ``label_names`` (-1: none), and the labeller's names; None without one
    named: np.ndarray | None = None
    label_names: list | None = None

    def part_sizes(self) -> np.ndarray:
        """Points assigned to each index: ``(m,) int``."""
        return np.bincount(self.labels[self.labels >= 0], minlength=self.cuboids.count)

    def semantic_labels(self) -> tuple[list, np.ndarray]:
        """``(names, codes)``: the distinct part names and each point's 1-based name code (-1 unassigned):
        the labeller's (``named``) when the model has one, else its index's name
        (:func:`primkit.model.parts.label_codes`, the same codes on every shape of a model)."""
        return semantic_codes(self.labels, self.part_names, self.named, self.label_names)

    def save(self, folder, *, semantic: bool = False, overwrite: bool = False) -> SegmentationFiles:
        """Write ``<name>.parts.npy`` (``(n,) int16``: the part index of each point, in input order,
        or with ``semantic`` the 1-based code of its name) and ``<name>.parts.ply`` (the points with
        the PLY property ``part`` and their part's colour). Returns the :class:`SegmentationFiles` written."""
        folder = Path(folder)
        folder.mkdir(parents=True, exist_ok=True)
        paths = SegmentationFiles(labels=folder / f"{self.name}.parts.npy", mesh=folder / f"{self.name}.parts.ply")
        io.refuse_existing([paths.labels, paths.mesh], overwrite)
        labels = self.semantic_labels()[1] if semantic else self.labels
        io.write_array(paths.labels, labels.astype(np.int16), overwrite=overwrite)
        palette = np.vstack([part_colors(max(self.cuboids.count, 1)), [[200, 200, 200]]]).astype(np.uint8)
        io.write_points(paths.mesh, self.points, labels=labels, colors=palette[np.where(self.labels < 0, -1, self.labels)],
                        overwrite=overwrite)
        return paths


def segment_points(cloud: io.PointCloud, cuboids: primitives.Cuboids, *, name: str = "shape", source: str = "",
                   part_names=None, labelling=None) -> PointSegmentation:
    """Co-segment one point cloud by its abstraction (cuboids in the cloud's frame).

    ``labelling``: ``"nearest"`` (each point to its nearest cuboid), ``"graphcut"`` or None (the
    default: a graph cut over the points' 8-NN graph) or a
    :class:`primkit.segmentation.graphcut.Labelling`."""
    names = list(part_names) if part_names is not None else parts.default_part_names(cuboids.count)
    points = np.asarray(cloud.points, float)
    labels = point_labels(points, cuboids) if cuboids.existence.any() else np.full(len(points), -1, np.int64)
    how = graphcut.as_labelling(labelling)
    if how.method_for("points") == "graphcut" and cuboids.existence.any():
        edges, contact, mass = graphcut.point_graph(points)
        labels = graphcut.graphcut_labels(points[:, None, :], edges, contact, mass, cuboids, labels, how.weight("points"))
    return PointSegmentation(name, source, points, np.asarray(labels, np.int64), cuboids, names)
