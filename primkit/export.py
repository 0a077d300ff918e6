"""Abstractions as glTF scenes: one ``.glb`` per shape whose parts are named, selectable nodes.

``primkit abstract SHAPES --model chair --format glb -o out/`` (or :func:`save_glb`) writes, per
shape, ``<name>.cuboids.json`` and ``<name>.glb``. A 3D tool or a web viewer (three.js, Blender,
``<model-viewer>``) opens the ``.glb`` and can pick a part by its node.

The scene (node names in quotes; every node's ``extras`` are JSON, which three.js's GLTFLoader
puts in ``object.userData`` and Blender in custom properties)::

    "<shape name>"                 extras: primkit_glb (format version), name, source, frame,
     |                                     part_names (the model's, one per index), parts (present)
     +- "16 seat"                  one node per present part: "<index> <name>";
     |   |                         extras: part_index, part_name, existence_probability (or null)
     |   +- "16 seat surface"      the input's faces labelled 16 (when the input has faces)
     |   +- "16 seat cuboid"       the cuboid: 12 triangles; extras: half_extents, quaternion_wxyz,
     |                             translation (input frame)
     +- "unlabelled surface"       faces no part claims (only when some exist)

* **Frame and units**: the input's own coordinates, as the input file and the JSON's cuboids
  (``"frame": "input"``); nothing is moved or scaled. glTF viewers take +Y as up: a shape stored
  +Z up lies on its back there, as it would in the input's file.
* **Materials**: one per part index, named ``"part <k> <name>"``, in the colour every primkit
  picture gives index ``k`` (:func:`primkit.viz.palette.part_colors`, decoded to linear values
  as glTF's ``baseColorFactor`` wants: :func:`linear_rgb`); the cuboid's is the same
  colour at 35% opacity (``alphaMode: BLEND``, double-sided) so the surface shows through it.
  Unlabelled faces are grey.
* **Labels**: the surface is split by :func:`primkit.segmentation.face_labels` (each face takes
  the part holding most of its area), the labels ``primkit segment`` gives.
* Point clouds and voxel grids have no faces: their scenes hold the cuboids alone.

The scene is built as a ``trimesh.Scene`` and written by trimesh's glTF exporter, which stores a
node's ``extras`` from the metadata of its scene-graph edge (``Scene.add_geometry(metadata=...)``,
``SceneGraph.update(metadata=...)``) and reads them back the same way, so no post-processing of the
glTF JSON is needed. trimesh also adds its base frame as the root node, named ``"world"``.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from . import io
from .model import parts as _parts
from .segmentation import face_labels
from .primitives.palette import part_colors

__all__ = ["GLB_FORMAT_VERSION", "CUBOID_OPACITY", "part_node_name", "linear_rgb", "glb_scene", "write_glb", "save_glb"]

#: Version of the scene layout above, stored as ``extras.primkit_glb`` on the shape's node.
GLB_FORMAT_VERSION = 1
#: Opacity of the cuboids' materials (the surface's are opaque).
CUBOID_OPACITY = 0.35
_GREY = np.array([160, 160, 160], np.uint8)


def part_node_name(index: int, name: str) -> str:
    """The node name of part ``index``: ``"16 seat"`` (index first: several indices may share a name)."""
    return f"{int(index)} {name}"


def linear_rgb(rgb) -> np.ndarray:
    """sRGB colours ``(..., 3) uint8`` (the palette's) as linear values ``(..., 3) float`` in [0, 1].

    glTF's ``baseColorFactor`` is linear: a viewer applies the sRGB transfer function on display,
    so the palette's sRGB values are decoded first (IEC 61966-2-1), else every part shows lighter
    than in primkit's pictures."""
    c = np.asarray(rgb, float) / 255.0
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


def _material(name: str, rgb, alpha: float = 1.0):
    from trimesh.visual.material import PBRMaterial

    colour = list(linear_rgb(rgb)) + [float(alpha)]
    return PBRMaterial(name=name, baseColorFactor=colour, metallicFactor=0.0, roughnessFactor=0.9,
                       alphaMode="BLEND" if alpha < 1.0 else "OPAQUE", doubleSided=alpha < 1.0)


def _trimesh(vertices, faces, material):
    import trimesh

    used, inverse = np.unique(np.asarray(faces, np.int64).ravel(), return_inverse=True)
    mesh = trimesh.Trimesh(np.asarray(vertices, float)[used], inverse.reshape(-1, 3), process=False)
    mesh.visual = trimesh.visual.TextureVisuals(material=material)
    return mesh


def glb_scene(cuboids, part_names=None, vertices=None, faces=None, *, labels=None, name: str = "shape",
              source: str = ""):
    """The scene of one abstracted shape (see the module notes), as a ``trimesh.Scene``.

    Parameters
    ----------
    cuboids : primkit.primitives.Cuboids
        In the frame of ``vertices`` (the input's: :attr:`AbstractionResult.cuboids`).
    part_names : sequence of m str, optional
        The model's name of each index; default ``part0, part1, ...``.
    vertices : (n, 3) float, optional; faces : (f, 3) int, optional
        The input's surface. None: the cuboids alone.
    labels : (f,) int, optional
        The part of each face (-1: none); default :func:`primkit.segmentation.face_labels`. Faces
        of -1 or of a part that is not present go to the ``"unlabelled surface"`` node.
    name, source : the shape's name (the root node's) and where it came from.
    """
    import trimesh

    m = cuboids.count
    names = [str(n) for n in (part_names if part_names is not None else _parts.default_part_names(m))]
    if len(names) != m:
        raise ValueError(f"part_names has {len(names)} names but the cuboids have {m} slots")
    palette = part_colors(max(m, 1))
    present = [int(k) for k in cuboids.present]
    probabilities = cuboids.probabilities
    scene = trimesh.Scene()
    root = str(name)
    scene.graph.update(frame_to=root, frame_from=scene.graph.base_frame, metadata={
        "primkit_glb": GLB_FORMAT_VERSION, "name": str(name), "source": str(source), "frame": "input",
        "part_names": names, "parts": present})
    if faces is not None and len(faces):
        vertices = np.asarray(vertices, float)
        faces = np.asarray(faces, np.int64)
        if vertices.ndim != 2 or vertices.shape[1] != 3 or faces.ndim != 2 or faces.shape[1] != 3:
            raise ValueError(f"`vertices` must be (n, 3) float and `faces` (f, 3) int, got {vertices.shape} and {faces.shape}")
        labels = face_labels(vertices, faces, cuboids) if labels is None else np.asarray(labels, np.int64)
        if labels.shape != (len(faces),):
            raise ValueError(f"`labels` must be ({len(faces)},) int, got shape {labels.shape}")
    else:
        faces = None
    cv, cf, cpart = cuboids.to_mesh()
    for k in present:
        node = part_node_name(k, names[k])
        p = None if probabilities is None else float(probabilities[k])
        scene.graph.update(frame_to=node, frame_from=root, metadata={
            "part_index": k, "part_name": names[k], "existence_probability": p})
        if faces is not None and np.any(labels == k):
            surface = _trimesh(vertices, faces[labels == k], _material(f"part {k} {names[k]}", palette[k]))
            scene.add_geometry(surface, node_name=f"{node} surface", geom_name=f"{node} surface", parent_node_name=node,
                               metadata={"part_index": k, "kind": "surface", "faces": int(np.sum(labels == k))})
        box = _trimesh(cv, cf[cpart == k], _material(f"part {k} {names[k]} cuboid", palette[k], CUBOID_OPACITY))
        scene.add_geometry(box, node_name=f"{node} cuboid", geom_name=f"{node} cuboid", parent_node_name=node,
                           metadata={"part_index": k, "kind": "cuboid",
                                     "half_extents": [float(x) for x in cuboids.half_extents[k]],
                                     "quaternion_wxyz": [float(x) for x in cuboids.quaternions[k]],
                                     "translation": [float(x) for x in cuboids.translations[k]]})
    unclaimed = None if faces is None else ~np.isin(labels, present)  # -1, or a part that is not present
    if unclaimed is not None and unclaimed.any():
        rest = _trimesh(vertices, faces[unclaimed], _material("unlabelled", _GREY))
        scene.add_geometry(rest, node_name="unlabelled surface", geom_name="unlabelled surface", parent_node_name=root,
                           metadata={"part_index": -1, "kind": "surface", "faces": int(unclaimed.sum())})
    return scene


def write_glb(path, cuboids, part_names=None, vertices=None, faces=None, *, labels=None, name: str | None = None,
              source: str = "", overwrite: bool = False) -> Path:
    """Write :func:`glb_scene`'s scene to ``path`` (``.glb``), atomically; an existing file is kept
    unless ``overwrite``. ``name`` defaults to the file's stem. Returns the path."""
    path = io.check_suffix(path, ".glb", "a glTF scene")
    io.refuse_existing(path, overwrite)
    scene = glb_scene(cuboids, part_names, vertices, faces, labels=labels, name=name or path.stem, source=source)
    data = scene.export(file_type="glb")
    with io.atomic_output(path, overwrite=overwrite) as tmp:
        Path(tmp).write_bytes(data)
    return path


def save_glb(abstraction, part_names, folder, *, overwrite: bool = False) -> tuple[Path, Path]:
    """Write ``<name>.cuboids.json`` (as :meth:`AbstractionResult.save`) and ``<name>.glb`` into
    ``folder`` for one :class:`primkit.model.abstraction.Abstraction`: its input surface (when it
    has faces) and its cuboids, in the input's frame. Nothing is written when either file exists
    and ``overwrite`` is false."""
    folder = Path(folder)
    result = abstraction.result
    json_path, glb_path = folder / f"{result.name}.cuboids.json", folder / f"{result.name}.glb"
    io.refuse_existing((json_path, glb_path), overwrite)
    try:
        vertices, faces = abstraction.vertices, abstraction.faces
    except (io.ShapeFileError, ValueError):  # a point cloud or a voxel grid: the cuboids alone
        vertices = faces = None
    scene = glb_scene(result.cuboids, part_names, vertices, faces, name=result.name, source=str(result.source))
    data = scene.export(file_type="glb")
    with io.atomic_output(json_path, overwrite=overwrite) as tmp:
        Path(tmp).write_text(json.dumps(result.to_dict(), indent=1))
    with io.atomic_output(glb_path, overwrite=overwrite) as tmp:
        Path(tmp).write_bytes(data)
    return json_path, glb_path
