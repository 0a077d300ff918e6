"""Unsupervised co-segmentation, and its evaluation against ground-truth labels.

Because one network explains a whole category, primitive ``k`` is the same part on every shape,
and projecting a shape onto its abstraction parses a whole collection consistently with no labels
given (Tulsiani et al. 2017, Sec. 5.1): every surface element goes to its nearest primitive, or
(the default) a graph cut labels them together so that boundaries follow the surface.

* :mod:`.meshes`: the rule on points, vertices and faces (:class:`Segmentation`);
* :mod:`.voxels`: the rule on a voxel grid's voxels (:class:`VoxelSegmentation`);
* :mod:`.evaluation`: ground truth (``.seg`` face labels; per-voxel labels such as PartNet's chair
  labels, :class:`VoxelLabelArchive`) and the evaluation against it (:func:`evaluate`,
  :func:`evaluate_voxels`);
* :mod:`.outputs`: what a run writes and under which names (each shape's files, the summaries,
  ``labels.csv``), and its plan (:func:`plan_segmentation`);
* :mod:`.points`: the rule on a point cloud's points (:class:`PointSegmentation`, a label per point);
* :mod:`.segmenter`: collections of files (:class:`Segmenter`, its planned :meth:`~Segmenter.run`) and one shape (:func:`segment`);
* :mod:`.graphcut`: the graph-cut labelling (alpha-expansion over faces, voxels or points).

May import: ``primkit.viz``, ``primkit.model`` (abstraction), ``primkit.data``, ``primkit.primitives``
(with the palette), ``primkit.geometry``, ``primkit.io``. Inside: segmenter -> outputs, evaluation -> voxels,
points -> meshes -> graphcut.
"""

from . import evaluation, graphcut, meshes, outputs, points, segmenter, voxels
from .evaluation import (PARTNET_LABEL_NAMES, PROTOCOLS, VOXEL_PROTOCOLS, Detection, GroundTruth, ProtocolScores,
                         SegmentationEvaluation, ShapeAccuracy, VoxelEvaluation, VoxelGroundTruth, VoxelLabelArchive,
                         VoxelProtocolScores, VoxelShapeScores,
                         accuracy, evaluate, evaluate_voxels, label_iou, majority_mapping, name_mapping, parse_label_names,
                         read_ground_truth)
from .meshes import Segmentation, SegmentationFiles, face_labels, point_labels, segment_mesh, vertex_labels
from .outputs import plan_segmentation, read_summary, summary_header, write_summary
from .points import PointSegmentation, segment_points
from .segmenter import SegmentationRun, Segmenter, resolve_labeller, segment
from .voxels import VoxelSegmentation, label_voxels, segment_voxels, voxel_centres

__all__ = (meshes.__all__ + voxels.__all__ + points.__all__ + segmenter.__all__
           + ["GroundTruth", "read_ground_truth", "parse_label_names", "majority_mapping", "name_mapping", "accuracy",
              "label_iou", "evaluate", "PROTOCOLS", "PARTNET_LABEL_NAMES", "VoxelGroundTruth", "VoxelLabelArchive",
              "evaluate_voxels", "VOXEL_PROTOCOLS", "SegmentationEvaluation", "ProtocolScores", "ShapeAccuracy",
              "VoxelEvaluation", "VoxelProtocolScores", "VoxelShapeScores", "Detection", "read_summary", "summary_header", "write_summary",
              "plan_segmentation"])
