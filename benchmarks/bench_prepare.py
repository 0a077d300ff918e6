"""Benchmark: preparing shapes (read, occupancy, distance grid, samples) and the alternatives.

    python benchmarks/bench_prepare.py [--quick] [--collection N] [--workers W] [--before REV]

What it measures, all in one run, on the same meshes:

1. Per-mesh time at 32^3 of ``primkit.io.read_mesh``, ``primkit.data.prepare`` and its parts
   (canonical frame, surface voxels, winding-number occupancy, distance grid, 10k surface
   samples); the same for ShapeNetVox32 binvox chairs (read + prepare, the voxel path).
2. Distance grids: primkit's (exact near the surface, far cells from their neighbours; and exact
   at every cell; and through Open3D's BVH) against libigl's AABB (``igl.point_mesh_squared_distance``,
   the exact reference), a brute-force NumPy loop over all triangles, and a Euclidean distance
   transform of a 256^3 voxelisation, with their errors. 2b: the whole ``prepare`` of every
   10k-20k-face mesh against libigl's distances alone. 2c (``--only path`` runs it alone): the
   whole preparation **from the path** (``primkit.data.prepare_file``: read the file and its labels,
   frame, occupancy, distance grid, samples) against libigl's distances alone on the already-loaded
   mesh, on every PSB and COSEG mesh, on a quiet machine and with one core kept busy by another
   process, in alternating rounds; prints each condition's median ratio and the load.
3. Occupancy: primkit's region-sampled winding numbers against libigl's at every cell; 3b: the
   surface cells, primkit's compiled triangle-box test against Open3D's voxeliser.
4. Peak memory (``ru_maxrss`` of a fresh spawned process per method) and throughput of
   ``primkit.data.prepare_collection`` over ShapeNetVox32 chairs, extrapolated to all 5,931.
6. ``--only training`` (about 15 minutes, not in the default run): does the faster preparation
   change training? ShapeNetVox32 chairs' voxel-boundary meshes go through the mesh path twice
   (today's defaults; every cell exact with libigl's winding numbers), the paper's network trains
   on each with three seeds, and the held-out chairs are scored against the exact preparation.

Inputs: the real meshes under ``<repo>/../shared/data`` when present (PSB segmentation benchmark,
COSEG chairs, ShapeNetVox32); otherwise procedural shapes from :mod:`primkit.synthetic` (and no
binvox sections). Times are wall-clock ``perf_counter``; per mesh the fastest of ``--repeats``
runs is kept (other processes on a small machine only ever add time), and the tables show the
median and the 90th percentile over meshes. Nothing here asserts a time: it prints and exits 0.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from _common import load_line, maxrss_kib, run_at_revision, run_isolated, table  # noqa: E402

RESOLUTION = 32
DATA = Path(__file__).resolve().parents[2] / "shared" / "data"
ALL_CHAIRS = 5931  # ShapeNetVox32 chairs in the shared split


# --------------------------------------------------------------------------------------------
# small helpers: tables, timing, fresh processes
# --------------------------------------------------------------------------------------------


def ms(seconds: float) -> str:
    return f"{1000.0 * seconds:.1f}"


def mib(kib: float) -> str:
    return f"{kib / 1024.0:.0f}"


def timed(fn, *args, **kwargs):
    """(result, seconds) of one call, primkit's kept mesh tree dropped first."""
    drop_kept_tree()
    t0 = time.perf_counter()
    out = fn(*args, **kwargs)
    return out, time.perf_counter() - t0


def drop_kept_tree() -> None:
    """Forget primkit's kept mesh tree: a repeat on the same mesh would otherwise skip its build
    (``prepare`` builds it once per mesh, for the occupancy, and the distances reuse it)."""
    try:
        from primkit.geometry import _mesh_kernels
    except ImportError:
        return
    _mesh_kernels._last_tree = (None, None)


def best_of(repeats: int, fn, *args, **kwargs):
    """(result of the last call, fastest time over ``repeats`` calls)."""
    best = np.inf
    out = None
    for _ in range(repeats):
        out, dt = timed(fn, *args, **kwargs)
        best = min(best, dt)
    return out, best


# --------------------------------------------------------------------------------------------
# inputs
# --------------------------------------------------------------------------------------------


def mesh_inputs(quick: bool) -> tuple[str, list[tuple[str, Path]]]:
    """(description, [(group, path)]) of the meshes to time."""
    psb = sorted(DATA.glob("psb_seg_benchmark/*/off/*.off"))
    coseg = sorted(DATA.glob("coseg_chairs/*/shapes/*.off"))
    if psb or coseg:
        if quick:
            psb, coseg = psb[::8], coseg[::4]
        items = [("psb", p) for p in psb] + [("coseg", p) for p in coseg]
        return f"real meshes from {DATA} ({len(psb)} PSB, {len(coseg)} COSEG chairs)", items
    from primkit import synthetic

    folder = Path(tempfile.mkdtemp(prefix="primkit-bench-meshes-"))
    count = 2 if quick else 10
    items = []
    for category in synthetic.CATEGORIES if hasattr(synthetic, "CATEGORIES") else ("chair", "table", "airplane", "animal"):
        for p in synthetic.write_collection(folder / category, category, count, seed=1):
            items.append((category, p))
    return f"procedural shapes (primkit.synthetic, {len(items)}) written to {folder}", items


def binvox_inputs(count: int) -> list[Path]:
    folder = DATA / "shapenetvox32" / "03001627"
    if not folder.is_dir():
        return []
    return sorted(folder.glob("*/model.binvox"))[:count]


def warm_up() -> None:
    """Load every library once (Open3D, libigl, trimesh, scipy) on a small procedural chair."""
    from primkit import data, io, synthetic

    s = synthetic.chair(seed=0)
    data.prepare(io.Mesh(s.vertices, s.faces))
    with tempfile.TemporaryDirectory() as folder:  # and the compiled text reader
        data.prepare_file(io.write_mesh(Path(folder) / "chair.off", s.vertices, s.faces))


# --------------------------------------------------------------------------------------------
# 1. per-shape preparation
# --------------------------------------------------------------------------------------------

PARTS = ("frame", "surface_voxels", "occupancy_grid", "distance_grid", "sample_surface")


def prepare_parts(mesh, settings) -> dict:
    """Time the steps of ``primkit.data.prepare`` one by one, in its order, with its arguments (the
    occupancy builds the mesh's tree, the distances reuse it, as in ``prepare``)."""
    from primkit import geometry

    out = {}
    drop_kept_tree()
    t0 = time.perf_counter()
    frame = geometry.canonical_frame(mesh.vertices, settings.up, settings.front)
    v = frame.to_canonical(mesh.vertices)
    f = mesh.faces
    t1 = time.perf_counter()
    surface = geometry.surface_voxels(v, f, settings.resolution)
    t2 = time.perf_counter()
    geometry.occupancy_grid(v, f, settings.resolution, surface=surface)
    t3 = time.perf_counter()
    geometry.distance_grid(v, f, settings.resolution, surface=surface)
    t4 = time.perf_counter()
    geometry.sample_surface(v, f, settings.samples, seed=settings.seed)
    t5 = time.perf_counter()
    for name, dt in zip(PARTS, (t1 - t0, t2 - t1, t3 - t2, t4 - t3, t5 - t4)):
        out[name] = dt
    return out


def bench_meshes(items, repeats: int) -> list[dict]:
    from primkit import data, io

    settings = data.PrepareSettings(resolution=RESOLUTION)
    rows = []
    for group, path in items:
        mesh, t_read = best_of(repeats, io.read_mesh, path)
        _, t_prep = best_of(repeats, data.prepare, mesh, settings)
        parts = {k: np.inf for k in PARTS}
        for _ in range(repeats):
            for k, v in prepare_parts(mesh, settings).items():
                parts[k] = min(parts[k], v)
        rows.append({"group": group, "path": path, "faces": len(mesh.faces), "read": t_read, "prepare": t_prep, **parts})
    return rows


def summary_rows(label: str, records: list[dict], keys: list[str]) -> list[list]:
    if not records:
        return []
    faces = np.array([r["faces"] for r in records])
    row_med = [f"{label} median", len(records), f"{int(np.median(faces))}"]
    row_p90 = [f"{label} p90", "", f"{int(np.percentile(faces, 90))}"]
    for k in keys:
        vals = np.array([r[k] for r in records])
        row_med.append(ms(np.median(vals)))
        row_p90.append(ms(np.percentile(vals, 90)))
    return [row_med, row_p90]


def report_meshes(records: list[dict]) -> None:
    keys = ["read", "prepare", *PARTS]
    rows = []
    band = [r for r in records if 5000 <= r["faces"] <= 20000]
    rows += summary_rows("5k-20k faces", band, keys)
    rows += summary_rows("all meshes", records, keys)
    for group in sorted({r["group"] for r in records}):
        rows += summary_rows(group, [r for r in records if r["group"] == group], keys)
    table(
        f"1. per-mesh preparation at {RESOLUTION}^3 (ms; fastest of the repeats per mesh, then median / p90 over meshes)",
        ["meshes", "n", "faces", "read", "prepare", *PARTS],
        rows,
        "prepare = primkit.data.prepare (frame + surface voxels + occupancy + distance grid + 10k samples);\n"
        "the part columns time the same steps one by one. Target: median prepare for a ~10k-face mesh well under 100 ms.",
    )
    if band:
        med = float(np.median([r["prepare"] for r in band]))
        print(f"-> median prepare for 5k-20k-face meshes: {ms(med)} ms "
              f"(faces median {int(np.median([r['faces'] for r in band]))}); target < 100 ms: "
              f"{'met' if med < 0.1 else 'NOT met'}")


def _binvox_mesh_path(grid, settings):
    """The voxel path before the grid-only preparation: the same turn, recentring and cavity filling
    (``data.preparation._canonical_voxels``), then the voxel boundary mesh through the mesh machinery (Open3D
    BVH closest points with the float64 recompute, Open3D voxeliser, trimesh samples)."""
    from primkit import data, geometry

    occ, frame = data.preparation._canonical_voxels(grid, settings)
    v, f = geometry.voxel_boundary_mesh(occ)
    surface = geometry.surface_voxels(v, f, settings.resolution) & occ
    return data.preparation._from_surface(v, f, occ, surface, settings, frame, name="shape", source="", kind="voxels")


_AT_REVISION = """
import json, sys, time
from primkit import data, io
paths, repeats = json.loads(sys.argv[1]), int(sys.argv[2])
settings = data.PrepareSettings(resolution=32)
data.prepare(io.read_shape(paths[0]), settings)  # warm-up: imports
out = []
for p in paths:
    best = float("inf")
    for _ in range(repeats):
        t0 = time.perf_counter()
        data.prepare(io.read_shape(p), settings)
        best = min(best, time.perf_counter() - t0)
    out.append(best)
print(json.dumps(out))
"""


def time_at_revision(rev: str, paths, repeats: int) -> list | None:
    """Read + prepare times of ``paths`` with primkit as it was at git revision ``rev``."""
    out, why = run_at_revision(rev, _AT_REVISION, json.dumps([str(p) for p in paths]), str(repeats))
    if out is None:
        print(f"(--before {rev}: {why})")
    return out


def bench_binvox(paths, repeats: int, before: str | None = None) -> None:
    from primkit import data, geometry, io

    settings = data.PrepareSettings(resolution=RESOLUTION)
    reads, preps, olds, errs, fts_fast, fts_scipy = [], [], [], [], [], []
    for p in paths:
        grid, t_read = best_of(repeats, io.read_shape, p)
        fast, t_prep = best_of(repeats, data.prepare, grid, settings)
        old, t_old = best_of(repeats, _binvox_mesh_path, grid, settings)
        _, t_fast = best_of(repeats, geometry.voxel_closest_points, fast.solid)
        _, t_scipy = best_of(repeats, geometry.voxel_closest_points, fast.solid, "scipy")
        reads.append(t_read)
        preps.append(t_prep)
        olds.append(t_old)
        fts_fast.append(t_fast)
        fts_scipy.append(t_scipy)
        errs.append(float(np.abs(fast.distance - old.distance).max()))
    r, q, o = np.array(reads), np.array(preps), np.array(olds)
    a, b = np.array(fts_fast), np.array(fts_scipy)
    rows = [
        ["read (io.read_shape)", len(r), ms(np.median(r)), ms(np.percentile(r, 90)), ms(r.max())],
        ["prepare: from the grid (primkit)", len(q), ms(np.median(q)), ms(np.percentile(q, 90)), ms(q.max())],
        ["  its closest points: compiled transform at the centres", len(a), ms(np.median(a)), ms(np.percentile(a, 90)), ms(a.max())],
        ["  the same by SciPy's transform of the whole lattice", len(b), ms(np.median(b)), ms(np.percentile(b, 90)), ms(b.max())],
        ["prepare: through the boundary mesh", len(o), ms(np.median(o)), ms(np.percentile(o, 90)), ms(o.max())],
        ["read + prepare (primkit)", len(q), ms(np.median(r + q)), ms(np.percentile(r + q, 90)), ms((r + q).max())],
    ]
    note = ""
    if before:
        then = time_at_revision(before, paths, repeats)
        if then is not None:
            t = np.array(then)
            rows.append([f"read + prepare, primkit at {before}", len(t), ms(np.median(t)), ms(np.percentile(t, 90)), ms(t.max())])
            note = (f"\nmedian per-shape ratio, primkit at {before} / now (read + prepare): {np.median(t / (r + q)):.1f}x "
                    "(that revision run from a git archive in a fresh process, same files, same run).")
    table(
        f"1b. ShapeNetVox32 binvox chairs at {RESOLUTION}^3 (ms per shape)",
        ["step", "n", "median", "p90", "max"],
        rows,
        f"median per-shape ratio, boundary mesh / grid: {np.median(o / q):.1f}x; compiled / SciPy transform: {np.median(b / a):.1f}x;\n"
        f"largest distance difference between the grid and mesh paths {max(errs):.1e} (both exact; float32 storage).\n"
        "Grid path: rotate/recentre, fill cavities, exact closest points by a feature transform of the doubled lattice,\n"
        "samples on the voxel squares (primkit.geometry.voxels)." + note,
    )


# --------------------------------------------------------------------------------------------
# 2. distance grids: primkit and the alternatives
# --------------------------------------------------------------------------------------------


def _dot(x, y):
    return np.einsum("...i,...i->...", x, y)


def brute_force_distance_sq(points: np.ndarray, vertices: np.ndarray, faces: np.ndarray, chunk: int = 16) -> np.ndarray:
    """Squared distance of each point to the mesh by testing every triangle (chunks of points).

    Per point and triangle: if the point projects inside the triangle, the squared distance to
    its plane; otherwise the smallest squared distance to the three edges (as segments).
    Degenerate triangles have no inside and fall back to their edges.

    points : (n, 3) float; returns (n,) float.
    """
    a, b, c = (vertices[faces[:, i]][None] for i in range(3))  # (1, f, 3)
    normal = np.cross(b - a, c - a)
    nn = _dot(normal, normal)
    edges = [(a, b - a), (b, c - b), (c, a - c)]
    edge_len = [_dot(d, d) for _, d in edges]
    out = np.empty(len(points))
    for start in range(0, len(points), chunk):
        p = points[start : start + chunk, None, :]  # (k, 1, 3)
        with np.errstate(divide="ignore", invalid="ignore"):
            h = _dot(p - a, normal)
            plane = h * h / nn
            inside = nn > 0
            for (s0, d) in edges:
                inside = inside & (_dot(np.cross(d, p - s0), normal) >= 0)
            best = None
            for (s0, d), dd in zip(edges, edge_len):
                u = np.clip(_dot(p - s0, d) / dd, 0.0, 1.0)
                u = np.where(dd > 0, u, 0.0)
                r = p - s0 - u[..., None] * d
                e = _dot(r, r)
                best = e if best is None else np.minimum(best, e)
        out[start : start + chunk] = np.where(inside, plane, best).min(axis=1)
    return out


def edt_distance(vertices: np.ndarray, faces: np.ndarray, fine: int = 256, samples: int = 2_000_000) -> np.ndarray:
    """Distance at the canonical cell centres from an exact EDT of a ``fine``^3 voxelisation.

    Surface voxels come from ``samples`` area-uniform surface samples; the EDT gives, at every fine
    voxel centre, the distance to the nearest surface voxel centre, and the 32^3 cell centres
    (which fall between fine voxel centres) read it by trilinear interpolation.

    Returns (R, R, R) float.
    """
    from scipy import ndimage

    from primkit import geometry

    pts = geometry.sample_surface(vertices, faces, samples, seed=0).points
    idx = np.clip(np.floor((pts + 0.5) * fine).astype(np.int64), 0, fine - 1)
    surface = np.zeros((fine,) * 3, bool)
    surface[idx[:, 0], idx[:, 1], idx[:, 2]] = True
    dist = ndimage.distance_transform_edt(~surface, sampling=1.0 / fine)
    centres = geometry.grid_centres(RESOLUTION).reshape(-1, 3)
    coords = ((centres + 0.5) * fine - 0.5).T
    return ndimage.map_coordinates(dist, coords, order=1, mode="nearest").reshape((RESOLUTION,) * 3)


def canonical_mesh(path):
    from primkit import geometry, io

    mesh = io.read_mesh(path)
    frame = geometry.canonical_frame(mesh.vertices)
    return frame.to_canonical(mesh.vertices), mesh.faces


def bench_distances(paths, bf_cells: int, repeats: int) -> None:
    import igl

    from primkit import geometry

    centres = geometry.grid_centres(RESOLUTION).reshape(-1, 3)
    sel = np.sort(np.random.default_rng(0).choice(len(centres), bf_cells, replace=False))
    from primkit import data, io

    keys = ("primkit", "exact", "open3d", "igl", "prepare", "brute", "edt")
    res = {k: {"t": [], "max": [], "mean": []} for k in keys}
    faces_seen = []
    for path in paths:
        v, f = canonical_mesh(path)
        faces_seen.append(len(f))
        (ref_sq, _, _), t_igl = best_of(repeats, igl.point_mesh_squared_distance, centres, v, f)
        ref = np.sqrt(ref_sq)
        surface = geometry.surface_voxels(v, f, RESOLUTION)  # prepare has it: given, as prepare does
        grid, t_pk = best_of(repeats, geometry.distance_grid, v, f, RESOLUTION, surface=surface)
        exact, t_ex = best_of(repeats, geometry.distance_grid, v, f, RESOLUTION, exact_within=None)
        old, t_o3d = best_of(repeats, geometry.distance_grid, v, f, RESOLUTION, engine="open3d")
        mesh = io.read_mesh(path)
        _, t_prep = best_of(repeats, data.prepare, mesh)
        bf_sq, t_bf = timed(brute_force_distance_sq, centres[sel], v, f)
        edt, t_edt = timed(edt_distance, v, f)
        for key, t, err in (
            ("igl", t_igl, np.zeros(1)),
            ("primkit", t_pk, grid.distance.ravel().astype(np.float64) - ref),
            ("exact", t_ex, exact.distance.ravel().astype(np.float64) - ref),
            ("open3d", t_o3d, old.distance.ravel().astype(np.float64) - ref),
            ("prepare", t_prep, grid.distance.ravel().astype(np.float64) - ref),
            ("brute", t_bf * len(centres) / bf_cells, np.sqrt(bf_sq) - ref[sel]),
            ("edt", t_edt, edt.ravel() - ref),
        ):
            res[key]["t"].append(t)
            res[key]["max"].append(np.abs(err).max())
            res[key]["mean"].append(np.abs(err).mean())
            if key == "primkit":
                res[key].setdefault("min", []).append(err.min())
    names = {
        "primkit": "primkit.geometry.distance_grid (exact within 2 cells, far cells from neighbours)",
        "exact": "  the same, exact_within=None (every cell searched exactly)",
        "open3d": "  the same, engine='open3d' (Open3D BVH + float64, every cell)",
        "igl": "igl.point_mesh_squared_distance (AABB; reference)",
        "prepare": "primkit.data.prepare, whole (read excluded)",
        "brute": f"brute force NumPy, all triangles (extrapolated from {bf_cells} cells)",
        "edt": "scipy EDT of 256^3 voxels from 2M samples, interpolated",
    }
    rows = []
    for key in keys:
        r = res[key]
        rows.append([names[key], ms(np.median(r["t"])), ms(np.max(r["t"])), f"{np.max(r['max']):.1e}", f"{np.mean(r['mean']):.1e}"])
    ratio = {k: np.median(np.divide(res[k]["t"], res["igl"]["t"])) for k in ("primkit", "exact", "open3d", "prepare")}
    table(
        f"2. distance grid at {RESOLUTION}^3 on {len(paths)} meshes ({min(faces_seen)}-{max(faces_seen)} faces)",
        ["method", "median ms", "max ms", "max |err|", "mean |err|"],
        rows,
        "errors: distance at the cell centres against libigl's exact distances, in units of the unit cube\n"
        "(a cell is 1/32 = 3.1e-2); primkit stores float32. primkit's far cells are never nearer than libigl's\n"
        f"(smallest difference {min(res['primkit']['min']):.1e}). Median per-mesh ratios to libigl's time: distance grid "
        f"{ratio['primkit']:.2f}\n(exact {ratio['exact']:.2f}, engine='open3d' {ratio['open3d']:.2f}); whole preparation "
        f"{ratio['prepare']:.2f}.",
    )


def path_inputs() -> list[tuple[str, Path]]:
    """(group, path) of the Princeton (PSB) and COSEG meshes of the shared data."""
    psb = sorted(DATA.glob("psb_seg_benchmark/*/off/*.off"))
    coseg = sorted(DATA.glob("coseg_*/**/shapes/*.off"))
    return [("psb", p) for p in psb] + [("coseg", p) for p in coseg]


def _busy_core():
    """Another process spinning on one core until it is terminated (the 'one core busy' condition)."""
    import subprocess

    return subprocess.Popen([sys.executable, "-c", "while True: pass"])


def bench_from_path(items, repeats: int, rounds: int) -> dict:
    """The issue's ratio from the path: ``prepare_file(path)`` against ``igl.point_mesh_squared_distance``
    of the 32^3 cell centres to the already-loaded mesh (canonical frame), per mesh the fastest of
    ``repeats`` calls each (alternating), in ``rounds`` rounds that alternate quiet and one core
    busy. Returns {condition: {group: [ratio per mesh]}}."""
    import igl

    from primkit import data, geometry, io

    centres = geometry.grid_centres(RESOLUTION).reshape(-1, 3)
    loaded = {}
    for _, path in items:  # the reference's input, loaded once (not timed)
        mesh = io.read_mesh(path)
        loaded[path] = (geometry.canonical_frame(mesh.vertices).to_canonical(mesh.vertices), mesh.faces)
    best = {c: {path: [np.inf, np.inf] for _, path in items} for c in ("quiet", "busy")}
    reads = {path: [np.inf, np.inf] for _, path in items}  # quiet: read_mesh, and with engine="trimesh"
    loads = {"quiet": [], "busy": []}
    conditions = [("quiet", "busy")[r % 2] for r in range(2 * rounds)]
    for condition in conditions:
        busy = _busy_core() if condition == "busy" else None
        try:
            if busy is not None:
                time.sleep(0.5)  # let it start spinning
            loads[condition].append(os.getloadavg()[0])
            for _, path in items:
                v, f = loaded[path]
                for _ in range(repeats):
                    _, t_igl = timed(igl.point_mesh_squared_distance, centres, v, f)
                    _, t_prep = timed(data.prepare_file, path)
                    b = best[condition][path]
                    b[0], b[1] = min(b[0], t_igl), min(b[1], t_prep)
                    if condition == "quiet":
                        _, t_new = timed(io.read_mesh, path)
                        _, t_old = timed(io.read_mesh, path, engine="trimesh")
                        r = reads[path]
                        r[0], r[1] = min(r[0], t_new), min(r[1], t_old)
            loads[condition].append(os.getloadavg()[0])
        finally:
            if busy is not None:
                busy.terminate()
                busy.wait()
    ratios = {c: {} for c in best}
    rows = []
    for group, path in items:
        row = [f"{path.parent.parent.name}/{path.name}", len(loaded[path][1])]
        for c in ("quiet", "busy"):
            t_igl, t_prep = best[c][path]
            ratios[c].setdefault(group, []).append(t_prep / t_igl)
            row += [ms(t_igl), ms(t_prep), f"{t_prep / t_igl:.2f}"]
        rows.append(row)
    summary = []
    for group in sorted({g for g, _ in items}, reverse=True):
        line = f"{group} ({len(ratios['quiet'][group])} meshes): "
        line += "; ".join(
            f"{c} median ratio {np.median(ratios[c][group]):.2f} (range {min(ratios[c][group]):.2f}-"
            f"{max(ratios[c][group]):.2f})" for c in ("quiet", "busy"))
        summary.append(line)
        igl_quiet = [best["quiet"][p][0] for g, p in items if g == group]
        new, old = ([reads[p][k] for g, p in items if g == group] for k in (0, 1))
        summary.append(f"  reading alone (quiet), median ratio to libigl's step: read_mesh {np.median(np.divide(new, igl_quiet)):.3f}, "
                       f"engine='trimesh' (the reader before issue 37) {np.median(np.divide(old, igl_quiet)):.3f}; "
                       f"median read {ms(np.median(new))} against {ms(np.median(old))} ms")
    table(
        f"2c. whole preparation from the path (prepare_file) against libigl's distances alone, quiet and one core busy",
        ["mesh", "faces", "quiet igl ms", "prepare_file ms", "ratio", "busy igl ms", "prepare_file ms", "ratio"],
        rows,
        "\n".join(summary) + "\n"
        f"per mesh the fastest of {repeats} alternating calls in each of {rounds} rounds per condition (rounds alternate "
        "quiet / busy);\n'busy' = another process spinning on one core. 1-min load average at the start and end of "
        "each round: quiet " + ", ".join(f"{x:.2f}" for x in loads["quiet"]) + "; busy "
        + ", ".join(f"{x:.2f}" for x in loads["busy"]) + f" ({os.cpu_count()} cores).",
    )
    return ratios


def bench_whole_preparation(paths, repeats: int) -> None:
    """The issue's ratio: the whole ``prepare`` of each 10k-20k-face mesh against libigl's exact
    distances alone at the same cell centres, and the largest far-cell error of its grid."""
    import igl

    from primkit import data, geometry, io

    centres = geometry.grid_centres(RESOLUTION).reshape(-1, 3)
    rows, ratios, errors = [], [], []
    for path in paths:
        mesh = io.read_mesh(path)
        v = geometry.canonical_frame(mesh.vertices).to_canonical(mesh.vertices)
        (ref_sq, _, _), t_igl = best_of(repeats, igl.point_mesh_squared_distance, centres, v, mesh.faces)
        prepared, t_prep = best_of(repeats, data.prepare, mesh)
        err = np.linalg.norm(prepared.closest.reshape(-1, 3).astype(np.float64) - centres, axis=1) - np.sqrt(ref_sq)
        ratios.append(t_prep / t_igl)
        errors.append(err.max())
        rows.append([f"{path.parent.parent.name}/{path.name}", len(mesh.faces), ms(t_igl), ms(t_prep),
                     f"{t_prep / t_igl:.2f}", f"{err.max():.1e}"])
    if not rows:
        return
    table(
        f"2b. whole preparation of the {len(rows)} meshes of 10k-20k faces against libigl's distances alone",
        ["mesh", "faces", "igl ms", "prepare ms", "ratio", "max distance error"],
        rows,
        f"median ratio {np.median(ratios):.2f} (range {min(ratios):.2f}-{max(ratios):.2f}); the largest distance "
        f"error {max(errors):.1e} (median of the meshes' largest {np.median(errors):.1e}).",
    )


# --------------------------------------------------------------------------------------------
# 3. occupancy: region-sampled winding number vs every cell
# --------------------------------------------------------------------------------------------


def bench_occupancy(paths, repeats: int) -> None:
    from primkit import geometry

    t_pk, t_igl, t_surf, t_o3d, diffs, surf_diffs, faces_seen = [], [], [], [], [], [], []
    for path in paths:
        v, f = canonical_mesh(path)
        faces_seen.append(len(f))
        surface, ts = best_of(repeats, geometry.surface_voxels, v, f, RESOLUTION)
        surface_o3d, to = best_of(repeats, geometry.surface_voxels, v, f, RESOLUTION, engine="open3d")
        t_o3d.append(to)
        surf_diffs.append(int((surface != surface_o3d).sum()))
        occ, tp = best_of(repeats, geometry.occupancy_grid, v, f, RESOLUTION, surface=surface)
        full, ti = best_of(repeats, geometry.occupancy_grid, v, f, RESOLUTION, engine="igl")
        t_pk.append(tp)
        t_igl.append(ti)
        t_surf.append(ts)
        diffs.append(int((full != occ).sum()))
    diffs = np.array(diffs)
    table(
        f"3. solid occupancy at {RESOLUTION}^3 on {len(paths)} meshes ({min(faces_seen)}-{max(faces_seen)} faces)",
        ["method", "median ms", "p90 ms", "cells differing (total)", "meshes differing"],
        [
            ["primkit occupancy_grid (its winding numbers, surface cells + a few per region; builds the tree)",
             ms(np.median(t_pk)), ms(np.percentile(t_pk, 90)), int(diffs.sum()), int((diffs > 0).sum())],
            ["  + its surface_voxels input", ms(np.median(np.add(t_pk, t_surf))), ms(np.percentile(np.add(t_pk, t_surf), 90)), "", ""],
            ["occupancy_grid(engine='igl'): igl.fast_winding_number at all 32768 cells", ms(np.median(t_igl)),
             ms(np.percentile(t_igl, 90)), "reference", ""],
        ],
        f"agreement: {100.0 * (1 - diffs.sum() / (len(paths) * RESOLUTION**3)):.4f}% of all cells; median per-mesh "
        f"time ratio {np.median(np.divide(t_pk, t_igl)):.2f}",
    )
    surf_diffs = np.array(surf_diffs)
    table(
        f"3b. surface cells (the cells a triangle meets) at {RESOLUTION}^3 on the same {len(paths)} meshes",
        ["method", "median ms", "p90 ms", "cells differing (total)", "meshes differing"],
        [
            ["primkit surface_voxels (compiled triangle-box test)", ms(np.median(t_surf)), ms(np.percentile(t_surf, 90)),
             int(surf_diffs.sum()), int((surf_diffs > 0).sum())],
            ["surface_voxels(engine='open3d'): VoxelGrid.create_from_triangle_mesh_within_bounds", ms(np.median(t_o3d)),
             ms(np.percentile(t_o3d, 90)), "reference", ""],
        ],
        f"median per-mesh time ratio {np.median(np.divide(t_surf, t_o3d)):.2f}",
    )


# --------------------------------------------------------------------------------------------
# 4. peak memory (fresh process per method) and collections
# --------------------------------------------------------------------------------------------


def _mem_job(method: str, path: str, bf_cells: int) -> dict:
    """Runs in a fresh process: warm up (imports + one small shape), then one method on one mesh."""
    import igl

    from primkit import data, geometry, io

    warm_up()
    base = maxrss_kib()
    mesh = io.read_mesh(path)
    frame = geometry.canonical_frame(mesh.vertices)
    v, f = frame.to_canonical(mesh.vertices), mesh.faces
    centres = geometry.grid_centres(RESOLUTION).reshape(-1, 3)
    t0 = time.perf_counter()
    if method == "prepare":
        data.prepare(mesh)
    elif method == "distance_grid":
        geometry.distance_grid(v, f, RESOLUTION)
    elif method == "igl":
        igl.point_mesh_squared_distance(centres, v, f)
    elif method == "brute":
        brute_force_distance_sq(centres[:bf_cells], v, f)
    elif method == "edt":
        edt_distance(v, f)
    elif method == "occupancy_grid":
        geometry.occupancy_grid(v, f, RESOLUTION)
    elif method == "fwn_all":
        igl.fast_winding_number(v, f, centres)
    else:
        raise ValueError(method)
    return {"base": base, "peak": maxrss_kib(), "seconds": time.perf_counter() - t0}


def bench_memory(path: Path, faces: int, bf_cells: int) -> None:
    methods = [
        ("prepare", "primkit.data.prepare (whole)"),
        ("distance_grid", "primkit distance_grid"),
        ("igl", "igl.point_mesh_squared_distance"),
        ("brute", f"brute force NumPy ({bf_cells} cells, 16 a chunk)"),
        ("edt", "scipy EDT 256^3"),
        ("occupancy_grid", "primkit occupancy_grid (incl. surface voxels)"),
        ("fwn_all", "igl.fast_winding_number, all cells"),
    ]
    rows = []
    for key, label in methods:
        r = run_isolated(_mem_job, key, str(path), bf_cells)
        rows.append([label, mib(r["base"]), mib(r["peak"]), mib(r["peak"] - r["base"]), ms(r["seconds"])])
    table(
        f"4. peak memory of one mesh ({path.parent.parent.name}/{path.name}, {faces} faces), fresh spawned process per method",
        ["method", "RSS after imports+warm-up MiB", "peak RSS MiB", "increase MiB", "ms (cold)"],
        rows,
        "RSS is the peak resident set size of the process (VmHWM; native allocations included); the warm-up prepares one small\n"
        "procedural chair so that every library is loaded before the baseline is read.",
    )


def _collection_job(files: list[str], workers: int) -> dict:
    """Runs in a fresh process: prepare_collection into an empty temporary cache, then again (cached)."""
    from primkit import data

    base = maxrss_kib()
    with tempfile.TemporaryDirectory(prefix="primkit-bench-cache-") as cache:
        coll, t_cold = timed(data.prepare_collection, files, cache_dir=cache, workers=workers, progress=False)
        parent_peak = maxrss_kib()
        child_peak = maxrss_kib(children=True)
        _, t_warm = timed(data.prepare_collection, files, cache_dir=cache, workers=workers, progress=False)
        size = sum(p.stat().st_size for p in Path(cache).rglob("*") if p.is_file())  # segments (.npy) and their index
    return {
        "ok": len(coll), "errors": coll.errors[:3], "n_errors": len(coll.errors), "cold": t_cold, "warm": t_warm,
        "base": base, "parent_peak": parent_peak, "child_peak": child_peak, "bytes": size,
    }


def bench_collection(files: list[Path], workers_list: list[int]) -> None:
    n = len(files)
    results = {w: run_isolated(_collection_job, [str(p) for p in files], w) for w in workers_list}
    rows = []

    def row(label, fn):
        rows.append([label, *(fn(w, results[w]) for w in workers_list)])

    row("shapes (prepared / errors)", lambda w, r: f"{r['ok']} / {r['n_errors']}")
    row("wall time, empty cache", lambda w, r: f"{r['cold']:.1f} s")
    row("shapes per second", lambda w, r: f"{n / r['cold']:.1f}")
    row(f"extrapolated, all {ALL_CHAIRS} chairs", lambda w, r: f"{ALL_CHAIRS * r['cold'] / n / 60:.1f} min")
    row("wall time again, all cached", lambda w, r: f"{r['warm']:.2f} s ({1000 * r['warm'] / n:.1f} ms/shape)")
    row("RSS after imports, main process", lambda w, r: f"{mib(r['base'])} MiB")
    row("peak RSS, main process", lambda w, r: f"{mib(r['parent_peak'])} MiB")
    row("peak RSS, largest worker", lambda w, r: f"{mib(r['child_peak'])} MiB" if w > 1 else "-")
    row("main + workers x largest (upper bound)", lambda w, r: f"{mib(r['parent_peak'] + (w if w > 1 else 0) * r['child_peak'])} MiB")
    row(
        f"cache on disk (extrapolated to {ALL_CHAIRS})",
        lambda w, r: f"{r['bytes'] / max(r['ok'], 1) / 1024:.0f} KiB/shape; {r['bytes'] / max(r['ok'], 1) * ALL_CHAIRS / 2**30:.2f} GiB",
    )
    errors = [e for r in results.values() for e in r["errors"]]
    table(
        f"5. prepare_collection on {n} ShapeNetVox32 chairs, fresh process per run, empty temporary cache",
        ["quantity", *(f"workers={w}" for w in workers_list)],
        rows,
        "workers=1 prepares in the main process; worker peaks include pages shared with the main process\n"
        "(workers are forked), so the sum over-counts. Worker processes import Open3D/libigl on first use."
        + (f"\nerrors: {errors}" if errors else ""),
    )


# --------------------------------------------------------------------------------------------
# 6. training on the two preparations
# --------------------------------------------------------------------------------------------


def _exact_preparation(mesh, name):
    """``prepare`` with every distance cell searched exactly and libigl's winding number at every cell."""
    from primkit import data, geometry

    distance_grid, occupancy_grid = geometry.distance_grid, geometry.occupancy_grid
    geometry.distance_grid = lambda *a, **k: distance_grid(*a, **{**k, "exact_within": None})
    geometry.occupancy_grid = lambda *a, **k: occupancy_grid(*a, **{**k, "engine": "igl"})
    try:
        return data.prepare(mesh, name=name)
    finally:
        geometry.distance_grid, geometry.occupancy_grid = distance_grid, occupancy_grid


def bench_training(count: int, stage1: int, stage2: int, seeds=(0, 1, 2)) -> None:
    """Section 6: the same chairs prepared both ways, trained on with each seed, scored on held-out
    chairs (every 6th) against the exact preparation; differences in units of the seeds' spread."""
    import torch

    from primkit import data, geometry, io, metrics
    from primkit.model.abstractor import Abstractor
    from primkit.model.training import ShapeTensors, TrainConfig, train

    paths = binvox_inputs(count)
    if not paths:
        print("\n(no ShapeNetVox32 folder: section 6 skipped)")
        return
    fast, exact, errors, solid = [], [], [], 0
    centres = geometry.grid_centres(RESOLUTION)
    for path in paths:
        grid = io.read_voxels(path)
        mesh = io.Mesh(*geometry.voxel_boundary_mesh(np.asarray(grid.occupancy, bool)))
        a, b = data.prepare(mesh, name=path.parent.name), _exact_preparation(mesh, path.parent.name)
        assert np.array_equal(a.occupancy, b.occupancy) and np.array_equal(a.points, b.points)
        errors.append(float((np.linalg.norm(a.closest - centres, axis=-1) - np.linalg.norm(b.closest - centres, axis=-1)).max()))
        solid += int((a.solid != b.solid).sum())
        fast.append(a)
        exact.append(b)
    print(f"  prepared {len(paths)} chairs both ways", flush=True)
    held = list(range(5, len(paths), 6))
    kept = [i for i in range(len(paths)) if i not in held]
    threads = torch.get_num_threads()
    results = {}
    with tempfile.TemporaryDirectory() as tmp:
        for seed in seeds:
            for variant, shapes in (("exact", exact), ("fast", fast)):
                config = TrainConfig(stage1_iterations=stage1, stage2_iterations=stage2, checkpoint_every=10**9,
                                     log_every=10, seed=seed)
                model = Path(tmp) / f"{variant}-{seed}.safetensors"
                result = train(ShapeTensors([shapes[i] for i in kept]), model, config, device="cpu", progress=False)
                predictions = Abstractor.load(model).predict([exact[i] for i in held])
                scores = [metrics.score(p.cuboids, exact[i]) for p, i in zip(predictions, held)]
                last = result.history[-10:]
                row = {f"train {k}": float(np.mean([e[k] for e in last])) for k in ("coverage", "consistency")}
                row.update({f"held-out {k}": float(np.mean([getattr(x, k) for x in scores]))
                            for k in ("chamfer", "iou", "coverage", "consistency", "parts")})
                results[(variant, seed)] = row
                print(f"  {variant} seed {seed}: " + ", ".join(f"{k} {v:.5f}" for k, v in row.items()), flush=True)
    rows = []
    for key in results[("exact", seeds[0])]:
        e = np.array([results[("exact", s)][key] for s in seeds])
        f = np.array([results[("fast", s)][key] for s in seeds])
        error = np.sqrt(e.var(ddof=1) / len(e) + f.var(ddof=1) / len(f))  # of the difference of the means
        rows.append([key, f"{e.mean():.5f} ({e.std(ddof=1):.5f})", f"{f.mean():.5f} ({f.std(ddof=1):.5f})",
                     f"{(f.mean() - e.mean()) / error:+.2f}" if error > 0 else "n/a"])
    table(
        f"6. training on {len(kept)} ShapeNetVox32 chairs' voxel-boundary meshes prepared two ways "
        f"({stage1} + {stage2} iterations, seeds {', '.join(map(str, seeds))}, {threads} torch thread(s)); "
        f"{len(held)} held-out chairs scored against the exact preparation",
        ["mean over seeds (sd)", "exact preparation", "today's preparation", "difference / its standard error"],
        rows,
        f"the grids: occupancy and samples identical; distances at most {max(errors):.1e} farther (median of the "
        f"shapes' largest {np.median(errors):.1e}); {solid} solid cells differ over {len(paths)} shapes (centres on "
        f"the boundary faces, where the winding number is 0.5: a tie either way). The training losses are\n"
        f"each run's own (coverage: to its samples, identical; consistency: through its own distance grid). The last\n"
        f"column is Welch's t: a difference stands out from the seeds' spread beyond about 2.8-4.3 (two-sided 5%, "
        f"{len(seeds)} seeds a side).",
    )


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true", help="few shapes and one repeat (smoke test)")
    parser.add_argument("--repeats", type=int, default=None, help="runs per mesh, fastest kept (default 2; quick 1)")
    parser.add_argument("--collection", type=int, default=None, help="ShapeNetVox32 chairs for prepare_collection (default 500; quick 50)")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--before", default=None, metavar="REV",
                        help="also time binvox preparation with primkit at this git revision (e.g. 7f3df5b, before issue 20)")
    parser.add_argument("--only", choices=("binvox", "path", "training"), default=None,
                        help="run section 1b alone, section 2c alone (from the path, quiet and busy), or section 6 "
                             "(training on both preparations; not in the default run)")
    parser.add_argument("--rounds", type=int, default=None, help="section 2c: rounds per condition (default 2; quick 1)")
    parser.add_argument("--iterations", default="1000,300", metavar="S1,S2", help="section 6's training stages")
    args = parser.parse_args(argv)
    quick = args.quick
    repeats = args.repeats or (1 if quick else 2)
    n_collection = args.collection or (50 if quick else 500)
    n_binvox = 10 if quick else 50
    n_distance = 2 if quick else 5
    bf_cells = 128 if quick else 1024

    import primkit

    print(f"# bench_prepare: primkit {primkit.__version__}, Python {platform.python_version()}, "
          f"NumPy {np.__version__}, {platform.machine()}, {'quick' if quick else 'full'} run")
    print(f"# {load_line()} at start")
    warm_up()
    t_start = time.perf_counter()
    if args.only == "training":
        s1, s2 = (int(x) for x in args.iterations.split(","))
        bench_training(args.collection or (36 if quick else 360), s1, s2, seeds=(0, 1) if quick else (0, 1, 2))
        print(f"\n# {load_line()} at end; benchmark took {time.perf_counter() - t_start:.0f} s")
        return 0
    rounds = args.rounds or (1 if quick else 2)
    if args.only == "path":
        items = path_inputs()
        if quick:
            items = items[::6]
        if items:
            bench_from_path(items, max(repeats, 3), rounds)
        else:
            print("\n(no PSB or COSEG meshes in the shared data: nothing to time)")
        print(f"\n# {load_line()} at end; benchmark took {time.perf_counter() - t_start:.0f} s")
        return 0
    if args.only == "binvox":
        binvox = binvox_inputs(n_binvox)
        if binvox:
            bench_binvox(binvox, repeats, args.before)
        else:
            print("\n(no ShapeNetVox32 folder: nothing to time)")
        print(f"\n# {load_line()} at end; benchmark took {time.perf_counter() - t_start:.0f} s")
        return 0
    what, items = mesh_inputs(quick)
    print(f"# inputs: {what}")
    records = bench_meshes(items, repeats)
    report_meshes(records)

    binvox = binvox_inputs(max(n_binvox, n_collection))
    if binvox:
        bench_binvox(binvox[:n_binvox], repeats, args.before)
    else:
        print("\n(no ShapeNetVox32 folder: binvox sections skipped)")

    # distance alternatives on a few meshes spread over the face counts
    order = sorted(records, key=lambda r: r["faces"])
    pick = [order[int(round(i))] for i in np.linspace(0, len(order) - 1, min(n_distance, len(order)))]
    bench_distances([r["path"] for r in pick], bf_cells, repeats)
    bench_whole_preparation([r["path"] for r in records if 10000 <= r["faces"] <= 20000], max(repeats, 3))
    if path_inputs():
        bench_from_path(path_inputs()[:: 6 if quick else 1], max(repeats, 3), rounds)
    bench_occupancy([r["path"] for r in records], repeats)

    biggest = order[-1]
    bench_memory(biggest["path"], biggest["faces"], bf_cells)
    if binvox:
        bench_collection(binvox[:n_collection], sorted({1, args.workers}))
    print(f"\n# {load_line()} at end; benchmark took {time.perf_counter() - t_start:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
