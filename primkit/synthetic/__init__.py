"""Procedural, seeded, part-labelled shapes: chairs, tables, airplanes and four-legged animals.

They stand in for real data sets (ShapeNet and friends) that cannot be shipped, so tests, examples
and demos of the cuboid abstraction have something realistic to chew on. Every shape is

* one watertight triangle mesh: the parts are built as closed solids that overlap slightly and are
  joined by a boolean union (manifold3d), so the result is a single connected component;
* labelled per face: each face carries the index of the part it came from, recovered from
  manifold3d's provenance (every part enters the union as its own *original* mesh, and the output
  mesh says which original each run of triangles came from);
* not a union of boxes: legs are cylinders or tapered, seats and backs have rounded edges, backs
  tilt, wings are swept, fuselages and torsos are smooth, heads are spheres; cuboids can only
  approximate them, as with real data;
* in the canonical frame of :mod:`primkit`: +Y up, +X front (chair seat faces +X, airplane nose
  and animal head point to +X), bounding box centred at the origin, longest side 1.

Left and right are the shape's own: looking along +X with +Y up, the right-hand side is +Z, so
``*_left`` parts lie at negative Z and ``*_right`` parts at positive Z.

Each category has a fixed tuple of instance-level part names (:data:`PART_NAMES`), so a label is a
stable index; parts a shape does not have (the arms of an armless chair) simply have no faces.
:data:`PART_GROUPS` maps every part to a coarse semantic group (``"legs"``, ``"seat"``, ...).

Randomness comes only from the ``seed`` argument. Every attribute is drawn from the generator in
a fixed order whatever the overrides, so ``chair(3, has_arms=True)`` is ``chair(3)`` with arms.
Absolute sizes are in metre-like units before the final normalisation; the attributes keep
those units.

Modules: :mod:`~primkit.synthetic.solids` (closed building blocks),
:mod:`~primkit.synthetic.labelled` (the labelled shape and its assembly),
:mod:`~primkit.synthetic.categories` (the four generators), :mod:`~primkit.synthetic.collection`
(seeded collections and their files). ``primkit.synthetic`` imports only :mod:`primkit.io`.
"""

from .categories import airplane, animal, chair, stool, table
from .collection import generate, read_collection_labels, write_collection
from .labelled import CATEGORIES, PART_GROUPS, PART_NAMES, LabelledShape

__all__ = [
    "CATEGORIES",
    "PART_GROUPS",
    "PART_NAMES",
    "LabelledShape",
    "airplane",
    "animal",
    "chair",
    "generate",
    "read_collection_labels",
    "stool",
    "table",
    "write_collection",
]
