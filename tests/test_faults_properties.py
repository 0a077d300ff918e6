"""Property tests (issue 36): random dtypes, shapes, NaN/inf/huge values and face indices given to
``primkit.abstract``, ``primkit.segment`` and ``primkit.read_shape`` give either a result or one
ValueError/TypeError line naming the input and the problem, never a crash or a hang.

Each example runs in a child process (``tests/_sandbox.py``), so an interpreter killed by a
compiled kernel reading past an array fails the example (and hypothesis shrinks it) instead of
killing pytest. The example counts are small: each call abstracts a shape with the chair model.
"""

import itertools

import numpy as np
import pytest

hypothesis = pytest.importorskip("hypothesis", reason="hypothesis is in the dev extra")
from hypothesis import HealthCheck, given, settings, strategies as st  # noqa: E402
from hypothesis.extra import numpy as hnp  # noqa: E402

from _sandbox import Sandbox  # noqa: E402

SETTINGS = dict(deadline=None, suppress_health_check=list(HealthCheck), derandomize=True)

values = st.one_of(st.floats(-1.0, 1.0), st.sampled_from([np.nan, np.inf, -np.inf, 1e305, -1e160, 0.0, 1e-200]))
dtypes = st.sampled_from(["float64", "float32", "int64", "int32", "uint8", "bool", "complex128"])


@st.composite
def coordinates(draw):
    """(n, k) coordinates, mostly (n, 3), of a random dtype."""
    n = draw(st.integers(0, 12))
    k = draw(st.sampled_from([3, 3, 3, 3, 2, 4]))
    a = draw(hnp.arrays(np.float64, (n, k), elements=values))
    dtype = draw(st.sampled_from(["float64"] * 4 + ["float32", "int64", "bool", "complex128"]))
    with np.errstate(all="ignore"):
        return a.astype(dtype)


@st.composite
def meshes(draw):
    """(vertices, faces) with face indices anywhere in -12..19 (mostly in range)."""
    v = draw(coordinates())
    m = draw(st.integers(0, 10))
    k = draw(st.sampled_from([3, 3, 3, 3, 4]))
    n = max(len(v), 1)
    lo, hi = draw(st.sampled_from([(0, n - 1), (0, n - 1), (-12, 19), (n, n + 5)]))
    f = draw(hnp.arrays(np.int64, (m, k), elements=st.integers(lo, hi)))
    dtype = draw(st.sampled_from(["int64"] * 4 + ["int32", "uint8", "float64"]))
    return v, f.astype(dtype)


@st.composite
def grids(draw):
    r = draw(st.integers(1, 6))
    fill = draw(hnp.arrays(np.float64, (r, r, r), elements=st.sampled_from([0.0, 1.0, 0.5, np.nan])))
    with np.errstate(all="ignore"):
        return fill.astype(draw(st.sampled_from(["bool", "bool", "float64", "int64"])))


shapes = st.one_of(meshes(), coordinates(), grids())


@pytest.fixture(scope="module")
def sandbox():
    box = Sandbox(timeout=90)
    yield box
    box.close()


def check(answer, name: str, what: str):
    assert answer[0] != "died", f"{what}: the interpreter died or hung ({answer[1]})"
    if answer[0] == "raised":
        kind, is_value_or_type, message = answer[1:]
        assert is_value_or_type, f"{what}: {kind}: {message}"
        assert message and "\n" not in message, f"{what}: {kind}: {message!r}"
        assert name in message, f"{what}: the message does not name the input: {message}"


@pytest.mark.integration  # hypothesis examples, each in a child process: seconds, left to the default suite
@settings(max_examples=12, **SETTINGS)
@given(shape=shapes)
def test_abstract_gives_a_result_or_one_line(sandbox, shape):
    check(sandbox.call("primkit.abstract", shape, model="chair"), "shape0", "abstract")


@settings(max_examples=6, **SETTINGS)
@given(shape=meshes())
def test_segment_gives_a_result_or_one_line(sandbox, shape):
    check(sandbox.call("primkit.segment", shape, model="chair"), "shape0", "segment")


_counter = itertools.count()


def _text(rows, fmt) -> str:
    return "\n".join(fmt(r) for r in rows)


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    return tmp_path_factory.mktemp("written")


@settings(max_examples=40, **SETTINGS)
@given(mesh=meshes(), suffix=st.sampled_from([".off", ".obj", ".xyz", ".ply"]))
def test_read_shape_on_written_files_gives_a_shape_or_one_line(sandbox, folder, mesh, suffix):
    v, f = mesh
    num = lambda x: repr(x.item() if hasattr(x, "item") else x)  # noqa: E731
    vs = _text(v, lambda r: " ".join(num(x) for x in r))
    fs = _text(f, lambda r: f"{len(r)} " + " ".join(num(x) for x in r))
    if suffix == ".off":
        body = f"OFF\n{len(v)} {len(f)} 0\n{vs}\n{fs}"
    elif suffix == ".obj":
        body = _text(v, lambda r: "v " + " ".join(num(x) for x in r)) + "\n" + \
            _text(f, lambda r: "f " + " ".join(num(x + 1) for x in r))
    elif suffix == ".ply":
        body = (f"ply\nformat ascii 1.0\nelement vertex {len(v)}\nproperty float x\nproperty float y\n"
                f"property float z\nelement face {len(f)}\nproperty list uchar int vertex_indices\nend_header\n"
                f"{vs}\n{fs}")
    else:
        body = vs
    path = folder / f"s{next(_counter)}{suffix}"
    path.write_text(body + "\n")
    check(sandbox.call("primkit.read_shape", str(path)), path.name, f"read_shape({path.name})")
