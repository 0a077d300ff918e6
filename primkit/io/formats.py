"""Shape, point and label file formats: the readers and writers (see :mod:`primkit.io` for the
formats, the face order and why trimesh reads and writes them)."""

from __future__ import annotations

import codecs
import os
import stat
from io import BytesIO, StringIO
from pathlib import Path

import numpy as np

from . import limits
from .files import atomic_output
from .values import Mesh, PointCloud, ShapeFileError, VoxelGrid, check_coordinates

__all__ = [
    "MESH_SUFFIXES",
    "POINT_SUFFIXES",
    "VOXEL_SUFFIXES",
    "LABEL_SUFFIXES",
    "MESH_WRITE_SUFFIXES",
    "is_shape_file",
    "read_mesh",
    "read_points",
    "read_voxels",
    "read_shape",
    "read_labels",
    "write_mesh",
    "write_labels",
    "write_points",
    "write_voxels",
    "write_like",
]


MESH_SUFFIXES = (".obj", ".ply", ".off", ".stl", ".glb", ".gltf")


POINT_SUFFIXES = (".xyz", ".npy", ".ply")


VOXEL_SUFFIXES = (".binvox",)


LABEL_SUFFIXES = (".seg",)


# suffixes write_mesh / write_points can produce
_MESH_WRITE_SUFFIXES = (".ply", ".obj", ".glb", ".off", ".stl")
#: the suffixes :func:`write_mesh` writes
MESH_WRITE_SUFFIXES = _MESH_WRITE_SUFFIXES


_POINT_WRITE_SUFFIXES = (".ply", ".xyz", ".npy")


def is_shape_file(path) -> bool:
    """True when ``path`` has a mesh, point or voxel suffix (case-insensitive)."""
    return Path(path).suffix.lower() in MESH_SUFFIXES + POINT_SUFFIXES + VOXEL_SUFFIXES


#: the readers' engines: "auto" parses plain OFF, OBJ, XYZ and SEG text with a compiled parser
#: (:mod:`primkit.io._text_kernels`) and everything else as "trimesh" does (trimesh's loaders,
#: NumPy's ``loadtxt``); both give the same arrays to the last bit
ENGINES = ("auto", "trimesh")


def read_mesh(path, *, engine: str = "auto") -> Mesh:
    """Read a triangle mesh, keeping vertex and face order.

    Parameters
    ----------
    path : str or Path
      ``.obj .ply .off .stl .glb .gltf``.
    engine : {"auto", "trimesh"}
      ``"auto"`` parses plain OFF and OBJ text (ASCII, triangles, three coordinates a vertex, no
      comments) with a compiled parser and hands every other file to trimesh; ``"trimesh"`` always
      uses trimesh's loader. The arrays are the same either way (tested on every shared mesh).

    Returns
    -------
    mesh : Mesh
      ``vertices : (n, 3) float64``, ``faces : (f, 3) int64``.

    Raises
    ------
    ShapeFileError
      Missing, unreadable, empty or unparsable file, unsupported suffix, no faces, NaN or inf
      coordinates, face indices out of range, zero total area, or more faces than
      :func:`primkit.io.limits.max_faces` (a scene's instances counted before they are expanded).
    """
    _check_engine(engine)
    data = _read_checked(path, MESH_SUFFIXES, "mesh")
    parsed = _parse_mesh_text(path, data) if engine == "auto" else None
    if parsed is not None:
        return _checked_mesh(path, *parsed)
    return _mesh_from_loaded(path, _load_trimesh(path, data))


def read_points(path, *, engine: str = "auto") -> PointCloud:
    """Read a point cloud.

    Parameters
    ----------
    path : str or Path
      ``.xyz`` (whitespace text, 3 columns or 6 with normals), ``.npy`` ((n, 3) or (n, 6)),
      or ``.ply`` without faces (normals from ``nx ny nz`` when present).
    engine : {"auto", "trimesh"}
      As for :func:`read_mesh`: ``"auto"`` parses plain ``.xyz`` text with the compiled parser,
      ``"trimesh"`` always with NumPy's ``loadtxt``.

    Returns
    -------
    cloud : PointCloud
      ``points : (n, 3) float64``, ``normals : (n, 3) float64`` or None.
    """
    _check_engine(engine)
    data = _read_checked(path, POINT_SUFFIXES, "point cloud")
    suffix = Path(path).suffix.lower()
    if suffix == ".ply":
        return _points_from_loaded(path, _load_trimesh(path, data))
    if suffix == ".npy":
        try:
            array = np.load(BytesIO(data), allow_pickle=False)
        except Exception as exc:  # numpy raises several types for bad headers
            raise ShapeFileError(path, f"cannot parse as NPY: {_short(exc)}") from exc
        if not (np.issubdtype(array.dtype, np.integer) or np.issubdtype(array.dtype, np.floating)):
            raise ShapeFileError(path, f"expected a real-valued array, got dtype {array.dtype}")
    else:
        array = _parse_rows_text(data) if engine == "auto" else None
        if array is None:
            text = data.decode("utf-8", errors="replace").replace(",", " ")
            try:
                array = np.loadtxt(StringIO(text), dtype=np.float64, comments="#", ndmin=2)
            except ValueError as exc:
                raise ShapeFileError(path, f"cannot parse as XYZ: {_short(exc)}") from exc
    if array.ndim != 2 or array.shape[1] not in (3, 6):
        raise ShapeFileError(path, f"expected (n, 3) or (n, 6) values, got shape {array.shape}")
    array = array.astype(np.float64)
    normals = array[:, 3:6] if array.shape[1] == 6 else None
    return _checked_points(path, array[:, :3], normals)


def read_voxels(path) -> VoxelGrid:
    """Read a binvox occupancy grid.

    binvox stores voxels as (value, count) byte pairs, with x slowest, then z, then y fastest.
    They are decoded and transposed to ``[x, y, z]``.

    Parameters
    ----------
    path : str or Path
      ``.binvox`` with a cubic ``dim``.

    Returns
    -------
    grid : VoxelGrid
      ``occupancy : (R, R, R) bool`` indexed ``[x, y, z]``, ``translate : (3,)``, ``scale``.
    """
    data = _read_checked(path, VOXEL_SUFFIXES, "voxel grid")
    header, payload = _parse_binvox_header(path, data)
    dims = header["dim"]
    if len(set(dims)) != 1:
        shape = " ".join(map(str, dims))
        raise ShapeFileError(path, f"non-cubic grid dim {shape} is not supported")
    r = dims[0]
    limits.check_grid(path, r)  # before the run lengths are expanded: a few MB can declare 1024^3
    if len(payload) % 2:
        raise ShapeFileError(path, "run-length data has an odd number of bytes")
    pairs = np.frombuffer(payload, dtype=np.uint8).reshape(-1, 2)
    values, counts = pairs[:, 0], pairs[:, 1]
    if values.size and values.max() > 1:
        raise ShapeFileError(path, "run-length values must be 0 or 1")
    total = int(counts.sum(dtype=np.int64))
    if total != r**3:
        raise ShapeFileError(path, f"run lengths sum to {total}, expected {r**3} for dim {r}")
    raw = np.repeat(values.astype(bool), counts).reshape(r, r, r)  # [x, z, y]
    occupancy = np.ascontiguousarray(raw.transpose(0, 2, 1))  # [x, y, z]
    if not occupancy.any():
        raise ShapeFileError(path, "no occupied voxels")
    if occupancy.all():
        # two ShapeNetVox32 tables are like this: a defect, not a shape (no surface inside the grid)
        raise ShapeFileError(path, "every voxel is occupied (no surface inside the grid)")
    return VoxelGrid(occupancy, header["translate"], header["scale"])


def read_shape(path, *, engine: str = "auto") -> Mesh | PointCloud | VoxelGrid:
    """Read any supported shape file, choosing the type by suffix.

    A ``.ply`` with faces is a :class:`Mesh`; one without faces a :class:`PointCloud`.
    ``engine`` as for :func:`read_mesh`.

    Returns
    -------
    shape : Mesh, PointCloud or VoxelGrid
    """
    _check_engine(engine)
    suffix = Path(path).suffix.lower()
    if suffix == ".ply":
        data = _read_checked(path, (".ply",), "shape")
        loaded = _load_trimesh(path, data)
        if len(getattr(loaded, "faces", ())) > 0:
            return _mesh_from_loaded(path, loaded)
        return _points_from_loaded(path, loaded)
    if suffix in MESH_SUFFIXES:
        return read_mesh(path, engine=engine)
    if suffix in POINT_SUFFIXES:
        return read_points(path, engine=engine)
    if suffix in VOXEL_SUFFIXES:
        return read_voxels(path)
    raise _unsupported(path, MESH_SUFFIXES + POINT_SUFFIXES + VOXEL_SUFFIXES, "shape")


def read_labels(path, face_count: int | None = None, *, engine: str = "auto") -> np.ndarray:
    """Read per-face labels, one integer per line in face order.

    Parameters
    ----------
    path : str or Path
      ``.seg`` file.
    face_count : int or None
      When given, the number of lines must equal it (the mesh's face count).
    engine : {"auto", "trimesh"}
      ``"auto"`` parses plain files (one integer a line) with the compiled parser, ``"trimesh"``
      always with NumPy's ``loadtxt``; the same labels either way.

    Returns
    -------
    labels : (f,) int64
    """
    _check_engine(engine)
    data = _read_checked(path, LABEL_SUFFIXES, "label")
    labels = _parse_labels_text(data) if engine == "auto" else None
    if labels is None:
        try:
            labels = np.loadtxt(BytesIO(data), dtype=np.int64, ndmin=1)
        except ValueError as exc:
            raise ShapeFileError(path, f"cannot parse as SEG: {_short(exc)}") from exc
    if labels.ndim != 1:
        raise ShapeFileError(path, f"expected one integer per line, got {labels.shape[1]} columns")
    if face_count is not None and len(labels) != face_count:
        raise ShapeFileError(path, f"{len(labels)} labels but the mesh has {face_count} faces")
    return labels


def write_mesh(path, vertices, faces, face_colors=None, *, overwrite=False) -> Path:
    """Write a triangle mesh, optionally with one colour per face.

    Parameters
    ----------
    path : str or Path
      ``.ply``, ``.obj`` (with colours also ``<stem>.mtl`` beside it, one material per colour),
      ``.glb``, ``.off`` or ``.stl``.
    vertices : (n, 3) float
    faces : (f, 3) int
    face_colors : (f, 3) or (f, 4) uint8, or float in [0, 1], or None
      Only for ``.ply``, ``.obj`` and ``.glb``. GLB has no per-face colours, so each face gets
      its own three corners carrying its colour: the file then holds ``3 f`` vertices.
    overwrite : bool
      Replace existing files.

    Returns
    -------
    path : Path
      The mesh file written.
    """
    path = Path(path)
    suffix = _write_suffix(path, _MESH_WRITE_SUFFIXES, "a mesh")
    mesh = Mesh(vertices, faces)
    if len(mesh.faces) and (mesh.faces.min() < 0 or mesh.faces.max() >= len(mesh.vertices)):
        raise ValueError(f"`faces` must index `vertices` (n = {len(mesh.vertices)})")
    colors = None if face_colors is None else _rgba_uint8(face_colors, len(mesh.faces))
    if colors is not None and suffix in (".off", ".stl"):
        raise ValueError(f"{path}: '{suffix}' cannot store face colours (use .ply, .obj or .glb)")

    if suffix == ".obj":
        _write_obj(path, mesh, colors, overwrite)
        return path

    if suffix == ".off":
        payload = _off_text(mesh).encode("ascii")
    elif suffix == ".ply":
        payload = _ply_bytes(mesh, colors)
    else:
        import trimesh

        if suffix == ".glb" and colors is not None:
            # flat colours through per-vertex colours: every face gets its own corners
            tm = trimesh.Trimesh(
                mesh.vertices[mesh.faces].reshape(-1, 3),
                np.arange(3 * len(mesh.faces), dtype=np.int64).reshape(-1, 3),
                vertex_colors=np.repeat(colors, 3, axis=0),
                process=False,
            )
        else:
            tm = trimesh.Trimesh(mesh.vertices, mesh.faces, face_colors=colors, process=False)
        payload = tm.export(file_type=suffix[1:])
    with atomic_output(path, overwrite=overwrite) as temporary:
        temporary.write_bytes(payload)
    return path


def write_labels(path, labels, *, overwrite=False) -> Path:
    """Write per-face labels, one integer per line.

    Parameters
    ----------
    path : str or Path
      ``.seg`` file.
    labels : (f,) int

    Returns
    -------
    path : Path
    """
    path = Path(path)
    if path.suffix.lower() not in LABEL_SUFFIXES:
        raise ValueError(f"{path}: labels are written as '.seg', not '{path.suffix}'")
    labels = np.asarray(labels)
    if labels.ndim != 1 or not (labels.size == 0 or np.issubdtype(labels.dtype, np.integer)):
        raise ValueError(
            f"`labels` must be (f,) int, got shape {labels.shape} dtype {labels.dtype}"
        )
    text = "".join(f"{value}\n" for value in labels.astype(np.int64).tolist())
    with atomic_output(path, overwrite=overwrite) as temporary:
        temporary.write_text(text, encoding="ascii")
    return path


def write_points(path, points, *, normals=None, labels=None, colors=None, overwrite=False) -> Path:
    """Write a point cloud.

    Parameters
    ----------
    path : str or Path
      ``.ply`` (binary: float64 ``x y z``, ``nx ny nz``, then uchar ``red green blue`` and int
      ``part`` when given), ``.xyz`` (text, 3 or 6 columns) or ``.npy`` ((n, 3) or (n, 6)).
    points : (n, 3) float
    normals : (n, 3) float or None
    labels : (n,) int or None
      A part index per point, the PLY property ``part`` (PLY only).
    colors : (n, 3) uint8 or None
      A colour per point (PLY only).

    Returns
    -------
    path : Path
    """
    path = Path(path)
    suffix = _write_suffix(path, _POINT_WRITE_SUFFIXES, "points")
    cloud = PointCloud(points, normals)
    n = len(cloud.points)
    if labels is not None:
        labels = np.asarray(labels)
        if labels.shape != (n,) or not (n == 0 or np.issubdtype(labels.dtype, np.integer)):
            raise ValueError(f"`labels` must be ({n},) int, got shape {labels.shape} dtype {labels.dtype}")
    if colors is not None:
        colors = np.asarray(colors)
        if colors.shape != (n, 3) or colors.dtype.kind == "f":
            raise ValueError(f"`colors` must be ({n}, 3) uint8, got shape {colors.shape} dtype {colors.dtype}")
    if (labels is not None or colors is not None) and suffix != ".ply":
        raise ValueError(f"{path}: labels and colours of points are written to .ply, not '{suffix}'")
    columns = cloud.points if cloud.normals is None else np.hstack([cloud.points, cloud.normals])
    with atomic_output(path, overwrite=overwrite) as temporary:
        if suffix == ".npy":
            with open(temporary, "wb") as handle:
                np.save(handle, columns)
        elif suffix == ".xyz":
            buffer = StringIO()
            np.savetxt(buffer, columns, fmt="%.17g")
            temporary.write_text(buffer.getvalue(), encoding="ascii")
        else:
            # Written here, not by trimesh's PointCloud export (trimesh 4.x): that writes float32
            # coordinates (10,000 normal points came back up to 2.2e-7 off; these are float64,
            # exact), no normals and no per-point `part` (a PointCloud has no vertex attributes),
            # and adds an alpha channel and a comment line.
            fields = [(name, "<f8") for name in ["x", "y", "z"] + ([] if cloud.normals is None else ["nx", "ny", "nz"])]
            fields += [(c, "u1") for c in ("red", "green", "blue")] if colors is not None else []
            fields += [("part", "<i4")] if labels is not None else []
            record = np.zeros(n, dtype=fields)
            for i, (name, _) in enumerate(fields[: columns.shape[1]]):
                record[name] = columns[:, i]
            if colors is not None:
                for i, c in enumerate(("red", "green", "blue")):
                    record[c] = colors[:, i]
            if labels is not None:
                record["part"] = labels
            kind = {"<f8": "double", "u1": "uchar", "<i4": "int"}
            header = "".join(
                ["ply\nformat binary_little_endian 1.0\n", f"element vertex {n}\n"]
                + [f"property {kind[t]} {name}\n" for name, t in fields]
                + ["end_header\n"]
            )
            temporary.write_bytes(header.encode("ascii") + record.tobytes())
    return path


def write_voxels(path, grid: VoxelGrid, *, overwrite=False) -> Path:
    """Write a voxel grid as ``.binvox`` (the layout :func:`read_voxels` reads: run-length pairs
    with x slowest, then z, then y fastest; ``translate`` and ``scale`` in the header), so that
    ``read_voxels(write_voxels(p, g))`` gives ``g`` back. Written here because none of our
    dependencies writes binvox (trimesh reads it and writes it only through the external binvox
    program).

    Returns
    -------
    path : Path
    """
    path = Path(path)
    _write_suffix(path, VOXEL_SUFFIXES, "voxel grid")
    if not isinstance(grid, VoxelGrid):
        raise TypeError(f"`grid` must be a VoxelGrid, got {type(grid).__name__}")
    r = grid.resolution
    flat = np.ascontiguousarray(grid.occupancy.transpose(0, 2, 1)).ravel().astype(np.uint8)  # [x, z, y]
    change = np.flatnonzero(np.diff(flat)) + 1
    starts = np.concatenate([[0], change])
    lengths = np.diff(np.concatenate([starts, [flat.size]]))
    values = flat[starts]
    # runs longer than 255 are split into full pieces of 255 and a remainder
    pieces = -(-lengths // 255)
    run_values = np.repeat(values, pieces)
    run_counts = np.full(pieces.sum(), 255, np.int64)
    ends = np.cumsum(pieces) - 1
    run_counts[ends] = lengths - 255 * (pieces - 1)
    payload = np.stack([run_values, run_counts.astype(np.uint8)], axis=1).tobytes()
    t = " ".join(repr(float(x)) for x in grid.translate)
    header = f"#binvox 1\ndim {r} {r} {r}\ntranslate {t}\nscale {float(grid.scale)!r}\ndata\n".encode("ascii")
    with atomic_output(path, overwrite=overwrite) as temporary:
        temporary.write_bytes(header + payload)
    return path


def _short(exc: BaseException, limit: int = 120) -> str:
    """One short line describing an exception from a parser."""
    text = " ".join(str(exc).split()) or type(exc).__name__
    return text if len(text) <= limit else text[: limit - 3] + "..."


def _unsupported(path, suffixes, what) -> ShapeFileError:
    suffix = Path(path).suffix or "(none)"
    return ShapeFileError(
        path, f"unsupported suffix '{suffix}' for a {what} (expected one of {', '.join(suffixes)})"
    )


# text formats whose leading UTF-8 byte-order mark is dropped (it is not part of the first line)
_TEXT_SUFFIXES = (".obj", ".off", ".xyz", ".seg")


def _read_checked(path, suffixes, what) -> bytes:
    """Bytes of ``path`` after checking suffix, existence and emptiness; a UTF-8 byte-order mark
    at the start of a text format is dropped. Every failure is a ShapeFileError naming ``path``."""
    p = Path(path)
    if p.suffix.lower() not in suffixes:
        raise _unsupported(path, suffixes, what)
    try:
        # os.stat, not Path.exists: that raises its own OSError for a name too long or a folder
        # that cannot be searched, naming no reader
        st = os.stat(p)
    except FileNotFoundError:
        raise ShapeFileError(path, "no such file") from None
    except NotADirectoryError:
        raise ShapeFileError(path, "no such file (a parent is not a folder)") from None
    except (OSError, ValueError) as exc:
        raise ShapeFileError(path, f"cannot read: {getattr(exc, 'strerror', None) or _short(exc)}") from exc
    if stat.S_ISDIR(st.st_mode):
        raise ShapeFileError(path, "is a directory")
    try:
        data = p.read_bytes()
    except OSError as exc:
        raise ShapeFileError(path, f"cannot read: {exc.strerror or _short(exc)}") from exc
    if p.suffix.lower() in _TEXT_SUFFIXES and data.startswith(codecs.BOM_UTF8):
        data = data[len(codecs.BOM_UTF8):]
    if not data.strip():
        raise ShapeFileError(path, "empty file")
    return data


def _check_engine(engine) -> None:
    if engine not in ENGINES:
        raise ValueError(f"`engine` must be one of {', '.join(map(repr, ENGINES))}, got {engine!r}")


def _kernels():
    """The compiled text parsers of :mod:`primkit.io._text_kernels`, loaded (and compiled) on first
    use. Numba is a dependency: a kernel that fails to import fails loudly, never silently slow."""
    from types import SimpleNamespace

    from ._text_kernels import OK, gather_tokens, parse_labels, parse_obj, parse_off, parse_rows

    return SimpleNamespace(OK=OK, gather_tokens=gather_tokens, parse_labels=parse_labels, parse_obj=parse_obj,
                           parse_off=parse_off, parse_rows=parse_rows)


def _fill_slow(kernels, buf: np.ndarray, flat: np.ndarray, slow: np.ndarray) -> None:
    """Convert the numbers the compiled parser left to Python (``slow``: (flat index, start, end)
    rows of ``buf``) as trimesh and NumPy convert text (``np.array(tokens, float)``), into ``flat``."""
    if len(slow):
        tokens = kernels.gather_tokens(buf, slow).tobytes().decode("ascii").split()
        flat[slow[:, 0]] = np.array(tokens, dtype=np.float64)


# Not measurably faster than meshio for `primkit segment` on the COSEG chairs: 11.26 s vs 11.80 s (bench_mesh_reader.py)
def _parse_mesh_text(path, data: bytes):
    """(vertices, faces) of a plain OFF or OBJ file by the compiled parser, or None (not plain,
    another format): the caller then reads it with trimesh."""
    kind = Path(path).suffix.lower()
    kernels = _kernels() if kind in (".off", ".obj") else None
    if kernels is None:
        return None
    parse = kernels.parse_off if kind == ".off" else kernels.parse_obj
    buf = np.frombuffer(data, dtype=np.uint8)
    status, vertices, faces, slow = parse(buf)
    if status != kernels.OK:
        return None
    limits.check_faces(path, len(faces))
    _fill_slow(kernels, buf, vertices.reshape(-1), slow)
    return vertices, faces


def _parse_rows_text(data: bytes):
    """(rows, columns) float64 of plain whitespace-separated text by the compiled parser, or None."""
    kernels = _kernels()
    if kernels is None:
        return None
    buf = np.frombuffer(data, dtype=np.uint8)
    status, values, slow = kernels.parse_rows(buf)
    if status != kernels.OK:
        return None
    _fill_slow(kernels, buf, values.reshape(-1), slow)
    return values


def _parse_labels_text(data: bytes):
    """(rows,) int64 of a plain one-integer-a-line file by the compiled parser, or None."""
    kernels = _kernels()
    if kernels is None:
        return None
    status, labels = kernels.parse_labels(np.frombuffer(data, dtype=np.uint8))
    return labels if status == kernels.OK else None


def _obj_geometry_only(text: str) -> str:
    """Keep only the ``v`` and ``f`` lines of OBJ text, with bare vertex indices.

    trimesh splits an OBJ at every ``usemtl``/``o``/``g`` and duplicates vertices that carry
    several texture coordinates, both of which reorder the mesh; without them it keeps order.
    """
    lines = []
    for number, line in enumerate(text.splitlines(), 1):
        words = line.split(None, 1)
        if len(words) < 2:
            continue
        if words[0] == "v":
            lines.append("v " + words[1])
        elif words[0] == "f":
            corners = [token.split("/")[0] for token in words[1].split()]
            # OBJ counts vertices from 1 (negative: from the end); trimesh would read 0 as the last vertex
            if any(c.strip("+-").isdigit() and int(c) == 0 for c in corners):
                raise ValueError(f"line {number}: face index 0 (OBJ numbers vertices from 1)")
            lines.append("f " + " ".join(corners))
    return "\n".join(lines) + "\n"


def _load_trimesh(path, data: bytes):
    """Parse ``data`` with trimesh without reordering; wraps parser errors."""
    import trimesh

    p = Path(path)
    kind = p.suffix.lower()[1:]
    try:
        if kind == "obj":
            text = _obj_geometry_only(data.decode("utf-8", errors="replace"))
            if "\nv " not in "\n" + text:
                raise ValueError("no vertex lines")
            return trimesh.load(
                BytesIO(text.encode("utf-8")),
                file_type="obj",
                process=False,
                maintain_order=True,
                skip_materials=True,
            )
        if kind in ("glb", "gltf"):
            _check_gltf_faces(path, data)
        if kind == "gltf":  # buffers may live in separate files beside it
            return trimesh.load(str(p), process=False)
        return trimesh.load(BytesIO(data), file_type=kind, process=False)
    except ShapeFileError:
        raise
    except Exception as exc:  # trimesh raises many types for malformed input
        if kind == "obj" and isinstance(exc, IndexError):
            raise ShapeFileError(path, "face index out of range") from exc
        raise ShapeFileError(path, f"cannot parse as {kind.upper()}: {_short(exc)}") from exc


def _gltf_json(data: bytes):
    """The JSON document of GLB or glTF bytes, or None when it cannot be found (trimesh then says why)."""
    import json
    import struct

    try:
        if data[:4] == b"glTF":
            length, kind = struct.unpack("<I4s", data[12:20])
            if kind != b"JSON":
                return None
            data = data[20 : 20 + length]
        document = json.loads(data)
    except (ValueError, struct.error):
        return None
    return document if isinstance(document, dict) else None


def _check_gltf_faces(path, data: bytes) -> None:
    """Refuse a GLB/glTF whose declared faces exceed the bound before trimesh decodes anything.

    trimesh builds one mesh per glTF mesh (even when they share their accessors) and primkit one
    per node placing a mesh, so both counts are bounded: the faces of every mesh of the file, and
    the faces of every mesh placement reached from the scenes (a node reached twice counts twice).
    Counted from the accessors' declared ``count`` (triangles: indices / 3; strips and fans: n - 2).
    """
    document = _gltf_json(data)
    if document is None:
        return
    try:
        accessors = document.get("accessors", [])
        mesh_faces = []
        for mesh in document.get("meshes", []):
            faces = 0
            for primitive in mesh.get("primitives", []):
                mode = primitive.get("mode", 4)
                index = primitive.get("indices", primitive.get("attributes", {}).get("POSITION"))
                count = int(accessors[index]["count"]) if index is not None else 0
                faces += count // 3 if mode == 4 else max(count - 2, 0) if mode in (5, 6) else 0
            mesh_faces.append(faces)
        nodes = document.get("nodes", [])
        roots = [n for scene in document.get("scenes", []) for n in scene.get("nodes", [])]
    except (AttributeError, IndexError, KeyError, TypeError, ValueError):
        return  # malformed: trimesh's own error says so
    bound = limits.max_faces()
    limits.check_faces(path, sum(mesh_faces))
    placed, stack, visits = 0, list(roots), 0
    while stack and placed <= bound:
        visits += 1
        if visits > len(nodes) + 1_000_000:  # a graph that reaches its nodes again and again (a cycle)
            break
        node = stack.pop()
        if not isinstance(node, int) or not 0 <= node < len(nodes) or not isinstance(nodes[node], dict):
            continue
        mesh = nodes[node].get("mesh")
        if isinstance(mesh, int) and 0 <= mesh < len(mesh_faces):
            placed += mesh_faces[mesh]
        children = nodes[node].get("children", [])
        if isinstance(children, list):
            stack.extend(children)
    if stack:
        placed = max(placed, bound + 1)
    limits.check_faces(path, placed, "after instancing")


def _scene_parts(scene):
    """(vertices, faces) of every mesh node of a trimesh Scene, transforms applied."""
    import trimesh

    parts = []
    for node in scene.graph.nodes_geometry:
        transform, name = scene.graph[node]
        geometry = scene.geometry.get(name)
        if not isinstance(geometry, trimesh.Trimesh) or len(geometry.faces) == 0:
            continue
        transform = np.asarray(transform, dtype=np.float64)
        vertices = np.asarray(geometry.vertices, dtype=np.float64) @ transform[:3, :3].T
        vertices = vertices + transform[:3, 3]
        faces = np.asarray(geometry.faces, dtype=np.int64)
        if np.linalg.det(transform[:3, :3]) < 0:  # a mirror turns the surface inside out
            faces = faces[:, [0, 2, 1]]
        parts.append((vertices, faces))
    return parts


def _mesh_from_loaded(path, loaded) -> Mesh:
    """Validated Mesh from whatever trimesh returned."""
    import trimesh

    if isinstance(loaded, trimesh.Scene):
        if not loaded.geometry and Path(path).suffix.lower() not in (".glb", ".gltf"):
            # trimesh returns an empty scene when none of its loaders understood the bytes
            kind = Path(path).suffix.lower()[1:].upper()
            raise ShapeFileError(path, f"cannot parse as {kind}: no geometry found")
        # counted before the instances are expanded: a 1 MB GLB can place one mesh 3,000 times
        limits.check_faces(path, _scene_face_count(loaded), "after instancing")
        parts = _scene_parts(loaded)
        if not parts:
            raise ShapeFileError(path, "no faces (no triangle mesh in the scene)")
        offsets = np.cumsum([0] + [len(v) for v, _ in parts[:-1]])
        vertices = np.concatenate([v for v, _ in parts])
        faces = np.concatenate([f + o for (_, f), o in zip(parts, offsets)])
    elif isinstance(loaded, trimesh.Trimesh):
        vertices = np.asarray(loaded.vertices, dtype=np.float64)
        faces = np.asarray(loaded.faces, dtype=np.int64).reshape(-1, 3)
    else:
        raise ShapeFileError(path, "no faces (a point cloud? use read_points)")
    if len(faces) == 0:
        raise ShapeFileError(path, "no faces (a point cloud? use read_points)")
    limits.check_faces(path, len(faces))
    return _checked_mesh(path, vertices, faces)


def _scene_face_count(scene) -> int:
    """Faces of every mesh node of a trimesh Scene, each instance counted (nothing expanded)."""
    import trimesh

    total = 0
    for node in scene.graph.nodes_geometry:
        geometry = scene.geometry.get(scene.graph[node][1])
        if isinstance(geometry, trimesh.Trimesh):
            total += len(geometry.faces)
    return total


def _checked_mesh(path, vertices, faces) -> Mesh:
    """The readers' checks on (vertices, faces) from any parser: finite coordinates, indices in
    range, STL's equal corners merged, a non-zero area."""
    if len(faces) == 0:
        raise ShapeFileError(path, "no faces (a point cloud? use read_points)")
    _require_finite(path, vertices, "vertices")
    try:  # a mesh scaled 1e200: its area overflows (a bare OverflowError before)
        check_coordinates(vertices, "vertices")
    except ValueError as exc:
        raise ShapeFileError(path, str(exc)) from None
    if faces.min() < 0 or faces.max() >= len(vertices):
        raise ShapeFileError(
            path,
            f"face index out of range ({int(faces.min())}..{int(faces.max())} "
            f"for {len(vertices)} vertices)",
        )
    if Path(path).suffix.lower() == ".stl":
        vertices, faces = _merge_equal_vertices(vertices, faces)

    mesh = Mesh(vertices, faces)
    used = vertices[np.unique(faces)]  # a vertex no face references says nothing of the area's scale
    extent = float(np.ptp(used, axis=0).max()) if len(used) else 0.0
    if not mesh.area() > 1e-12 * extent**2:
        raise ShapeFileError(path, "zero total area (all faces are degenerate)")
    return mesh


def _merge_equal_vertices(vertices, faces):
    """Merge exactly equal vertices, numbered in order of first appearance."""
    unique, first, inverse = np.unique(vertices, axis=0, return_index=True, return_inverse=True)
    order = np.argsort(first)
    rank = np.empty(len(order), dtype=np.int64)
    rank[order] = np.arange(len(order))
    return unique[order], rank[inverse.reshape(-1)][faces]


def _points_from_loaded(path, loaded) -> PointCloud:
    """Validated PointCloud from a trimesh result for a PLY without faces."""
    import trimesh

    if isinstance(loaded, trimesh.Trimesh) and len(loaded.faces):
        raise ShapeFileError(path, f"has {len(loaded.faces)} faces; read it with read_mesh")
    if not isinstance(loaded, (trimesh.Trimesh, trimesh.PointCloud)):
        raise ShapeFileError(path, f"no points (parsed as {type(loaded).__name__})")
    points = np.asarray(loaded.vertices, dtype=np.float64).reshape(-1, 3)
    normals = None
    # trimesh keeps the PLY vertex properties: a dict for ASCII, a structured array for binary
    raw = loaded.metadata.get("_ply_raw", {}).get("vertex", {}).get("data")
    if isinstance(raw, dict):
        names = raw.keys()
    else:
        names = getattr(getattr(raw, "dtype", None), "names", None)
    if names is not None and {"nx", "ny", "nz"} <= set(names):
        normals = np.column_stack([np.asarray(raw[k], np.float64) for k in ("nx", "ny", "nz")])
    if normals is not None and normals.shape != points.shape:
        normals = None
    return _checked_points(path, points, normals)


def _require_finite(path, coordinates, what: str) -> None:
    """ShapeFileError naming how many rows of ``coordinates`` ((n, 3) float) hold NaN or inf."""
    bad = ~np.isfinite(coordinates).all(axis=1)
    if bad.any():
        raise ShapeFileError(path, f"NaN or inf coordinates in {int(bad.sum())} of {len(coordinates)} {what}")


def _checked_points(path, points, normals) -> PointCloud:
    if len(points) == 0:
        raise ShapeFileError(path, "no points")
    _require_finite(path, points, "points")
    if normals is not None and not np.isfinite(normals).all():
        raise ShapeFileError(path, "normals have NaN or inf values")
    return PointCloud(points, normals)


def _parse_binvox_header(path, data: bytes):
    """Header fields ``dim``, ``translate``, ``scale`` and the run-length payload."""
    marker = data.find(b"\ndata\n")
    if not data.startswith(b"#binvox") or marker < 0:
        raise ShapeFileError(path, "cannot parse as BINVOX: missing '#binvox' or 'data' line")
    header = {"translate": [0.0, 0.0, 0.0], "scale": 1.0}
    try:
        for line in data[:marker].decode("ascii").splitlines()[1:]:
            words = line.split()
            if not words or words[0].startswith("#"):
                continue
            if words[0] == "dim":
                header["dim"] = [int(w) for w in words[1:4]]
            elif words[0] == "translate":
                header["translate"] = [float(w) for w in words[1:4]]
            elif words[0] == "scale":
                header["scale"] = float(words[1])
    except (UnicodeDecodeError, ValueError, IndexError) as exc:
        raise ShapeFileError(path, f"cannot parse as BINVOX: bad header ({_short(exc)})") from exc
    dims = header.get("dim")
    if dims is None or len(dims) != 3 or min(dims) < 1:
        raise ShapeFileError(path, "cannot parse as BINVOX: missing or bad 'dim' line")
    if len(header["translate"]) != 3:
        raise ShapeFileError(path, "cannot parse as BINVOX: bad 'translate' line")
    return header, data[marker + len(b"\ndata\n") :]


def _rgba_uint8(colors, count) -> np.ndarray:
    """(count, 4) uint8 from (count, 3|4) uint8 or float in [0, 1]."""
    colors = np.asarray(colors)
    if colors.ndim != 2 or len(colors) != count or colors.shape[1] not in (3, 4):
        raise ValueError(
            f"`face_colors` must be (f, 3) or (f, 4) with f = {count}, got {colors.shape}"
        )
    if np.issubdtype(colors.dtype, np.floating):
        if not np.isfinite(colors).all() or colors.min() < 0 or colors.max() > 1:
            raise ValueError("float `face_colors` must lie in [0, 1]")
        colors = np.round(colors * 255.0)
    elif np.issubdtype(colors.dtype, np.integer):
        if colors.size and (colors.min() < 0 or colors.max() > 255):
            raise ValueError("integer `face_colors` must lie in [0, 255]")
    else:
        raise ValueError(f"`face_colors` must be uint8 or float, got dtype {colors.dtype}")
    colors = colors.astype(np.uint8)
    if colors.shape[1] == 3:
        colors = np.column_stack([colors, np.full(count, 255, dtype=np.uint8)])
    return colors


def _write_suffix(path: Path, allowed, what: str) -> str:
    """``path``'s lower-cased suffix, or ValueError naming the file when we cannot write ``what`` in it."""
    suffix = path.suffix.lower()
    if suffix not in allowed:
        raise ValueError(f"{path}: cannot write {what} as '{suffix}' (expected one of {', '.join(allowed)})")
    return suffix


def _vertex_lines(vertices, prefix: str) -> str:
    buffer = StringIO()
    np.savetxt(buffer, vertices, fmt="%.17g")
    text = buffer.getvalue()
    if not prefix:
        return text
    return "".join(f"{prefix}{line}\n" for line in text.splitlines())


def _off_text(mesh: Mesh) -> str:
    faces = np.column_stack([np.full(len(mesh.faces), 3, dtype=np.int64), mesh.faces])
    buffer = StringIO()
    np.savetxt(buffer, faces, fmt="%d")
    return (
        f"OFF\n{len(mesh.vertices)} {len(mesh.faces)} 0\n"
        + _vertex_lines(mesh.vertices, "")
        + buffer.getvalue()
    )


def _ply_bytes(mesh: Mesh, colors) -> bytes:
    """Binary little-endian PLY: float32 vertices, int32 triangles, optional RGBA per face (the
    layout trimesh's exporter writes). Written with NumPy: importing trimesh for it cost about 1 s of
    a one-shape ``segment`` or ``abstract`` run."""
    head = ["ply", "format binary_little_endian 1.0", "comment written by primkit",
            f"element vertex {len(mesh.vertices)}", "property float x", "property float y", "property float z",
            f"element face {len(mesh.faces)}", "property list uchar int vertex_indices"]
    fields = [("n", "u1"), ("v", "<i4", (3,))]
    if colors is not None:
        head += [f"property uchar {c}" for c in ("red", "green", "blue", "alpha")]
        fields.append(("rgba", "u1", (4,)))
    face = np.empty(len(mesh.faces), dtype=fields)
    face["n"] = 3
    face["v"] = mesh.faces
    if colors is not None:
        face["rgba"] = colors
    vertices = np.ascontiguousarray(mesh.vertices, "<f4")
    return ("\n".join(head + ["end_header"]) + "\n").encode("ascii") + vertices.tobytes() + face.tobytes()


def _write_obj(path: Path, mesh: Mesh, colors, overwrite: bool) -> None:
    """OBJ text, plus a ``.mtl`` with one material per distinct face colour."""
    face_lines = [f"f {a} {b} {c}\n" for a, b, c in (mesh.faces + 1).tolist()]
    head = "# written by primkit\n"
    if colors is None:
        text = head + _vertex_lines(mesh.vertices, "v ") + "".join(face_lines)
        with atomic_output(path, overwrite=overwrite) as temporary:
            temporary.write_text(text, encoding="ascii")
        return

    mtl_path = path.with_suffix(".mtl")
    palette, material = np.unique(colors, axis=0, return_inverse=True)
    material = material.reshape(-1)
    mtl = "".join(
        f"newmtl color_{k}\nKd {r / 255:.6f} {g / 255:.6f} {b / 255:.6f}\nd {a / 255:.6f}\n\n"
        for k, (r, g, b, a) in enumerate(palette.tolist())
    )
    # a usemtl before each run of equal material keeps the faces in order
    starts = np.flatnonzero(np.r_[True, material[1:] != material[:-1]]).tolist()
    body = []
    for i, start in enumerate(starts):
        stop = starts[i + 1] if i + 1 < len(starts) else len(face_lines)
        body.append(f"usemtl color_{material[start]}\n")
        body.extend(face_lines[start:stop])
    text = f"{head}mtllib {mtl_path.name}\n" + _vertex_lines(mesh.vertices, "v ") + "".join(body)
    with atomic_output(path, overwrite=overwrite) as obj_tmp, atomic_output(
        mtl_path, overwrite=overwrite
    ) as mtl_tmp:
        mtl_tmp.write_text(mtl, encoding="ascii")
        obj_tmp.write_text(text, encoding="ascii")


def write_like(source_path, path, vertices, faces, *, overwrite: bool = False) -> Path:
    """Write ``vertices`` with the source's faces; when ``path`` has the source's suffix (PLY, OBJ,
    GLB) and trimesh reads the source with the same vertices and faces, its other attributes
    (vertex colours, texture coordinates) are kept. Otherwise :func:`write_mesh`."""
    src, path = Path(source_path), Path(path)
    if src.suffix.lower() == path.suffix.lower() and path.suffix.lower() in (".ply", ".obj", ".glb"):
        try:
            import trimesh  # imported on first use, as by the readers

            tm = trimesh.load(str(src), process=False, maintain_order=True, force="mesh")
            same = len(tm.vertices) == len(vertices) and np.array_equal(np.asarray(tm.faces), np.asarray(faces))
        except Exception:  # noqa: BLE001 - fall back to the plain writer
            same = False
        if same:
            tm.vertices = np.asarray(vertices, float)
            payload = tm.export(file_type=path.suffix.lower()[1:])
            with atomic_output(path, overwrite=overwrite) as tmp:
                Path(tmp).write_bytes(payload if isinstance(payload, bytes) else payload.encode())
            return path
    return write_mesh(path, vertices, faces, overwrite=overwrite)
