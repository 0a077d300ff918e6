"""Read and write shapes: meshes, point clouds, voxel grids and per-face labels.

Every reader returns one small value type (:class:`Mesh`, :class:`PointCloud`,
:class:`VoxelGrid`) or a plain array, and every failure is a :class:`ShapeFileError` whose
text is one line, ``"<path>: <reason>"``. Writers never replace an existing file unless asked
(``overwrite=True``) and write through :func:`atomic_output`, so a crash never leaves half a
file behind. Input files are never modified: commands check every output before any work
(:func:`check_outputs`), and an output that is an input is refused even with ``--force``.

Why trimesh is the format library
---------------------------------
trimesh is pure Python on top of NumPy, so it installs everywhere. It reads OBJ, PLY, OFF, STL,
GLB and GLTF, including scenes whose nodes carry transforms, it triangulates polygons, and it
keeps vertex and face order when asked (``process=False``). It writes per-face colours to PLY,
and per-vertex colours to GLB. Open3D's reader keeps no per-face colours at all, and on a
missing or broken file it logs a warning and returns an empty mesh instead of raising.

Plain OFF, OBJ, XYZ and SEG text (ASCII, triangles, no comments) is parsed by a compiled parser
(:mod:`~primkit.io._text_kernels`) into the same arrays, to the last bit, 15-20 times faster;
``engine="trimesh"`` reads every file the old way (see ``docs/io.md``).

Three things are written here rather than by trimesh, each in a few lines:

* OFF and OBJ text, with ``%.17g`` coordinates, so float64 vertices survive a round trip
  exactly (trimesh writes a fixed number of decimals).
* OBJ per-face colours: one material per distinct colour in a ``.mtl`` file beside the
  ``.obj``, with a ``usemtl`` before each run of equal colours, so the faces stay in order.
* binvox decoding: a short NumPy run-length decoder whose axis order is spelled out below.

Face order
----------
Per-face label files (``.seg``) index faces in file order, so readers keep it: OFF, PLY, STL and
triangle-only OBJ faces come back exactly in file order. Meshes with a few degenerate faces are
kept as they are (no face is dropped). Polygons with more than three corners are triangulated
by trimesh, which groups the resulting triangles by polygon size. After that the triangles no
longer line up with the file's faces. Label files can only be matched against triangle-only
meshes, and :func:`read_labels` with ``face_count`` raises when the counts differ, as they
always do for a mesh with a polygon face.

Formats
-------
* Meshes: ``.obj .ply .off .stl .glb .gltf``. STL stores every triangle with its own three
  corners, so exactly equal corners are merged on reading (vertices in order of first use;
  the faces keep their order). A GLB or GLTF scene is flattened: every mesh node, with its
  scene-graph transform applied, in the scene graph's node order.
* Points: ``.xyz`` (whitespace text, 3 columns, or 6 with normals), ``.npy`` ((n, 3) or
  (n, 6)) and ``.ply`` without faces. A ``.ply`` with faces is a mesh.
* Voxels: ``.binvox``, see :class:`VoxelGrid` for the axis order.
* Labels: ``.seg``, one integer per line, one line per face.

PLY, GLB and STL store vertices as float32; OFF, OBJ and the point formats keep float64.

Bounds: a file may not make a reader allocate past :mod:`~primkit.io.limits` (faces, also after
a scene's instancing; voxel grid side), raised by ``PRIMKIT_MAX_FACES`` / ``PRIMKIT_MAX_GRID``.
A UTF-8 byte-order mark at the start of a text format is read as nothing.

Modules: :mod:`~primkit.io.values` (the value types and the error), :mod:`~primkit.io.files`
(safe writing), :mod:`~primkit.io.formats` (the readers and writers), :mod:`~primkit.io.limits`
(the bounds). ``primkit.io`` is the bottom layer: it imports nothing else of primkit.
"""

from . import faces, files, formats, limits, values
from .faces import declared_face_count
from .files import OutputError, atomic_output, check_outputs, check_suffix, is_temporary, refuse_existing, write_array
from .formats import LABEL_SUFFIXES, MESH_SUFFIXES, MESH_WRITE_SUFFIXES, POINT_SUFFIXES, VOXEL_SUFFIXES, is_shape_file, read_labels, read_mesh, read_points, read_shape, read_voxels, write_labels, write_like, write_mesh, write_points, write_voxels
from .values import Mesh, PointCloud, ShapeFileError, VoxelGrid

__all__ = values.__all__ + formats.__all__ + files.__all__ + faces.__all__
