"""Part names per element: a labeller any category can use.

A :class:`~primkit.labelling.labeller.Labeller` names every element of a shape (a voxel, a face, a
point) from where it sits in the shape's abstraction and in the shape itself, learned from a few
labelled shapes of one model and stored in the model file without code. The modules, each one
concept:

* :mod:`primkit.labelling.labeller`: the labeller (fit, predict, decide) and its storage in a
  model file;
* :mod:`primkit.labelling.features`: what it reads of each element
  (:class:`~primkit.labelling.features.LabellerSettings`);
* :mod:`primkit.labelling.profile`, :mod:`primkit.labelling.sides`: the shape-profile and side
  features;
* :mod:`primkit.labelling.trees`: the fitted trees as plain arrays, and the walk that predicts
  with them;
* :mod:`primkit.labelling.smoothing`: a voxel grid's neighbours, sampling and normals;
* :mod:`primkit.labelling.post`: the post-steps a labeller file may name
  (:mod:`primkit.labelling.presence`, :mod:`primkit.labelling.layers`: a chair's arms and where
  its seat ends).

How a segmented shape's elements are read and labelled (meshes over their surface) is in
:mod:`primkit.segmentation.labeller` and :mod:`primkit.segmentation.meshlabels`.

Imports: :mod:`primkit.primitives`, :mod:`primkit.model.modelfile` and :mod:`primkit.io` (to
write a model file) below it; :mod:`primkit.segmentation` and the layers above import it, never
the other way.
"""

from .features import LabellerSettings, feature_count, frame_features
from .labeller import Labeller, decide, has_labeller, read_labeller, write_labeller
from .post import resolve_post
from .trees import TreeEnsemble

__all__ = ["Labeller", "LabellerSettings", "TreeEnsemble", "decide", "feature_count", "frame_features",
           "has_labeller", "read_labeller", "resolve_post", "write_labeller"]
