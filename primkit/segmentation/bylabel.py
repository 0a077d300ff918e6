"""Parts by label: what a name means on each shape when the model has a labeller.

Without a labeller a part name selects part *indices* (:func:`primkit.model.parts.resolve_parts`),
the same on every shape. With one (:mod:`primkit.segmentation.labeller`), ``arms`` means the
elements the labeller calls arms *on that shape*, whichever cuboids hold them:

* ``embed --parts arms`` / ``similar --parts arms`` (and the embedding explorer) describe each
  shape's labelled voxels (:func:`labelled_grid` here, then :class:`primkit.embedding.RegionTable`
  and :class:`primkit.embedding.RegionDescriptor`); :func:`label_regions` gives them to
  :func:`primkit.embedding.label_boxes`, one box per label;
* ``edit --scale arms=1.2`` edits the cuboids whose surface the labeller mostly calls arms on that
  mesh (:func:`primkit.segmentation.labeller.names_by_index`).

:func:`by_label` says when a ``--parts`` text goes by label: every item is one of the labeller's
names. An index (``3``, ``part3``), ``all`` or a name only the index table knows keeps the
index-based meaning.
"""

from __future__ import annotations

import numpy as np

from .. import geometry, io
from .labeller import grid_elements, label_elements, mesh_elements, point_elements

__all__ = ["by_label", "labelled_voxels", "labelled_grid", "label_regions", "labelled_surface"]


def by_label(spec, label_names) -> list | None:
    """The labels ``spec`` names, in ``label_names``' spelling, when every item of it is one of
    them (case-insensitive; ``"arms"``, ``"back,seat"``); None otherwise (no spec, ``all``, an
    index, or a name the labeller does not know: the index-based meaning applies)."""
    if spec is None or label_names is None:
        return None
    items = spec.split(",") if isinstance(spec, str) else list(spec)
    items = [str(i).strip() for i in items if str(i).strip()]
    lower = {str(n).lower(): str(n) for n in label_names}
    if not items or any(i.lower() not in lower for i in items):
        return None
    return list(dict.fromkeys(lower[i.lower()] for i in items))


def labelled_voxels(labeller, occupancy, canonical) -> tuple[np.ndarray, np.ndarray]:
    """Each occupied voxel of a prepared shape's canonical grid, named by ``labeller``.

    Parameters
    ----------
    labeller : :class:`primkit.segmentation.labeller.Labeller`
    occupancy : (R, R, R) bool
        The grid in the canonical frame (:meth:`primkit.model.abstraction.Abstraction.canonical_shape`'s
        ``occupancy``: cell centres at :func:`primkit.geometry.grids.grid_centres`).
    canonical : primkit.primitives.Cuboids, the shape's canonical cuboids

    Returns
    -------
    points : (n, 3) float, the occupied voxels' centres, canonical (+Y up, +X front, longest side 1)
    labels : (n,) int, indices into ``labeller.names`` (-1: none, e.g. no cuboid present)
    """
    occupancy = np.asarray(occupancy, bool)
    # the canonical grid as a voxel grid (cell centres -0.5 + (i + 0.5) / R) in a frame that is
    # already canonical: the labeller then reads it as it reads any voxel file
    grid = io.VoxelGrid(occupancy, np.full(3, -0.5), 1.0)
    identity = geometry.CanonicalFrame(np.eye(3), np.zeros(3), 1.0)
    elements, _ = grid_elements(grid, identity)
    return elements.points, label_elements(labeller, elements, canonical)


def labelled_grid(labeller, occupancy, canonical) -> np.ndarray:
    """``(R, R, R) int``: :func:`labelled_voxels` written back into the grid: each occupied cell's
    label (an index into ``labeller.names``), -1 for an empty cell or one without a name. What
    :meth:`primkit.embedding.RegionTable.from_grids` reads beside the occupancy."""
    occupancy = np.asarray(occupancy, bool)
    _, labels = labelled_voxels(labeller, occupancy, canonical)  # the occupied cells in np.argwhere order
    out = np.full(occupancy.shape, -1, np.int64)
    out[tuple(np.argwhere(occupancy).T)] = labels
    return out


def label_regions(labeller, chosen, grids, canonicals) -> tuple[list, list]:
    """Each shape's voxels named by ``labeller``, as :func:`primkit.embedding.label_boxes` reads
    them for the labels ``chosen`` (some of ``labeller.names``, e.g. :func:`by_label`'s):
    ``label_boxes(*label_regions(labeller, chosen, grids, canonicals), chosen)``.

    ``grids``: each shape's canonical occupancy ``(R, R, R) bool`` (:func:`labelled_voxels`);
    ``canonicals``: each shape's canonical cuboids. Returns ``(points, slots)``: per shape its
    occupied voxels' centres ``(n_i, 3) float`` (canonical) and each voxel's position in
    ``chosen`` ``(n_i,) int`` (-1: a label not chosen, or none).
    """
    names = list(labeller.names)
    slot = np.full(len(names) + 1, -1, np.int64)  # a label's slot among the chosen; the last (label -1): none
    slot[[names.index(n) for n in chosen]] = np.arange(len(chosen))
    points, slots = [], []
    for occupancy, canonical in zip(grids, canonicals):
        p, named = labelled_voxels(labeller, occupancy, canonical)
        points.append(p)
        slots.append(slot[named])
    return points, slots


def labelled_surface(labeller, vertices, faces, result) -> np.ndarray:
    """``(f,) int``: each face of a mesh (or each point of a cloud, ``faces`` empty) named by
    ``labeller`` (indices into ``labeller.names``; -1 none), in the frame of the shape's
    abstraction ``result`` (its ``frame`` and ``canonical`` cuboids). What ``primkit view abstraction
    --label-guess`` starts from."""
    if len(faces):
        elements = mesh_elements(vertices, faces, result.frame)
    else:
        elements = point_elements(vertices, result.frame)
    return label_elements(labeller, elements, result.canonical)
