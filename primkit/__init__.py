"""primkit: explain collections of 3D shapes with a few volumetric primitives.

A reimplementation of Tulsiani et al., "Learning Shape Abstractions by Assembling Volumetric
Primitives" (CVPR 2017), with the tooling around it: reading shapes, preparing them, training the
cuboid abstractor, and the applications that live on its indexed parts.

Conventions used everywhere (written once, here):

* **Canonical frame.** Shapes are prepared into a frame where +Y is up and +X is the front, the
  axis-aligned bounding box is centred at the origin and its longest side is 1, so the shape lies
  inside [-0.5, 0.5]^3 (as ShapeNet and the voxel grids of ShapeNetVox32).
* **Grids.** A grid of resolution ``R`` covers [-0.5, 0.5]^3 with ``R`` cells per axis, indexed
  ``grid[i, j, k]`` with ``i`` along X, ``j`` along Y and ``k`` along Z. The centre of cell
  ``(i, j, k)`` is ``-0.5 + (index + 0.5) / R``.
* **Arrays.** Public functions take and return NumPy arrays; shapes are documented as
  ``(n, 3) float``. Letters: ``n`` points, ``f`` faces, ``m`` primitives (parts), ``s`` shapes.
  torch stays inside the model and training code.

Imports run one way (README, "Layout"; ``lint-imports`` checks it): io -> geometry -> primitives
-> data, synthetic, viz -> model, metrics -> applications -> report, plugins -> viewers, demo -> cli.
Modules import primkit's own modules at their top. Heavy third-party libraries (torch, VTK and
pyvista, Open3D, trimesh, libigl, scipy, scikit-learn, matplotlib, Pillow, tqdm) are imported inside
the functions that use them, so ``import primkit`` and its light modules load none of them; the
modules built on torch (:mod:`primkit.model` but its abstraction entry, :mod:`primkit.image`)
:mod:`primkit.image`) import it at their top.

For scripts::

    import primkit
    a = primkit.abstract("chair.off", model="chair")      # or a mesh, (vertices, faces), points
    a.cuboids                                             # primkit.Cuboids, in the input's frame
    seg = primkit.segment("chair.off", model="chair")     # face_labels: part index per face
    model = primkit.load_model("chair")                   # for many predictions
    shape = primkit.read_shape("chair.off")               # primkit.Mesh, PointCloud or VoxelGrid
"""

from .version import __version__

#: the names ``import primkit`` offers, and where each lives (imported on first use, so that
#: ``import primkit`` loads neither torch nor VTK)
_EXPORTS = {
    "abstract": "primkit.model.abstraction",
    "abstract_shapes": "primkit.model.abstraction",
    "load_model": "primkit.model.abstraction",
    "Abstraction": "primkit.model.abstraction",
    "segment": "primkit.segmentation",
    "read_shape": "primkit.io",
    "Mesh": "primkit.io",
    "PointCloud": "primkit.io",
    "VoxelGrid": "primkit.io",
    "Cuboids": "primkit.primitives",
}

__all__ = ["__version__", *_EXPORTS]


def __getattr__(name):
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module 'primkit' has no attribute {name!r}")
    import importlib  # the lazy exports' loader: the modules above are imported on first use

    return getattr(importlib.import_module(module), name)


def __dir__():
    return sorted(set(globals()) | set(_EXPORTS))
