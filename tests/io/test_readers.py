"""The compiled text readers against the old path (trimesh, np.loadtxt), the byte-order mark,
the resource bounds (measured under an address-space limit) and the paths in I/O errors."""

import codecs
import errno
import json
import os
import re
import struct
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest
import trimesh

from primkit import io
from primkit.io import ShapeFileError, limits, read_labels, read_mesh, read_points, read_voxels

REPO = Path(__file__).resolve().parents[2]


def same_bits(a, b) -> bool:
    return a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes()


def read_both(reader, path):
    """(auto, trimesh) results of ``reader``: arrays, or the error text."""
    out = []
    for engine in ("auto", "trimesh"):
        try:
            out.append(reader(path, engine=engine))
        except ShapeFileError as err:
            out.append(str(err))
    return out


# ------------------------------------------------------------------------------ shared data


@pytest.mark.slow  # a sweep: every shared mesh read twice
@pytest.mark.shared
def test_readers_give_the_old_arrays_on_every_shared_mesh(shared_data):
    files = sorted(p for p in shared_data.rglob("*") if p.suffix.lower() in io.MESH_SUFFIXES + (".xyz", ".npy"))
    assert files
    fast, declined = 0, []
    for number, path in enumerate(files):
        if path.suffix.lower() in (".xyz", ".npy"):
            a, b = read_both(read_points, path)
            assert same_bits(a.points, b.points), path
            continue
        a, b = read_both(read_mesh, path)
        assert same_bits(a.vertices, b.vertices) and same_bits(a.faces, b.faces), path
        if path.suffix.lower() == ".off" and number % 5 == 0:  # and against trimesh itself, outside primkit
            tm = trimesh.load(path, process=False)
            assert same_bits(a.vertices, np.asarray(tm.vertices, np.float64)), path
            assert np.array_equal(a.faces, tm.faces), path
        data = path.read_bytes()
        if io.formats._parse_mesh_text(path, data) is not None:
            fast += 1
        elif path.suffix.lower() in (".off", ".obj"):  # left to trimesh: only OBJ files with normals or UVs
            assert path.suffix.lower() == ".obj" and re.search(rb"^v[nt]\s", data, re.M), path
            declined.append(path)
    # the plain OFF and OBJ files went through the compiled parser
    assert fast + len(declined) == sum(p.suffix.lower() in (".off", ".obj") for p in files)
    assert fast > 10 * len(declined)


@pytest.mark.shared
def test_labels_equal_loadtxt_on_every_shared_seg(shared_data):
    files = sorted(shared_data.rglob("*.seg"))
    assert files
    for path in files:
        labels = read_labels(path)
        assert same_bits(labels, np.loadtxt(path, dtype=np.int64, ndmin=1)), path


# ------------------------------------------------------------------------------ synthetic text


def _numbers(rng, count):
    """Coordinates of every kind a file holds: short decimals, 17 digits, exponents, zeros, huge."""
    values = rng.normal(size=count) * 10.0 ** rng.integers(-30, 30, size=count)
    values[::7] = np.round(values[::7], 3)
    values[::11] = 0.0
    values[::13] = -0.0
    return values


FORMATS = ("%.17g", "%.6f", "%g", "%.3e", "%.9E", "%+.4f", "%.25f")


@pytest.mark.parametrize("fmt", FORMATS)
def test_off_and_obj_numbers_equal_pythons_float(tmp_path, fmt):
    rng = np.random.default_rng(abs(hash(fmt)) % 2**32)
    v = _numbers(rng, 3 * 400).reshape(-1, 3)
    v[:, 0] += np.arange(len(v))  # no zero area
    f = rng.integers(0, len(v), size=(300, 3))
    rows = "\n".join(" ".join(fmt % x for x in row) for row in v)
    faces = "\n".join("3 %d %d %d" % tuple(r) for r in f)
    off = tmp_path / "m.off"
    off.write_text(f"OFF\n{len(v)} {len(f)} 0\n{rows}\n{faces}\n")
    obj = tmp_path / "m.obj"
    obj.write_text("\n".join("v " + " ".join(fmt % x for x in row) for row in v) + "\n"
                   + "\n".join("f %d/1 %d/2 %d/3" % tuple(r + 1) for r in f) + "\n")
    expected = np.array([[float(fmt % x) for x in row] for row in v])  # Python's own parser
    for path in (off, obj):
        a, b = read_both(read_mesh, path)
        assert same_bits(a.vertices, expected) and same_bits(b.vertices, expected), path
        assert np.array_equal(a.faces, f) and same_bits(a.faces, b.faces)
    xyz = tmp_path / "p.xyz"
    xyz.write_text(rows + "\n")
    a, b = read_both(read_points, xyz)
    assert same_bits(a.points, expected) and same_bits(b.points, expected)


EDGE_NUMBERS = [
    "0.1", "0.3", "1e22", "1e23", "1e-22", "1e-23", "9007199254740992", "9007199254740993",
    "123456789012345678", "1234567890123456789012", "0.000000000000000000000000001", "4.9e-324",
    "2.2250738585072014e-308", "1.7976931348623157e308", "1e309", "-0", "-0.0e5", ".5", "5.", "00001.5000",
    "1E+5", "+7", "3.14159265358979323846", "0.30000000000000004", "1e-400", "100000000000000000000000",
    "8.589973e9", "1.0000000000000002", "0.1000000000000000055511151231257827",
]


def test_edge_numbers_equal_pythons_float(tmp_path):
    tokens = EDGE_NUMBERS + ["1"] * (-len(EDGE_NUMBERS) % 3)
    path = tmp_path / "edge.xyz"
    path.write_text("\n".join(" ".join(tokens[k:k + 3]) for k in range(0, len(tokens), 3)) + "\n")
    kernels = io.formats._kernels()
    status, values, _ = kernels.parse_rows(np.frombuffer(path.read_bytes(), np.uint8))
    assert status == kernels.OK  # all of them go through the compiled parser (some left to Python)
    expected = np.array([float(t) for t in tokens]).reshape(-1, 3)
    got = io.formats._parse_rows_text(path.read_bytes())
    assert same_bits(got, expected)


TET = "0 0 0\n1 0 0\n0 1 0\n0 0 1\n"
TET_FACES = "3 0 1 2\n3 0 3 1\n3 0 2 3\n3 1 3 2\n"

# files off the plain path (or at its edges): both engines must agree, arrays or error text
VARIANTS = {
    "plain": f"OFF\n4 4 6\n{TET}{TET_FACES}",
    "crlf": f"OFF\r\n4 4 6\r\n{TET}{TET_FACES}".replace("\n", "\r\n").replace("\r\r", "\r"),
    "tabs and blank lines": f"OFF\n\n4\t4\t6\n\n{TET}\n\n{TET_FACES}\n\n".replace(" ", "\t"),
    "counts on the OFF line": f"OFF 4 4 6\n{TET}{TET_FACES}",
    "two counts": f"OFF\n4 4\n{TET}{TET_FACES}",
    "comment": f"# made by hand\nOFF\n4 4 6 # counts\n{TET}{TET_FACES}",
    "coff colours": f"COFF\n4 4 6\n" + TET.replace("\n", " 255 0 0 255\n") + TET_FACES,
    "extra vertex column": f"OFF\n4 4 6\n" + TET.replace("\n", " 1\n") + TET_FACES,
    "quad": f"OFF\n4 3 6\n{TET}4 0 1 2 3\n3 0 3 1\n3 0 2 3\n",
    "face colours": f"OFF\n4 4 6\n{TET}" + TET_FACES.replace("\n", " 255 0 0\n"),
    "lone cr": f"OFF\n4 4 6\r{TET}{TET_FACES}",
    "trailing text": f"OFF\n4 4 6\n{TET}{TET_FACES}junk\n",
    "too few vertices": f"OFF\n5 4 6\n{TET}{TET_FACES}",
    "index out of range": f"OFF\n4 4 6\n{TET}{TET_FACES}3 0 1 9\n".replace("4 4 6", "4 5 6"),
    "negative index": f"OFF\n4 4 6\n{TET}{TET_FACES}".replace("3 0 1 2", "3 0 1 -2"),
    "nan": f"OFF\n4 4 6\n{TET.replace('1 0 0', 'nan 0 0')}{TET_FACES}",
    "inf": f"OFF\n4 4 6\n{TET.replace('1 0 0', '1 -inf 0')}{TET_FACES}",
    "plus signs": f"OFF\n4 4 6\n{TET.replace('1 0 0', '+1 +0.0e+0 -0')}{TET_FACES}",
    "huge header": "OFF\n999999999999 999999999999 0\n0 0 0\n",
    "degenerate": "OFF\n3 1 0\n0 0 0\n1 0 0\n2 0 0\n3 0 1 2\n",
    "latin-1 comment": f"OFF\n4 4 6\n{TET}{TET_FACES}# caf\xe9\n",
    "no newline at the end": f"OFF\n4 4 6\n{TET}{TET_FACES}".rstrip("\n"),
}

OBJ_TET = "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\n"
OBJ_FACES = "f 1 2 3\nf 1 4 2\nf 1 3 4\nf 2 4 3\n"
OBJ_VARIANTS = {
    "plain": OBJ_TET + OBJ_FACES,
    "groups and materials": "mtllib m.mtl\no a\n" + OBJ_TET + "g one\nusemtl red\ns 1\n" + OBJ_FACES,
    "texture and normals": OBJ_TET + "vt 0 0\nvn 0 0 1\n" + OBJ_FACES.replace(" 2", " 2/1/1").replace(" 4", " 4//1"),
    "indented and crlf": (OBJ_TET + OBJ_FACES).replace("v ", "  v\t").replace("\n", "\r\n"),
    "quad": OBJ_TET + "f 1 2 3 4\nf 1 4 2\n",
    "negative index": OBJ_TET + "f -4 -3 -2\nf 1 4 2\n",
    "index zero": OBJ_TET + "f 0 1 2\n",
    "index out of range": OBJ_TET + "f 1 2 9\n",
    "vertex colours": OBJ_TET.replace("\n", " 1 0 0\n") + OBJ_FACES,
    "w coordinate": OBJ_TET.replace("\n", " 1\n") + OBJ_FACES,
    "unreferenced vertices": "v 0 0 0\nv 5 5 5\n" + OBJ_TET[8:] + "v 9 9 9\n" + OBJ_FACES.replace("1", "4"),
    "faces before vertices": OBJ_FACES + OBJ_TET,
    "trailing slashes": OBJ_TET + OBJ_FACES.replace(" 3", " 3/"),
    "no faces": OBJ_TET,
    "comment only": "# nothing\n",
    "unicode comment": "# \u00e9t\u00e9\n" + OBJ_TET + OBJ_FACES,
}


@pytest.mark.parametrize("case", list(VARIANTS))
def test_off_variants_read_alike_by_both_engines(tmp_path, case):
    path = tmp_path / "v.off"
    path.write_bytes(VARIANTS[case].encode("latin-1"))
    a, b = read_both(read_mesh, path)
    if isinstance(b, str):
        assert a == b
    else:
        assert same_bits(a.vertices, b.vertices) and same_bits(a.faces, b.faces)


@pytest.mark.parametrize("case", list(OBJ_VARIANTS))
def test_obj_variants_read_alike_by_both_engines(tmp_path, case):
    path = tmp_path / "v.obj"
    path.write_text(OBJ_VARIANTS[case], encoding="utf-8")
    a, b = read_both(read_mesh, path)
    if isinstance(b, str):
        assert a == b
    else:
        assert same_bits(a.vertices, b.vertices) and same_bits(a.faces, b.faces)


@pytest.mark.parametrize("text", ["1\n2\n-3\n", "\n1\n\n2\n", "1 2\n3 4\n", "1\n2.5\n", "+1\n2\n", "1\r\n2\r\n", "7"])
def test_labels_read_alike_by_both_engines(tmp_path, text):
    path = tmp_path / "l.seg"
    path.write_text(text)
    a, b = read_both(read_labels, path)
    assert a == b if isinstance(b, str) else same_bits(a, b)


@pytest.mark.parametrize("text", ["1 2 3\n4 5 6\n", "1,2,3\n", "1 2 3 # c\n", "1 2\n3 4 5\n", "1 2 3 4 5 6\n"])
def test_xyz_read_alike_by_both_engines(tmp_path, text):
    path = tmp_path / "p.xyz"
    path.write_text(text)
    a, b = read_both(read_points, path)
    if isinstance(b, str):
        assert a == b
    else:
        assert same_bits(a.points, b.points)
        assert (a.normals is None) == (b.normals is None)


def test_unknown_engine_is_refused(tmp_path):
    with pytest.raises(ValueError, match="engine"):
        read_mesh(tmp_path / "m.off", engine="fast")


# ------------------------------------------------------------------------------ byte-order mark


@pytest.mark.parametrize("suffix, text", [(".obj", OBJ_TET + OBJ_FACES), (".off", VARIANTS["plain"])])
def test_a_byte_order_mark_is_read_as_nothing(tmp_path, suffix, text):
    plain = tmp_path / f"plain{suffix}"
    plain.write_text(text)
    marked = tmp_path / f"marked{suffix}"
    marked.write_bytes(codecs.BOM_UTF8 + text.encode())
    for engine in io.formats.ENGINES:
        a, b = read_mesh(plain, engine=engine), read_mesh(marked, engine=engine)
        assert len(b.vertices) == 4 and same_bits(a.vertices, b.vertices) and same_bits(a.faces, b.faces)
    labels = tmp_path / "l.seg"
    labels.write_bytes(codecs.BOM_UTF8 + b"1\n2\n")
    assert read_labels(labels).tolist() == [1, 2]


# ------------------------------------------------------------------------------ resource bounds


def _grid_binvox(path: Path, side: int) -> Path:
    """A binvox of ``side``^3 voxels, alternately empty and full in runs of 255: a few bytes per
    255 voxels on disk (1024^3: 8.4 MB), ``side``^3 bytes once decoded."""
    runs = -(-side**3 // 255)
    counts = np.full(runs, 255, np.uint8)
    counts[-1] = side**3 - 255 * (runs - 1)
    values = (np.arange(runs) % 2).astype(np.uint8)
    header = f"#binvox 1\ndim {side} {side} {side}\ntranslate 0 0 0\nscale 1\ndata\n".encode()
    path.write_bytes(header + np.stack([values, counts], axis=1).tobytes())
    return path


def _instanced_glb(path: Path, copies: int, side: int = 102) -> Path:
    """A GLB of one triangulated grid (2 (side - 1)^2 faces) referenced by ``copies`` meshes and
    nodes (the shape of the 1.1 MB file of issue 36 that expands to 61M faces)."""
    i, j = np.meshgrid(np.arange(side - 1), np.arange(side - 1), indexing="ij")
    k = (i * side + j).ravel()
    faces = np.concatenate([np.stack([k, k + 1, k + side], 1), np.stack([k + 1, k + side + 1, k + side], 1)])
    x, y = np.meshgrid(np.arange(side, dtype=np.float32), np.arange(side, dtype=np.float32), indexing="ij")
    vertices = np.stack([x.ravel(), y.ravel(), np.zeros(side * side, np.float32)], 1)
    index_bytes, vertex_bytes = faces.astype(np.uint32).tobytes(), vertices.tobytes()
    document = {
        "asset": {"version": "2.0"},
        "scene": 0,
        "scenes": [{"nodes": list(range(copies))}],
        "nodes": [{"mesh": n, "translation": [float(n), 0.0, 0.0]} for n in range(copies)],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 1}, "indices": 0, "mode": 4}]}] * copies,
        "buffers": [{"byteLength": len(index_bytes) + len(vertex_bytes)}],
        "bufferViews": [
            {"buffer": 0, "byteOffset": 0, "byteLength": len(index_bytes)},
            {"buffer": 0, "byteOffset": len(index_bytes), "byteLength": len(vertex_bytes)},
        ],
        "accessors": [
            {"bufferView": 0, "componentType": 5125, "count": faces.size, "type": "SCALAR"},
            {"bufferView": 1, "componentType": 5126, "count": len(vertices), "type": "VEC3",
             "min": vertices.min(0).tolist(), "max": vertices.max(0).tolist()},
        ],
    }
    text = json.dumps(document).encode()
    text += b" " * (-len(text) % 4)
    binary = index_bytes + vertex_bytes
    binary += b"\0" * (-len(binary) % 4)
    chunks = struct.pack("<I4s", len(text), b"JSON") + text + struct.pack("<I4s", len(binary), b"BIN\0") + binary
    path.write_bytes(struct.pack("<4sII", b"glTF", 2, 12 + len(chunks)) + chunks)
    return path


def _read_under_address_limit(path: Path, reader: str, headroom_mib: int, env=None) -> str:
    """Read ``path`` in a fresh process whose address space may grow only ``headroom_mib`` beyond
    what it has once primkit, NumPy and trimesh are loaded; returns its one output line."""
    script = textwrap.dedent(f"""
        import resource, sys
        import numpy, trimesh, trimesh.exchange.gltf
        from primkit import io
        from primkit.io import _text_kernels  # the compiled parsers loaded before the limit is set, as in a running program
        size = int(open("/proc/self/statm").read().split()[0]) * resource.getpagesize()
        limit = size + {headroom_mib} * 2**20
        resource.setrlimit(resource.RLIMIT_AS, (limit, limit))
        try:
            io.{reader}({str(path)!r})
            print("read")
        except io.ShapeFileError as err:
            print("ShapeFileError", err)
        except MemoryError:
            print("MemoryError")
    """)
    environment = {**os.environ, "PYTHONPATH": str(REPO), "OMP_NUM_THREADS": "1", **(env or {})}
    run = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, env=environment, timeout=300)
    lines = run.stdout.strip().splitlines()
    return lines[-1] if lines else f"rc {run.returncode}: {run.stderr.strip()[-300:]}"


def test_a_binvox_declaring_a_huge_grid_is_refused_before_decoding(tmp_path):
    path = _grid_binvox(tmp_path / "huge.binvox", 1024)  # 8.4 MB, 1 GiB decoded
    assert path.stat().st_size < 9e6
    line = _read_under_address_limit(path, "read_voxels", 400)
    assert line == f"ShapeFileError {path}: a 1024^3 voxel grid exceeds the bound of 512^3 " \
                   "(raise it with PRIMKIT_MAX_GRID=N or primkit.io.limits.MAX_GRID)", line


def test_a_glb_instancing_one_mesh_thousands_of_times_is_refused_before_decoding(tmp_path):
    path = _instanced_glb(tmp_path / "many.glb", 3000)  # 3,000 x 20,402 faces = 61.2M
    assert path.stat().st_size < 2e6
    line = _read_under_address_limit(path, "read_mesh", 400)
    assert line.startswith(f"ShapeFileError {path}: 61,206,000 faces exceed the bound of 20,000,000 "), line
    assert "PRIMKIT_MAX_FACES" in line


def test_bounds_are_raised_by_the_environment_or_the_module(tmp_path, monkeypatch):
    glb = _instanced_glb(tmp_path / "few.glb", 3, side=6)  # 3 x 50 faces, placed 3 times
    off = tmp_path / "m.off"
    off.write_text(VARIANTS["plain"])
    binvox = _grid_binvox(tmp_path / "g.binvox", 8)
    monkeypatch.setenv("PRIMKIT_MAX_FACES", "100")
    with pytest.raises(ShapeFileError, match=r"150 faces exceed the bound of 100 \(raise it with PRIMKIT_MAX_FACES"):
        read_mesh(glb)
    monkeypatch.setenv("PRIMKIT_MAX_FACES", "3")
    for engine in io.formats.ENGINES:
        with pytest.raises(ShapeFileError, match="4 faces exceed the bound of 3"):
            read_mesh(off, engine=engine)
    monkeypatch.delenv("PRIMKIT_MAX_FACES")
    monkeypatch.setattr(limits, "MAX_FACES", 149)
    with pytest.raises(ShapeFileError, match="bound of 149"):
        read_mesh(glb)
    monkeypatch.setattr(limits, "MAX_FACES", 150)
    assert len(read_mesh(glb).faces) == 150
    monkeypatch.setenv("PRIMKIT_MAX_GRID", "7")
    with pytest.raises(ShapeFileError, match=r"a 8\^3 voxel grid exceeds the bound of 7\^3"):
        read_voxels(binvox)
    monkeypatch.setenv("PRIMKIT_MAX_GRID", "8")
    assert read_voxels(binvox).resolution == 8
    monkeypatch.setenv("PRIMKIT_MAX_GRID", "lots")
    with pytest.raises(ValueError, match="PRIMKIT_MAX_GRID must be a positive integer"):
        read_voxels(binvox)


# ------------------------------------------------------------------------------ paths in errors


def test_reader_io_errors_name_the_path(tmp_path, monkeypatch):
    long_name = tmp_path / ("x" * 300 + ".off")  # stat fails with ENAMETOOLONG
    with pytest.raises(ShapeFileError) as info:
        read_mesh(long_name)
    assert str(info.value).startswith(f"{long_name}: cannot read") and "\n" not in str(info.value)

    path = tmp_path / "m.off"
    path.write_text(VARIANTS["plain"])

    def fail(self):
        raise OSError(errno.EIO, "Input/output error")

    monkeypatch.setattr(Path, "read_bytes", fail)
    for reader in (read_mesh, io.read_shape):
        with pytest.raises(ShapeFileError, match="cannot read: Input/output error") as info:
            reader(path)
        assert info.value.path == path


def test_a_full_disk_names_the_output(tmp_path):
    target = tmp_path / "out.seg"
    with pytest.raises(OSError) as info:
        with io.atomic_output(target) as temporary:
            temporary.write_text("1\n")
            raise OSError(errno.ENOSPC, "No space left on device")
    assert info.value.errno == errno.ENOSPC and info.value.filename == str(target)
    assert str(target) in str(info.value)
    assert not target.exists() and list(tmp_path.iterdir()) == []
