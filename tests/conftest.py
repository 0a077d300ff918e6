import os
from pathlib import Path

import pytest

SHARED = Path(__file__).resolve().parents[2] / "shared" / "data"

# pictures are rendered off screen through EGL; never try an X server in tests
os.environ.setdefault("VTK_DEFAULT_OPENGL_WINDOW", "vtkEGLRenderWindow")

# under pytest-xdist (`-n 2`, docs/testing.md) each worker computes on one thread, set before torch,
# NumPy's BLAS or OpenMP start: two workers of two threads each on two cores slow torch twentyfold
if os.environ.get("PYTEST_XDIST_WORKER"):
    for _var in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS", "NUMBA_NUM_THREADS"):
        os.environ.setdefault(_var, "1")


@pytest.fixture(scope="session")
def shared_data():
    if not SHARED.is_dir():
        pytest.skip(f"shared data not found at {SHARED} (real-data checks need ../shared/data beside the checkout)")
    return SHARED


@pytest.fixture(scope="session")
def wheel_env(tmp_path_factory):
    """A fresh virtual environment holding the wheel of this checkout (:mod:`wheel_env`), built once
    for every test that uses primkit as a user installs it; its folder (``env/bin/python``)."""
    from wheel_env import fresh_environment

    return fresh_environment(tmp_path_factory.mktemp("wheel"))


@pytest.fixture(scope="session")
def chairs():
    from primkit import synthetic

    return synthetic.generate("chair", 8, seed=0)


@pytest.fixture(scope="session")
def prepared_chairs(chairs):
    from primkit import data, io

    return [data.prepare(io.Mesh(s.vertices, s.faces), face_labels=s.face_labels, name=f"chair{i}") for i, s in enumerate(chairs)]


def pytest_collection_modifyitems(config, items):
    """A ``slow`` test is also ``integration``, so the fast loop ``-m "not integration"`` (which
    replaces the default ``-m "not slow"``) leaves the slow ones out too."""
    for item in items:
        if item.get_closest_marker("slow") is not None and item.get_closest_marker("integration") is None:
            item.add_marker(pytest.mark.integration)
