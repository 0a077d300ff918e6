"""Collections of procedural shapes: seeded generation with optional attribute rates, and the
files (mesh, per-face labels through :mod:`primkit.io`, attributes) written for each shape."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from .. import io
from .categories import GENERATORS
from .labelled import CATEGORIES, LabelledShape

__all__ = ["generate", "write_collection", "read_collection_labels"]


def _check_category(category: str):
    if category not in GENERATORS:
        raise ValueError(f"unknown category {category!r}; expected one of {CATEGORIES}")
    return GENERATORS[category]


def _derived_seed(seed: int, index: int) -> int:
    """The seed of shape ``index`` of a collection seeded with ``seed``."""
    return int(np.random.SeedSequence([seed, index]).generate_state(1, dtype=np.uint32)[0])


def generate(category: str, count: int, seed: int = 0, *, rates: dict | None = None) -> list[LabelledShape]:
    """``count`` shapes of ``category``; shape ``i`` comes from a seed derived from (seed, i).

    The shape's own ``seed`` field holds that derived seed, so ``chair(shapes[i].seed)``
    regenerates shape ``i`` alone (with ``rates``, pass its drawn values too:
    ``chair(s.seed, has_arms=s.attributes["has_arms"])``).

    Parameters
    ----------
    rates : dict of str to float, optional
        The fraction of shapes that have a yes/no attribute, replacing the generator's own rate:
        ``{"has_arms": 0.5}`` gives a collection in which about half the chairs have arms (the
        generator's default is about 30%). Each shape draws these from its own stream, seeded by
        ``(seed, i)`` and separate from the one its other attributes come from, so a shape keeps
        every other attribute whatever the rates.
    """
    make = _check_category(category)
    if count < 0:
        raise ValueError(f"`count` must be non-negative, got {count}")
    if seed < 0:
        raise ValueError(f"`seed` must be non-negative, got {seed}")
    rates = dict(rates or {})
    if rates:
        defaults = make(0).attributes
        for key, rate in rates.items():
            if not isinstance(defaults.get(key), bool):
                yes_no = sorted(k for k, v in defaults.items() if isinstance(v, bool))
                raise ValueError(f"`rates` takes yes/no attributes of {category} ({', '.join(yes_no)}), got {key!r}")
            if not 0.0 <= float(rate) <= 1.0:
                raise ValueError(f"rate of {key!r} must lie in [0, 1], got {rate!r}")
    shapes = []
    for i in range(count):
        overrides = {}
        if rates:
            draws = np.random.default_rng([seed, i, _RATES_STREAM]).random(len(rates))
            overrides = {key: bool(u < float(rate)) for (key, rate), u in zip(sorted(rates.items()), draws)}
        shapes.append(make(_derived_seed(seed, i), **overrides))
    return shapes


_RATES_STREAM = 0x72617465  # tells the ``rates`` draws' seed apart from the shapes' own


def write_collection(
    folder, category: str, count: int, seed: int = 0, *, rates: dict | None = None, overwrite: bool = False
) -> list[Path]:
    """Generate ``count`` shapes and write them to ``folder``; returns the mesh paths.

    For shape ``i`` three files are written: ``<category>_<i:04d>.ply`` (the mesh, binary PLY,
    vertex and face order as generated), ``<category>_<i:04d>.seg`` (one part index per line,
    in face order) and ``<category>_<i:04d>.json`` (``category``, ``part_names``,
    ``part_groups``, ``attributes``, ``seed``). ``rates`` is :func:`generate`'s. Existing files are refused with
    :class:`FileExistsError` (before anything is written) unless ``overwrite`` is set. Every
    file is written atomically.
    """
    _check_category(category)
    folder = Path(folder)
    stems = [folder / f"{category}_{i:04d}" for i in range(count)]
    io.check_outputs([stem.with_suffix(suffix) for stem in stems for suffix in (".ply", ".seg", ".json")],
                     overwrite=overwrite)  # writable, nothing replaced without overwrite
    shapes = generate(category, count, seed, rates=rates)  # bad rates fail before anything is written
    folder.mkdir(parents=True, exist_ok=True)
    mesh_paths = []
    for stem, shape in zip(stems, shapes):
        io.write_mesh(stem.with_suffix(".ply"), shape.vertices, shape.faces, overwrite=True)
        io.write_labels(stem.with_suffix(".seg"), shape.face_labels, overwrite=True)
        meta = {
            "category": shape.category,
            "part_names": list(shape.part_names),
            "part_groups": shape.part_groups,
            "attributes": shape.attributes,
            "seed": shape.seed,
        }
        with io.atomic_output(stem.with_suffix(".json"), overwrite=True) as tmp:
            tmp.write_text(json.dumps(meta, indent=2) + "\n", encoding="utf-8")
        mesh_paths.append(stem.with_suffix(".ply"))
    return mesh_paths


def read_collection_labels(mesh_path) -> tuple[np.ndarray, dict]:
    """Read the ``.seg`` and ``.json`` written by :func:`write_collection` beside ``mesh_path``.

    Returns
    -------
    face_labels : (f,) int64
      Part index per face, in the mesh's face order.
    meta : dict
      ``category``, ``part_names`` (a tuple), ``part_groups``, ``attributes``, ``seed``.
    """
    mesh_path = Path(mesh_path)
    labels = io.read_labels(mesh_path.with_suffix(".seg"))
    meta = json.loads(mesh_path.with_suffix(".json").read_text(encoding="utf-8"))
    meta["part_names"] = tuple(meta["part_names"])
    return labels, meta
