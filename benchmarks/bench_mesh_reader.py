"""`primkit segment` over the shared COSEG chairs with each mesh reader: primkit's compiled OFF/OBJ
parser (``primkit.io._text_kernels``, the default), meshio, and trimesh (``engine="trimesh"``), at
command level (a fresh ``primkit segment`` process per run, an empty cache each time) and for the
reading alone (every file read once in this process, after one warm-up read).

    python benchmarks/bench_mesh_reader.py [--runs 3] [--data ../shared/data]

meshio is not a dependency of primkit: the benchmark installs nothing and skips meshio without it
(``pip install meshio``). The runs of the three readers alternate, so a change of machine load
falls on all of them; medians are printed with the load average.
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from _common import load_line, table

FOLDERS = ("coseg_chairs/chairs_101-120/shapes", "coseg_chairs/large_chairs/shapes")

# run in the command's process: swap the compiled parser for another reader, then run the command
LAUNCH = """
import sys
import numpy as np
from primkit.io import formats
reader = sys.argv.pop(1)
if reader == "meshio":
    import meshio
    def parse(path, data):
        m = meshio.read(path)
        faces = m.cells_dict.get("triangle")
        if faces is None or len(faces) != sum(len(c.data) for c in m.cells):
            return None  # polygons or other cells: primkit's own path
        return np.asarray(m.points, np.float64), np.asarray(faces, np.int64)
    formats._parse_mesh_text = parse
elif reader == "trimesh":
    formats._parse_mesh_text = lambda path, data: None  # every file to trimesh's loader
from primkit.cli import main
sys.exit(main(sys.argv[1:]))
"""


def _meshio_available() -> bool:
    try:
        import meshio  # noqa: F401
    except ImportError:
        return False
    return True


def _read_times(files, reader: str) -> float:
    """Seconds to read every file once with ``reader`` (after one warm-up read)."""
    import numpy as np

    from primkit.io import formats, read_mesh

    if reader == "meshio":
        import meshio

        def read(f):
            m = meshio.read(f)
            return np.asarray(m.points, np.float64), np.asarray(m.cells_dict["triangle"], np.int64)
    else:
        def read(f):
            return read_mesh(f, engine="auto" if reader == "compiled" else "trimesh")
    read(files[0])
    start = time.perf_counter()
    for f in files:
        read(f)
    del formats
    return time.perf_counter() - start


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--data", default=str(Path(__file__).resolve().parents[2] / "shared" / "data"))
    args = ap.parse_args()
    folders = [Path(args.data) / f for f in FOLDERS]
    files = sorted(f for d in folders for f in d.glob("*.off"))
    if not files:
        sys.exit(f"no COSEG chairs under {args.data}")
    readers = ["compiled", "trimesh"] + (["meshio"] if _meshio_available() else [])

    # the same arrays from every reader
    import numpy as np

    from primkit.io import read_mesh

    if "meshio" in readers:
        import meshio

        for f in files:
            a, m = read_mesh(f), meshio.read(f)
            assert np.array_equal(a.vertices, m.points) and np.array_equal(a.faces, m.cells_dict["triangle"]), f

    reading = {r: statistics.median(_read_times(files, r) for _ in range(5)) for r in readers}
    times = {r: [] for r in readers}
    with tempfile.TemporaryDirectory() as tmp:
        for run in range(args.runs):
            for r in readers:
                out, cache = Path(tmp) / f"{r}{run}", Path(tmp) / f"cache-{r}{run}"
                start = time.perf_counter()
                done = subprocess.run([sys.executable, "-c", LAUNCH, r, "segment", *map(str, folders), "--model",
                                       "chair", "-o", str(out), "--cache", str(cache), "--workers", "1", "-q"],
                                      capture_output=True, text=True, env={**os.environ, "OMP_NUM_THREADS": "1"})
                times[r].append(time.perf_counter() - start)
                if done.returncode != 0:
                    sys.exit(done.stderr[-2000:])
            labels = {r: sorted((Path(tmp) / f"{r}{run}").glob("*.seg")) for r in readers}
            first = [p.read_bytes() for p in labels[readers[0]]]
            assert all([p.read_bytes() for p in labels[r]] == first for r in readers), "the readers' labels differ"
    rows = [[r, f"{1000 * reading[r]:.0f} ms", f"{statistics.median(times[r]):.2f} s",
             " ".join(f"{t:.1f}" for t in times[r])] for r in readers]
    table(f"primkit segment over {len(files)} COSEG chairs ({sum(len(read_mesh(f).faces) for f in files):,} faces), "
          "--workers 1, empty cache", ["reader", "reading the files", "segment (median)", "runs (s)"], rows,
          note=load_line() + ("" if "meshio" in readers else "\nmeshio not installed: pip install meshio"))


if __name__ == "__main__":
    main()
