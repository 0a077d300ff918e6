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

Imports run one way: io / geometry -> primitives -> data -> model and training -> applications
-> viewers and the command line.
"""

from .version import __version__

__all__ = ["__version__"]
