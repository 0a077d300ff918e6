"""Unsupervised co-segmentation, and its evaluation against ground-truth labels.

Because one network explains a whole category, primitive ``k`` is the same part on every shape,
and projecting a shape onto its abstraction parses a whole collection consistently with no labels
given (Tulsiani et al. 2017, Sec. 5.1): every surface element goes to its nearest primitive, or
(the default) a graph cut labels them together so that boundaries follow the surface.

* :mod:`.meshes`: the rule on points, vertices and faces (:class:`Segmentation`), face-label
  ground truth (``.seg`` files) and its evaluation (:func:`evaluate`);
* :mod:`.voxels`: the rule on a voxel grid's voxels (:class:`VoxelSegmentation`), per-voxel ground
  truth (e.g. PartNet's chair labels, :class:`VoxelLabelArchive`) and its evaluation
  (:func:`evaluate_voxels`);
* :mod:`.points`: the rule on a point cloud's points (:class:`PointSegmentation`, a label per point);
* :mod:`.segmenter`: collections of files (:class:`Segmenter`) and one shape (:func:`segment`);
* :mod:`.graphcut`: the graph-cut labelling (alpha-expansion over faces, voxels or points).

May import: ``primkit.viz``, ``primkit.model`` (abstraction), ``primkit.data``, ``primkit.primitives``
(with the palette), ``primkit.geometry``, ``primkit.io``. Inside: segmenter -> voxels, points -> meshes
-> graphcut.
"""

from . import graphcut, meshes, points, segmenter, voxels
from .meshes import (PROTOCOLS, GroundTruth, Segmentation, accuracy, evaluate, face_labels, label_iou, majority_mapping,
                     name_mapping, parse_label_names, point_labels, read_ground_truth, segment_mesh, vertex_labels)
from .points import PointSegmentation, segment_points
from .segmenter import Segmenter, read_summary, segment, summary_header, write_summary
from .voxels import (PARTNET_LABEL_NAMES, VOXEL_PROTOCOLS, VoxelGroundTruth, VoxelLabelArchive, VoxelSegmentation,
                     evaluate_voxels, label_voxels, segment_voxels, voxel_centres)

__all__ = meshes.__all__ + voxels.__all__ + points.__all__ + segmenter.__all__
