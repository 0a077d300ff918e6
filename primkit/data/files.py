"""Input files and their names: the shape files of a folder, the files read with each (``.seg``
labels, ``.json`` attributes), one unique name per shape for its outputs, the hold-out split, and
:func:`prepare_file` (one file read and prepared)."""

from __future__ import annotations

import os
import warnings
from pathlib import Path

from .. import io
from .preparation import PreparedShape, PrepareSettings, prepare


def labels_path(path: Path) -> Path | None:
    """The ``.seg`` file that goes with a mesh: ``<stem>.seg`` beside it, or COSEG's ``../gt/<stem>.seg``."""
    for cand in (path.with_suffix(".seg"), path.parent.parent / "gt" / (path.stem + ".seg")):
        if cand.is_file():
            return cand
    return None


def prepare_file(path, settings: PrepareSettings = PrepareSettings()) -> PreparedShape:
    """Read and prepare one shape file; a ``.seg`` label file beside a mesh is used if present.

    Raises :class:`primkit.io.ShapeFileError` (one line, naming the file) when the file cannot be used.
    """
    path = Path(path)
    shape = io.read_shape(path)
    labels = None
    info = {}
    if isinstance(shape, io.Mesh):
        seg = labels_path(path)
        if seg is not None:
            try:
                labels = io.read_labels(seg, face_count=len(shape.faces))
                info["labels"] = str(seg)
            except io.ShapeFileError as exc:
                # labels are for the commands that evaluate or train on them: a stale .seg beside a
                # mesh must not keep the mesh from being abstracted; it is prepared without labels
                warnings.warn(f"{exc} (prepared without labels)", stacklevel=2)
                info["labels_error"] = str(exc)
    try:
        prepared = prepare(shape, settings, face_labels=labels, name=shape_name(path), source=str(path))
    except (ValueError, RuntimeError) as exc:
        raise io.ShapeFileError(path, f"cannot prepare: {exc}") from exc
    if info:
        prepared = PreparedShape(**{**prepared.__dict__, "info": info})
    return prepared


#: files that belong to the shape beside them with this stem (a point cloud's labels), never shapes
_BELONGS = ".labels.npy"


def find_shape_files(folder) -> list[Path]:
    """Shape files under ``folder`` (recursively, sorted), by suffix (see :func:`primkit.io.is_shape_file`).

    Symbolically linked folders are searched too (each folder once, so a link back up is not a
    loop); the hidden temporaries a killed write leaves (:func:`primkit.io.is_temporary`) are not
    shapes, nor is a ``<stem>.labels.npy`` beside a shape file of that stem (its labels). A file
    given by name is returned as it is. An empty list means no shape file."""
    folder = Path(folder)
    if folder.is_file():
        return [folder]
    if not folder.is_dir():
        raise FileNotFoundError(f"{folder}: no such file or folder")
    found, searched = [], set()
    for root, dirs, files in os.walk(folder, followlinks=True):
        st = os.stat(root)
        if (st.st_dev, st.st_ino) in searched:  # reached again through a link
            dirs[:] = []
            continue
        searched.add((st.st_dev, st.st_ino))
        stems = {n.rsplit(".", 1)[0] for n in files if "." in n and io.is_shape_file(n)}
        for name in files:
            if name.endswith(_BELONGS) and name[: -len(_BELONGS)] in stems:
                continue  # a labelled cloud's labels (<stem>.labels.npy), not a shape of its own
            p = Path(root) / name
            # a dangling link is kept: its error line names it
            if io.is_shape_file(p) and not io.is_temporary(p) and (p.is_file() or p.is_symlink()):
                found.append(p)
    return sorted(found)


def input_files(path) -> list[Path]:
    """The files read for the shape file ``path``: itself, the ``.seg`` labels that go with it
    (:func:`prepare_file`) and the ``.json`` attributes beside procedural shapes (``primkit
    generate``). Outputs are checked against these, so that no run writes over what it reads."""
    path = Path(path)
    out = [path]
    seg = labels_path(path)
    if seg is not None:
        out += [seg, seg.with_suffix(".json")]
    out.append(path.with_suffix(".json"))
    return [p for p in dict.fromkeys(out) if os.path.lexists(p)]


#: file stems that say nothing about the shape (ShapeNet's ``<synset>/<id>/model.binvox``); the
#: folder's name is used instead
_GENERIC_STEMS = {"model", "model_normalized", "models", "mesh", "shape"}


def shape_name(path) -> str:
    """A shape's name from its path: the file's stem, or its folder's name when the stem is generic
    (``03001627/1a6f615e8b1b5ae4dbbc9440457e303e/model.binvox`` -> ``1a6f615e...``)."""
    path = Path(path)
    if path.stem.lower() in _GENERIC_STEMS and path.parent.name:
        return path.parent.name
    return path.stem


def shape_names(paths) -> list[str]:
    """One name per path, unique within ``paths``: :func:`shape_name`, except where several paths
    share it; those take the folders that tell them apart (``a/x.ply``, ``b/x.ply`` -> ``a-x``,
    ``b-x``), or their suffix when the folder is the same (``x.ply``, ``x.obj`` -> ``x-ply``,
    ``x-obj``), and a number when nothing else differs (the same file twice: ``x``, ``x-2``).

    Outputs are named after shapes, so two inputs never write the same output file; the names
    depend only on the paths, so a run and its re-run name everything alike."""
    paths = [Path(p) for p in paths]
    names = [shape_name(p) for p in paths]
    groups: dict = {}
    for i, name in enumerate(names):
        groups.setdefault(name, []).append(i)
    out = list(names)
    for name, members in groups.items():
        if len(members) < 2:
            continue
        # the folder above the one a generic stem (model.binvox) is named after
        anchors = [Path(os.path.abspath(paths[i])).parent for i in members]
        anchors = [a.parent if paths[i].stem.lower() in _GENERIC_STEMS else a for a, i in zip(anchors, members)]
        common = os.path.commonpath(anchors)
        for a, i in zip(anchors, members):
            out[i] = "-".join(Path(a).relative_to(common).parts + (name,))
        same: dict = {}
        for i in members:
            same.setdefault(out[i], []).append(i)
        for equal in same.values():
            if len({paths[i].suffix.lower() for i in equal}) > 1:
                for i in equal:
                    out[i] = f"{out[i]}-{paths[i].suffix[1:].lower()}"
    used, planned = set(), set(out)
    for i, name in enumerate(out):  # still equal (the same file twice), or equal to another shape's name
        if name in used:
            k = 2
            while f"{name}-{k}" in used or f"{name}-{k}" in planned:
                k += 1
            out[i] = f"{name}-{k}"
        used.add(out[i])
    return out


def split_files(files, hold_out_every: int) -> tuple[list, list]:
    """Split files deterministically into (training, held-out): sorted by path, the file of rank
    ``r`` is held out when ``r % hold_out_every == hold_out_every - 1``; ``0`` holds out nothing.

    The rule depends only on the sorted paths, so the held-out set can be recomputed from a model
    file's metadata (``primkit eval --split held-out``)."""
    files = sorted(Path(p) for p in files)
    if not hold_out_every:
        return files, []
    if hold_out_every < 2:
        raise ValueError(f"hold_out_every must be 0 or at least 2, got {hold_out_every}")
    train = [p for r, p in enumerate(files) if r % hold_out_every != hold_out_every - 1]
    held = [p for r, p in enumerate(files) if r % hold_out_every == hold_out_every - 1]
    return train, held
