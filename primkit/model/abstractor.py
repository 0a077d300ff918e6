"""Inference: a trained abstractor turns prepared shapes into indexed cuboids.

``Abstractor.load(path).predict(shapes)`` for prepared shapes (the network's cost is paid once and
shapes go through it in batches); :mod:`primkit.model.abstraction` takes shapes as the user has them
(files, meshes, arrays) and is what the commands use.

Which parts are kept: a part exists when its probability is above ``existence_threshold`` (0.5),
then parts mostly inside the others are pruned (:func:`primkit.primitives.prune_covered`: while the
part with the largest fraction of its volume inside the other present parts exceeds
``prune_threshold``, 0.6 as in the published code, that part is dropped), and last parts without a
size are dropped (:func:`drop_unsized_parts`: a part whose longest side is under ``min_extent``,
0.02 of the shape's longest bounding-box side, or that is the nearest present part of none of the
shape's surface samples). Part indices are never renumbered: part ``k`` is slot ``k`` of the
network on every shape, and absent parts stay in the output, marked absent.

Options (both off by default, both in ``primkit abstract``):

* ``align="auto"``: each shape is tried in the 24 axis-aligned orientations
  (:mod:`primkit.model.orientation`) and the one whose predicted cuboids have the lowest coverage +
  consistency loss (:func:`primkit.model.fitting.fit_losses`) is used; the result records it
  (``alignment``) and the cuboids still come back in the input's frame.
* ``refine=N``: ``N`` Adam steps on each shape's own losses, from the network's answer, with part
  indices and existence kept (:func:`primkit.model.fitting.refine`); the result records the loss before
  and after.

Results come back in the input's own frame (the canonical frame used by the network is undone),
and :meth:`AbstractionResult.save` writes a JSON file (schema-versioned, see
:class:`primkit.primitives.Cuboids`) and a mesh of the present cuboids coloured by part index.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .. import data, io, primitives
from . import orientation
from .parts import default_part_names
from .bundled import resolve_model
from ..primitives.palette import part_colors
from .fitting import fit_losses_of_sets
from .fitting import refine as refine_cuboids
from .cuboids_file import cuboids_document, write_cuboids_file
from .orientation import Alignment
from .network import load_network

__all__ = ["Abstractor", "AbstractionResult", "OrientationSearch", "Refinement", "RawCuboids", "MIN_EXTENT", "ORIENTATION_POINTS", "ORIENTATION_SAMPLES",
           "drop_unsized_parts"]

#: Surface points of a shape and samples per cuboid with which orientations are scored.
ORIENTATION_POINTS = 4000
ORIENTATION_SAMPLES = 300

#: Smallest longest side of a present part, in canonical units (the shape's longest bounding-box side
#: is 1; a cell of a 32^3 grid is 0.031). The bundled chair model's present parts are bimodal: on
#: 150 PartNet validation chairs 576 of 1,310 had a longest side under 1e-4 and only 9 lay between
#: 1e-4 and 0.03 (scripts/partnet_part_counts.py), so the exact value matters little.
MIN_EXTENT = 0.02


def drop_unsized_parts(cuboids: primitives.Cuboids, points, min_extent: float = MIN_EXTENT, *,
                       grow: bool = True) -> primitives.Cuboids:
    """The same slots with every part that has no size marked absent (indices kept).

    ``points`` are the shape's surface samples, ``(n, 3) float`` in the cuboids' frame;
    ``min_extent`` is in the same units (in the canonical frame, a fraction of the shape's longest
    side). Three steps, each deterministic:

    1. ``grow``: a present part whose longest side ``2 * max(half_extents[k])`` is under
       ``min_extent`` but that is the nearest present part (:func:`primkit.primitives.assign_points`:
       ties to the larger volume, then the lower index) of some points is replaced by the smallest
       box in its own orientation holding those points. The network places such degenerate parts
       (a point, or a needle) where it means a part, and the nearest-part rule labels with them, so
       dropping them outright loses parts the user can see (the chair model's arms and some legs).
    2. A present part whose longest side is still under ``min_extent`` is marked absent. When none
       is left, the present part with the longest side is kept, so a shape never loses every part.
    3. A present part that is the nearest present part of none of ``points`` is marked absent. One
       pass is exact: the part that owns no point gives none to the others, so none loses one.
    """
    c = cuboids
    if not isinstance(c, primitives.Cuboids):
        raise TypeError(f"`cuboids` must be a Cuboids, got {type(c).__name__}")
    present = c.present
    if not len(present):
        return c
    points = np.asarray(points, float).reshape(-1, 3)
    half, trans = c.half_extents.copy(), c.translations.copy()
    small = c.existence & (2.0 * half.max(axis=1) < float(min_extent))
    if grow and small.any() and len(points):
        owner = primitives.assign_points(points, c)
        for k in np.flatnonzero(small):
            mine = points[owner == k]
            if len(mine):  # the box of its points in the part's own axes (columns of R are its axes)
                rot = c.rotations[k]
                local = (mine - trans[k]) @ rot
                lo, hi = local.min(axis=0), local.max(axis=0)
                trans[k] = trans[k] + rot @ ((lo + hi) / 2.0)
                half[k] = np.maximum((hi - lo) / 2.0, half[k])  # half extents stay > 0
    longest = 2.0 * half.max(axis=1)
    keep = c.existence & (longest >= float(min_extent))
    if not keep.any():
        keep[present[np.argmax(longest[present])]] = True
    c = primitives.Cuboids(half, c.quaternions, trans, keep, c.probabilities)
    if len(points):
        owned = np.zeros(c.count, bool)
        owned[primitives.assign_points(points, c)] = True
        keep &= owned
    return c.with_existence(keep)


@dataclass(frozen=True, eq=False)
class RawCuboids:
    """The network's answer for ``s`` occupancy grids, before any threshold or pruning
    (:meth:`Abstractor.predict_canonical`): canonical frame, float64, ``m`` slots per shape.

    Attributes
    ----------
    half_extents : (s, m, 3) float
    quaternions : (s, m, 4) float
        Unit, real part first.
    translations : (s, m, 3) float
    existence : (s, m) float
        The probability that each part exists.
    """

    half_extents: np.ndarray
    quaternions: np.ndarray
    translations: np.ndarray
    existence: np.ndarray

    def arrays(self) -> dict[str, np.ndarray]:
        """The four arrays by field name (e.g. for ``np.savez``; ``RawCuboids(**arrays)`` is the inverse)."""
        return {"half_extents": self.half_extents, "quaternions": self.quaternions,
                "translations": self.translations, "existence": self.existence}

    def rows(self, index) -> "RawCuboids":
        """The shapes ``index`` (an int array, a slice or a boolean mask) of every array."""
        return RawCuboids(self.half_extents[index], self.quaternions[index], self.translations[index],
                          self.existence[index])


@dataclass(frozen=True)
class Refinement:
    """How ``refine`` changed one shape's cuboids: ``steps`` Adam steps, and the fit loss
    (:func:`primkit.model.fitting.fit_losses`) before and after."""

    steps: int
    loss_before: float
    loss_after: float

    def to_dict(self) -> dict:
        """JSON-ready (the ``refinement`` entry of ``<name>.cuboids.json``)."""
        return {"steps": self.steps, "loss_before": self.loss_before, "loss_after": self.loss_after}


@dataclass(frozen=True, eq=False)
class OrientationSearch:
    """What :meth:`Abstractor.search_orientations` found for ``s`` shapes (nothing turned yet).

    Attributes
    ----------
    choice : (s,) int
        Each shape's orientation, an index into :data:`primkit.model.orientation.AXIS_ROTATIONS`.
    reports : list of orientation.Alignment
        As :meth:`Abstractor.orient` returns them.
    answers : RawCuboids or None
        When asked: the network's raw answer for each shape turned by its choice, from the
        search's own forward pass of that turn (the turned occupancy is the network's input, so it
        is the answer :meth:`Abstractor.predict_canonical` gives the turned shape).
    """

    choice: np.ndarray
    reports: list
    answers: RawCuboids | None = None


@dataclass(frozen=True)
class AbstractionResult:
    """The cuboids a model gives one prepared shape: a value, with no geometry of the shape
    (:class:`primkit.model.abstraction.Abstraction` pairs it with the shape; :mod:`primkit.model`
    sets the four names side by side).

    Attributes
    ----------
    name : str
    cuboids : primitives.Cuboids
        In the input's frame.
    canonical : primitives.Cuboids
        The same in the canonical frame of the network.
    frame : geometry.CanonicalFrame
    source : str
    alignment : orientation.Alignment or None
        How ``align`` turned the shape; None when it was not asked.
    refinement : Refinement or None
        What ``refine`` did; None when it was not asked.
    model : str
        The model that abstracted it, as given (a bundled name or a model file's path; "" unknown).
    part_names : tuple of str
        The model's name of each part slot (empty: ``part<k>``).
    """

    name: str
    cuboids: primitives.Cuboids
    canonical: primitives.Cuboids
    frame: object
    source: str = ""
    alignment: Alignment | None = None
    refinement: Refinement | None = None
    model: str = ""
    part_names: tuple = ()

    def _file_fields(self) -> dict:
        extra = {}
        if self.alignment is not None:
            extra["alignment"] = self.alignment.to_dict()
        else:  # as declared (or the defaults): say which axes were taken as up and front
            axes = orientation.describe_rotation(self.frame.rotation)
            extra["alignment"] = {"mode": "none", "up": axes.up, "front": axes.front}
        if self.refinement is not None:
            extra["refinement"] = self.refinement.to_dict()
        return dict(name=self.name, source=self.source, frame="input", canonical_frame=self.frame,
                    model=self.model or None, part_names=list(self.part_names) or None, **extra)

    def to_dict(self) -> dict:
        """The JSON of ``<name>.cuboids.json`` (:mod:`primkit.model.cuboids_file`, cuboids in the input's frame)."""
        return cuboids_document(self.cuboids, **self._file_fields())

    def canonical_shape(self, shape):
        """The prepared ``shape`` in the frame of ``canonical`` (turned when ``align`` chose an orientation)."""
        if self.alignment is None:
            return shape
        return orientation.rotate_prepared(shape, np.asarray(self.alignment.rotation, float))

    def save(self, folder, *, overwrite: bool = False, mesh_format: str = ".ply") -> tuple[Path, Path]:
        """Write ``<name>.cuboids.json`` and ``<name>.cuboids<mesh_format>`` into ``folder``."""
        folder = Path(folder)
        folder.mkdir(parents=True, exist_ok=True)
        json_path = folder / f"{self.name}.cuboids.json"
        mesh_path = folder / f"{self.name}.cuboids{mesh_format}"
        io.refuse_existing((json_path, mesh_path), overwrite)
        # the mesh first: the JSON marks the pair done (--skip-done), so it is never left alone
        v, f, part = self.cuboids.to_mesh()
        colors = part_colors(self.cuboids.count)[part] if len(f) else None  # no part present: an empty mesh
        io.write_mesh(mesh_path, v, f, face_colors=colors, overwrite=overwrite)
        self.save_json(json_path, overwrite=overwrite)
        return json_path, mesh_path

    def save_json(self, path, *, overwrite: bool = False) -> Path:
        """Write ``path``, a ``<name>.cuboids.json`` alone (:func:`primkit.model.cuboids_file.write_cuboids_file`)."""
        return write_cuboids_file(path, self.cuboids, overwrite=overwrite, **self._file_fields())


@dataclass(frozen=True, eq=False)
class _Scored:
    """What the frame search's losses read of a shape: its distance grid and the chosen surface samples."""

    closest: np.ndarray
    points: np.ndarray


def _unit_rows(q: np.ndarray) -> np.ndarray:
    """Quaternion rows normalised as :class:`primkit.primitives.Cuboids` does on construction
    (rows already unit to 1e-12 are kept bit for bit)."""
    norm = np.linalg.norm(q, axis=-1, keepdims=True)
    return np.where(np.abs(norm - 1.0) > 1e-12, q / norm, q)


class Abstractor:
    """A trained model, loaded once: the network, its part names and its model-file metadata;
    :meth:`predict` turns prepared shapes into :class:`AbstractionResult` values.

    Parameters
    ----------
    network : primkit.model.network.AbstractionNet
    metadata : dict
    """

    def __init__(self, network, metadata: dict, device: str | None = None, *, model: str = ""):
        import torch

        self.device = device or ("cuda" if torch.cuda.is_available() else "cpu")
        self.network = network.to(self.device).eval()
        self.metadata = metadata
        #: the model as given to :meth:`load` (a bundled name or a path), recorded in the results
        self.model = str(model)

    @classmethod
    def load(cls, path, device: str | None = None) -> "Abstractor":
        """Load a model file written by ``primkit train``, or a bundled model by name (``"chair"``)."""
        net, meta = load_network(resolve_model(path))
        return cls(net, meta, device, model=str(path))

    @property
    def parts(self) -> int:
        return self.network.config.parts

    @property
    def resolution(self) -> int:
        return self.network.config.grid

    @property
    def part_names(self) -> list[str]:
        names = self.metadata.get("part_names")
        return list(names) if names else default_part_names(self.parts)

    @property
    def hold_out_every(self) -> int:
        """The hold-out rule the model was trained with (:func:`primkit.data.split_files`; 0: none recorded)."""
        return int(((self.metadata.get("training") or {}).get("data") or {}).get("hold_out_every") or 0)

    @property
    def settings(self) -> data.PrepareSettings:
        return data.PrepareSettings(resolution=self.resolution)

    def predict_canonical(self, occupancy: np.ndarray, batch_size: int = 64) -> RawCuboids:
        """Raw network output for ``(s, R, R, R)`` occupancy grids, as NumPy arrays (:class:`RawCuboids`).

        On the CPU each shape goes through the network on its own: oneDNN's convolutions choose
        their kernels by batch size, and on some CPUs a shape's output then changed with the batch
        it came in by up to 2e-7 (so a Dask run's files differed from a local run's, and a shape
        deformed onto itself moved). Alone, a shape's output is the same whatever else is asked and
        however many threads run; it costs about 0.2 ms a shape. On CUDA shapes go ``batch_size``
        at a time."""
        import torch

        return self._raw(occupancy, batch_size if torch.device(self.device).type == "cuda" else 1)

    def _raw(self, occupancy: np.ndarray, step: int) -> RawCuboids:
        """:meth:`predict_canonical`'s answer, ``step`` shapes at a time on any device."""
        import torch

        occupancy = np.asarray(occupancy)
        out = {"half_extents": [], "quaternions": [], "translations": [], "existence": []}
        with torch.inference_mode():
            for i in range(0, len(occupancy), step):
                x = torch.from_numpy(occupancy[i : i + step].astype(np.float32)).to(self.device)
                pred = self.network(x)
                for key in out:
                    out[key].append(getattr(pred, key).double().cpu().numpy())
        raw = {k: np.concatenate(v) for k, v in out.items()}
        for key, values in raw.items():
            if not np.isfinite(values).all():  # "`half_extents` must be finite" named no file before
                from .modelfile import ModelFileError

                raise ModelFileError(self.model or "the model", f"its network answers NaN or inf {key} (weights "
                                     "that are not finite?): the model file is damaged")
        return RawCuboids(**raw)

    def _cuboids(self, raw: RawCuboids, i: int, existence_threshold: float) -> primitives.Cuboids:
        # max_half_extent * sigmoid(x) is exactly 0 in float32 below x of about -104 (a part driven to
        # no size, as adaptation can): floored so that a Cuboids can hold it; drop_unsized_parts drops it
        return primitives.Cuboids(
            np.maximum(raw.half_extents[i], 1e-12), raw.quaternions[i], raw.translations[i],
            raw.existence[i] > existence_threshold, probabilities=raw.existence[i],
        )

    def align(self, shape, existence_threshold: float = 0.5, mode: str = "any"):
        """One shape turned into the axis-aligned orientation the model explains best
        (:meth:`orient` for one shape; ``mode`` as there)."""
        turned, reports = self.orient([shape], mode, existence_threshold)
        return turned[0], reports[0]

    def _candidate_losses(self, shapes, candidates, existence_threshold: float, chunk: int, *,
                          points: int = ORIENTATION_POINTS, samples_per_cuboid: int = ORIENTATION_SAMPLES):
        """(s, k) fit losses of every shape turned by every candidate rotation (:meth:`_score_candidates`)."""
        return self._score_candidates(shapes, candidates, existence_threshold, chunk, points=points,
                                      samples_per_cuboid=samples_per_cuboid)[0]

    def _score_candidates(self, shapes, candidates, existence_threshold: float, chunk: int, *,
                          points: int = ORIENTATION_POINTS, samples_per_cuboid: int = ORIENTATION_SAMPLES,
                          keep_raw: bool = False, draws: dict | None = None):
        """``(losses, raw)``: (s, k) fit losses of every shape turned by every candidate rotation,
        and (with ``keep_raw``, else None) the network's raw answers, (s, k, m, ...) arrays.

        Only the occupancy grid is turned (the network's input); the predicted cuboids are turned
        back into the shape's own canonical frame and scored there, which is exact (axis
        rotations map cells onto cells) and spares turning the distance grids and samples. Every
        candidate of a shape is scored on the same ``points`` surface samples, and each shape's
        distance grid is read once for its ``k`` turns (:func:`primkit.model.fitting.fit_losses_of_sets`).

        The straightforward way (each turned grid through the network alone, each answer turned
        back as a :class:`~primkit.primitives.Cuboids`, :func:`~primkit.model.fitting.fit_losses` on
        the list, ``chunk`` shapes at a time) does the same arithmetic on the same random samples,
        except that here (on the CPU) a shape's ``k`` turns go through the network as one batch,
        which rounds differently (up to 5e-7 in the outputs, 5e-6 relative in the losses, measured
        on 960 turns; a shape's answers still depend on that shape alone):
        ``tests/model/test_orientation.py`` compares the two and their choices. Written as arrays
        because that way spent most of the frame search on the network's batches of one, copying
        each distance grid ``k`` times and building ``s k`` cuboid objects (docs/adaptation.md). ``draws``: a dict kept across calls for the
        losses' random samples (:func:`~primkit.model.fitting.fit_losses_of_sets`).
        """
        import torch

        candidates = np.asarray(candidates)
        k = len(candidates)
        rotations = orientation.AXIS_ROTATIONS[candidates]  # A: the turn; its cuboids come back by A^T
        out = np.empty((len(shapes), k))
        kept = []
        draws = {} if draws is None else draws  # the losses' random samples: the same for every chunk
        rng = np.random.default_rng(0)
        for start in range(0, len(shapes), chunk):
            block = shapes[start : start + chunk]
            b, res = len(block), block[0].occupancy.shape[0]
            flat = np.stack([np.asarray(s.occupancy).reshape(-1) for s in block])  # (b, R^3)
            cells = np.stack([orientation.source_index(res, a) for a in rotations])  # (k, R^3)
            grids = flat[:, cells].reshape(b * k, res, res, res)  # shape-major, as rotate_grid turns each
            raw = self._raw(grids, k if torch.device(self.device).type == "cpu" else len(grids))
            m = raw.half_extents.shape[1]
            # each answer back in its shape's frame, as Cuboids(...).transformed(A^T) does it, on arrays
            half = np.maximum(raw.half_extents, 1e-12).reshape(b, k, m, 3)
            q = _unit_rows(raw.quaternions)
            turned_back = np.swapaxes(rotations, 1, 2)[None, :, None] @ primitives.quaternion_to_matrix(q).reshape(
                b, k, m, 3, 3)
            quats = _unit_rows(primitives.matrix_to_quaternion(turned_back))
            trans = (raw.translations.reshape(b, k, m, 1, 3) @ rotations[None, :, None])[..., 0, :] + 0.0
            exist = raw.existence.reshape(b, k, m) > existence_threshold
            scored = []
            for s in block:
                pick = rng.choice(len(s.points), min(points, len(s.points)), replace=False)
                scored.append(_Scored(s.closest, s.points[pick]))
            out[start : start + b] = fit_losses_of_sets(half, quats, trans, exist, scored,
                                                        samples_per_cuboid=samples_per_cuboid, draws=draws).total
            if keep_raw:
                kept.append(RawCuboids(**{key: v.reshape((b, k) + v.shape[1:]) for key, v in raw.arrays().items()}))
        raw = None
        if keep_raw:
            raw = RawCuboids(**{key: np.concatenate([r.arrays()[key] for r in kept]) for key in RawCuboids.__dataclass_fields__})
        return out, raw

    def orient(self, shapes, mode: str = "auto", existence_threshold: float = 0.5, *, up_margin: float | None = None,
               chunk: int = 16, vote_shapes: int = 24) -> tuple[list, list[Alignment]]:
        """Shapes turned into the orientation ``mode`` finds (:data:`primkit.model.orientation.ALIGN_MODES`).

        Each candidate orientation is predicted and scored with the fit losses
        (:func:`primkit.model.fitting.fit_losses`). ``"front"`` and ``"any"`` score their 4 or 24
        candidates on every shape. ``"auto"`` scores every shape in all 24 orientations and keeps,
        for each, the best turn about the expected up axis unless an orientation with another up
        axis cuts the loss by the margin (:func:`primkit.model.orientation.choose_orientation`):
        the shape is then clearly lying down. An axis the shape is mirror symmetric across
        (:func:`primkit.model.orientation.mirror_symmetry`) is never taken as up, the expected one
        included: a pedestal stool is not laid on its side, and one that lies is stood up. The expected up axis is +Y, or the collection's: up
        to ``vote_shapes`` shapes (spread over the collection) each pick their own up axis from +Y
        by the margin, and when two thirds of them agree (and there is more than one shape) that
        axis is expected of every shape. So a symmetric stool among chairs keeps the collection's
        up, and a chair lying on its side among upright ones is still stood up (imposing the
        collection's up axis on every shape left one in ten Princeton chairs and three in ten
        tables on their side). It costs 24 candidates a shape, as ``"any"`` does.

        Returns ``(turned shapes, reports)``; a report (:class:`~primkit.model.orientation.Alignment`)
        gives the ``mode``, the chosen ``rotation``
        of the canonical frame, the input axes taken as ``up`` and ``front``, the loss of the
        chosen orientation and of the shape as given, and how the up axis was decided.
        :meth:`search_orientations` finds the same without turning the shapes.
        """
        shapes = list(shapes)
        found = self.search_orientations(shapes, mode, existence_threshold, up_margin=up_margin, chunk=chunk,
                                         vote_shapes=vote_shapes)
        turned = [orientation.rotate_prepared(s, orientation.AXIS_ROTATIONS[c]) for s, c in zip(shapes, found.choice)]
        return turned, found.reports

    def search_orientations(self, shapes, mode: str = "auto", existence_threshold: float = 0.5, *,
                            up_margin: float | None = None, chunk: int = 16, vote_shapes: int = 24,
                            answers: bool = False) -> OrientationSearch:
        """The orientation :meth:`orient` finds for each shape, without turning the shapes
        (:class:`OrientationSearch`; the same arguments). With ``answers``, also the network's raw
        answer for each shape in its chosen orientation, taken from the search's own forward pass
        (what :func:`primkit.model.adaptation.adapt` pulls toward): nothing is run twice."""
        shapes = list(shapes)
        margin = orientation.UP_MARGIN if up_margin is None else float(up_margin)
        rotations = orientation.AXIS_ROTATIONS
        up_decided = ["given"] * len(shapes)
        if mode == "auto":
            sample = orientation.vote_sample(len(shapes), vote_shapes)
            everything = np.arange(len(rotations))
            candidates = everything
            draws: dict = {}
            sample_losses, sample_raw = self._score_candidates([shapes[i] for i in sample], everything,
                                                               existence_threshold, chunk, keep_raw=answers,
                                                               draws=draws)
            losses = np.empty((len(shapes), len(everything)))
            losses[sample] = sample_losses
            rest = np.setdiff1d(np.arange(len(shapes)), sample)
            order = sample
            raw = [sample_raw]
            if len(rest):
                losses[rest], rest_raw = self._score_candidates([shapes[i] for i in rest], everything,
                                                                existence_threshold, chunk, keep_raw=answers,
                                                                draws=draws)
                order = np.concatenate([sample, rest])
                raw.append(rest_raw)
            symmetry = np.array([orientation.mirror_symmetry(s.occupancy) for s in shapes])
            vote = orientation.choose_auto(losses, margin, vote_shapes, symmetry=symmetry)
            choice = list(vote.choice)
            loss = [float(losses[i, c]) for i, c in enumerate(choice)]
            as_given = [float(row[0]) for row in losses]
            for i, c in enumerate(choice):
                if not vote.voted:
                    up_decided[i] = "shape"
                elif np.allclose(rotations[c][1], vote.expected):
                    up_decided[i] = f"collection: {vote.agree} of {vote.voters} sampled shapes"
                else:
                    up_decided[i] = (f"shape: lying down against the collection's ({vote.agree} of {vote.voters} "
                                     "sampled shapes)")
        else:
            candidates = orientation.candidate_rotations(mode)
            losses, raw = self._score_candidates(shapes, candidates, existence_threshold, chunk, keep_raw=answers)
            raw, order = [raw], np.arange(len(shapes))
            choice = [orientation.choose_orientation(row, candidates, mode, margin) for row in losses]
            rows = {int(c): i for i, c in enumerate(candidates)}
            loss = [float(losses[i, rows[c]]) for i, c in enumerate(choice)]
            as_given = [float(row[0]) for row in losses]
        reports = []
        for i, s in enumerate(shapes):
            axes = orientation.describe_rotation(rotations[choice[i]] @ s.frame.rotation)
            reports.append(Alignment(mode, rotations[choice[i]].copy(), axes.up, axes.front, up_decided[i], loss[i],
                                     as_given[i]))
        chosen = None
        if answers:  # each shape's row of its chosen candidate, in the shapes' order
            column = {int(c): j for j, c in enumerate(candidates)}
            where = np.empty(len(shapes), int)
            where[order] = np.arange(len(order))
            pick = (where, np.array([column[int(c)] for c in choice], int))
            chosen = RawCuboids(**{key: np.concatenate([r.arrays()[key] for r in raw])[pick]
                                   for key in RawCuboids.__dataclass_fields__})
        return OrientationSearch(np.asarray(choice, int), reports, chosen)

    def predict(
        self,
        shapes,
        existence_threshold: float = 0.5,
        prune_threshold: float | None = 0.6,
        batch_size: int = 64,
        seed: int = 0,
        align: str | None = None,
        refine: int = 0,
        min_extent: float | None = MIN_EXTENT,
    ) -> list[AbstractionResult]:
        """Abstract prepared shapes (:class:`primkit.data.PreparedShape`), in batches.

        Parameters
        ----------
        existence_threshold : float
            Parts with probability above it exist.
        prune_threshold : float or None
            Drop parts whose volume is more than this fraction inside the other parts; None keeps all.
        align : None or a mode of :data:`primkit.model.orientation.ALIGN_MODES`
            How each shape's orientation is found: ``"auto"`` (the 4 turns about the up axis, and
            another up axis for a shape clearly lying down), ``"front"``, ``"any"`` (24 turns) or
            ``None``/``"none"`` (as prepared).
        refine : int
            Gradient steps per shape on its own losses after the network (0: none).
        min_extent : float or None
            Parts without a size are dropped (:func:`drop_unsized_parts`, after pruning and again
            after ``refine``); None keeps them (the behaviour before this rule).
        """
        shapes = list(shapes)
        if not shapes:
            return []
        if align is not None and align not in orientation.ALIGN_MODES:
            raise ValueError(f"align must be None or one of {', '.join(orientation.ALIGN_MODES)}, got {align!r}")
        for s in shapes:
            if s.resolution != self.resolution:
                raise ValueError(f"{s.name}: prepared at {s.resolution}^3 but the model reads {self.resolution}^3")
        alignments = [None] * len(shapes)
        if align not in (None, "none"):
            shapes, alignments = self.orient(shapes, align, existence_threshold)
        raw = self.predict_canonical(np.stack([s.occupancy for s in shapes]), batch_size)
        cubs = [self._cuboids(raw, i, existence_threshold) for i in range(len(shapes))]
        if prune_threshold is not None:  # all shapes at once (the same result as one at a time)
            cubs = primitives.prune_covered_many(cubs, prune_threshold, seed=seed)
        if min_extent is not None:
            cubs = [drop_unsized_parts(c, s.points, min_extent) for c, s in zip(cubs, shapes)]
        refinements = [None] * len(shapes)
        if refine:
            refined = []
            for i in range(0, len(shapes), batch_size):
                done = refine_cuboids(cubs[i : i + batch_size], shapes[i : i + batch_size], refine, seed=seed)
                refined.extend(done.cuboids)
                for j in range(len(done.cuboids)):
                    refinements[i + j] = Refinement(int(refine), float(done.loss_before[j]), float(done.loss_after[j]))
            cubs = refined
            if min_extent is not None:
                cubs = [drop_unsized_parts(c, s.points, min_extent) for c, s in zip(cubs, shapes)]
        results = []
        for s, cub, al, rf in zip(shapes, cubs, alignments, refinements):
            back = np.linalg.inv(s.frame.matrix)
            results.append(AbstractionResult(s.name, cub.transformed(back), cub, s.frame, s.source, al, rf,
                                             model=self.model, part_names=tuple(self.part_names)))
        return results
