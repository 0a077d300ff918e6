"""Abstraction from a single image, distilled from a volume model (the paper's Section 5.2).

The volume abstractor (:mod:`primkit.model.network`) reads a 32^3 grid; for a photo there is no grid. So,
as in the paper, an image network is trained to reproduce the volume network's cuboids from a
picture of the same shape: the volume model is the *teacher*, the image network the *student*,
and primitive ``k`` of the student is trained on primitive ``k`` of the teacher, so part indices
keep their meaning (seat, back, ...) across the two models.

Frames: the student predicts in the shape's canonical frame (object-centred: +Y up, front toward
+X, longest side 1), whatever the viewpoint of the picture; it also predicts the viewpoint
(azimuth and elevation of :class:`primkit.image.camera.OrbitCamera`), which is what lets
:func:`draw_over_image` project the cuboids back onto the picture.

Network (:class:`ImageNet`; torchvision has no CPU build here and is not needed)::

    (B, 3, S, S) image, S = 64
    5 x [3x3 conv stride 2, batch norm, ReLU], channels 32, 48, 64, 96, 128  -> (B, 128, 2, 2)
    flatten, linear 512 -> 256, ReLU
    heads as the volume network's: half_extents = 0.5 sigmoid, quaternions = normalise,
    translations = 0.5 tanh, existence = sigmoid (logits kept), viewpoint (cos az, sin az, el rad)

About 0.4 M weights (1.6 MB as float32). Batch norm, unlike the volume network's paper encoder,
because backgrounds and lighting move the input statistics a lot.

Distillation loss (:func:`distillation_loss`), per part ``k`` of each image, with the teacher's
existence probability ``p_k`` weighting the shape terms (a part the teacher does not use carries
no shape information)::

    existence   BCE(student logit_k, p_k)
    extents     |z_k - z_k^T|_1 / 3
    translation |t_k - t_k^T|_1 / 3
    rotation    1 - |<q_k, q_k^T>|      (q and -q are one rotation; for unit quaternions this is
                                         1 - cos(theta / 2), theta the angle between the rotations)
    viewpoint   squared error of (cos az, sin az, el)

Optionally (``ImageTrainConfig.geometric > 0``, with each training shape's surface points and
closest-point grid), the student is also held to the shape itself: the method's coverage and
consistency losses (:mod:`primkit.model.losses`) of its cuboids against the true shape, over the parts
the teacher uses. The teacher's own errors are then no longer a floor for the student's.

The cuboid symmetries (a cuboid turned by 90 degrees with two extents swapped is the same solid)

Modules: :mod:`~primkit.image.camera` (the views' camera), :mod:`~primkit.image.backgrounds`,
:mod:`~primkit.image.views` (rendering training views), :mod:`~primkit.image.network`,
:mod:`~primkit.image.distill` (training) and :mod:`~primkit.image.inference` (using a model).
``primkit.image`` imports the model (its losses, network heads, model files), the drawing kit's
backend and palette, and the layers below.
"""

from .backgrounds import PALETTE_HUES, PALETTES, composite, random_background, training_backgrounds
from .camera import OrbitCamera, ViewSettings, project, random_camera, viewpoint_targets
from .distill import DistillationLoss, DistillWeights, ImageTrainConfig, ImageTrainResult, distillation_loss, rotation_distance, train_image_model
from .inference import KIND, ImageAbstraction, ImageAbstractor, draw_over_image, read_image
from .network import ImageNet, ImageNetConfig, ImagePrediction, images_to_float
from .views import RenderedViews, ViewRenderer, load_views, render_views, render_views_cached, shape_surface

__all__ = [
    "ViewSettings", "OrbitCamera", "project", "random_camera", "viewpoint_targets",
    "PALETTES", "PALETTE_HUES", "random_background", "training_backgrounds", "composite",
    "RenderedViews", "ViewRenderer", "shape_surface", "render_views", "render_views_cached", "load_views",
    "ImageNetConfig", "ImageNet", "ImagePrediction", "images_to_float",
    "DistillWeights", "DistillationLoss", "distillation_loss", "rotation_distance", "ImageTrainConfig", "ImageTrainResult", "train_image_model",
    "KIND", "ImageAbstractor", "ImageAbstraction", "read_image", "draw_over_image",
]
