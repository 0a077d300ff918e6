"""The half of the ParaView plugin that runs in primkit's own Python: NumPy arrays in, labels out.

ParaView's Python carries its own VTK (Debian 12: ParaView 5.11 on VTK 9.2), and primkit's needs
pip's VTK (9.3 or later, through pyvista): the two cannot live in one process (pip's VTK first on
the path crashes ``pvpython``; ParaView's first makes pyvista refuse to import). So the plugin
(:mod:`primkit.plugins.paraview_plugin`, which imports nothing of primkit) converts ParaView's
polydata to NumPy, and runs this module with the Python primkit is installed in::

    python -m primkit.plugins.paraview_worker IN.npz OUT.npz
    python -m primkit.plugins.paraview_worker --serve      # answers requests until stdin closes
    python -m primkit.plugins.paraview_worker --where      # prints the plugin file's path

The plugin keeps one ``--serve`` worker while ParaView runs, so that the imports and the model load
(about 5 s) are paid once: each request is one line ``{"in": IN.npz, "out": OUT.npz}`` on its
stdin, each answer one line ``{"status": 0|2, "error": "..."}`` on its stdout (anything else the
libraries print goes to stderr); the models named are loaded once. It ends when its stdin closes,
which the operating system does when ParaView exits, however it exits.

``IN.npz`` holds ``points`` ((n, 3) float), ``faces`` ((f, 3) int, empty for a point cloud) and
``options`` (a JSON object: ``model``, ``up``, ``front``, ``align``, ``refine``, the keywords of
:func:`primkit.plugins.common.label_shapes`). ``OUT.npz`` (written atomically) holds
``face_labels`` ((f,) int64, empty for a cloud), ``point_labels`` ((n,) int64), ``part_names``
((m,) str), ``colors`` ((m, 3) uint8, :func:`primkit.viz.palette.part_colors`), and the present
cuboids as a triangle mesh in the input's frame: ``cuboid_vertices`` ((8c, 3) float64),
``cuboid_faces`` ((12c, 3) int64), ``cuboid_part`` ((12c,) int64, the slot of each triangle).

On a bad input or option it prints one line to stderr (``primkit segmentation: <reason>``) and
exits with status 2; the plugin shows that line in ParaView's output window.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

__all__ = ["label_arrays", "answer", "serve", "main"]


def label_arrays(points: np.ndarray, faces: np.ndarray, options: dict, models: dict | None = None) -> dict[str, np.ndarray]:
    """Label one shape held as arrays; the arrays of ``OUT.npz`` (see the module notes). ``models``,
    kept by a caller across calls, holds each named model loaded once with its labeller."""
    from ..viz.palette import part_colors
    from .common import label_shape

    options = dict(options)
    model = options.pop("model", "chair")
    if models is not None and isinstance(model, str):
        model, options["labeller"] = _loaded(model, models)
    points = np.asarray(points, dtype=np.float64)
    faces = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    shape = (points, faces) if len(faces) else points
    labelled = label_shape(shape, model, name="input", **options)
    v, f, part = labelled.cuboids.to_mesh()
    empty = np.zeros(0, np.int64)
    return {
        "face_labels": empty if labelled.face_labels is None else labelled.face_labels.astype(np.int64),
        "point_labels": labelled.point_labels.astype(np.int64),
        "part_names": np.array(labelled.part_names, dtype=str),
        "colors": part_colors(len(labelled.part_names)).astype(np.uint8),
        "cuboid_vertices": np.asarray(v, np.float64).reshape(-1, 3),
        "cuboid_faces": np.asarray(f, np.int64).reshape(-1, 3),
        "cuboid_part": np.asarray(part, np.int64),
    }


def _loaded(name: str, models: dict):
    """The model called ``name`` (a bundled name or a file) and its labeller, loaded once per file
    version (a file rewritten since is loaded again)."""
    from ..model.abstraction import load_model
    from ..segmentation import resolve_labeller
    from .common import model_key

    key = model_key(name)
    if key not in models:
        models[key] = (load_model(name), resolve_labeller(name))
    return models[key]


def answer(given: str, result: str, models: dict | None = None) -> tuple[int, str]:
    """Label ``given`` (an ``IN.npz``) into ``result`` (``OUT.npz``, atomically): ``(0, "")``, or
    ``(2, "primkit segmentation: <reason>")`` on a bad input or option."""
    from ..io import atomic_output

    from ..io.limits import max_faces, npz_members, read_npz_member

    try:
        # checked from the members' headers before anything is loaded: a truncated archive, or a
        # small one declaring GiBs, is one line (a BadZipFile traceback, a 6.7 GiB allocation before)
        members = npz_members(given, max_bytes=24 * max_faces())  # (f, 3) int64 faces at the bound
        missing = [k for k in ("points", "faces", "options") if k not in members]
        if missing:
            raise KeyError(f"{given}: no {', '.join(missing)} array")
        with np.load(given, allow_pickle=False) as arrays:
            points, faces, options = (read_npz_member(arrays, given, k) for k in ("points", "faces", "options"))
            out = label_arrays(points, faces, json.loads(str(options)), models)
    except (ValueError, TypeError, OSError, KeyError) as exc:
        return 2, f"primkit segmentation: {str(exc).splitlines()[0] if str(exc) else type(exc).__name__}"
    with atomic_output(result, overwrite=True) as tmp:
        with open(tmp, "wb") as fh:
            np.savez(fh, **out)
    return 0, ""


def serve(requests, replies) -> int:
    """Answer requests (lines of ``requests``) until it ends, one line on ``replies`` each (module notes)."""
    models: dict = {}
    for line in requests:
        if not line.strip():
            continue
        try:
            request = json.loads(line)
            status, error = answer(str(request["in"]), str(request["out"]), models)
        except (ValueError, KeyError, TypeError) as exc:
            status, error = 2, f"primkit segmentation: bad request to the worker ({exc})"
        replies.write(json.dumps({"status": status, "error": error}) + "\n")
        replies.flush()
    return 0


def main(argv=None) -> int:
    import os

    argv = sys.argv[1:] if argv is None else argv
    if argv == ["--where"]:  # the plugin file, for ParaView's Load New and LoadPlugin
        print(Path(__file__).with_name("paraview_plugin.py"))
        return 0
    if argv == ["--serve"]:
        # the answers keep the real stdout; whatever else writes to fd 1 (Python or C) goes to stderr
        replies = os.fdopen(os.dup(1), "w", encoding="utf-8")
        os.dup2(2, 1)
        sys.stdout = sys.stderr
        return serve(sys.stdin, replies)
    if len(argv) != 2:
        print("usage: python -m primkit.plugins.paraview_worker IN.npz OUT.npz | --serve | --where", file=sys.stderr)
        return 2
    status, error = answer(argv[0], argv[1])
    if status:
        print(error, file=sys.stderr)
    return status


if __name__ == "__main__":
    sys.exit(main())
