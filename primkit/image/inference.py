"""Using an image model: reading pictures, abstracting them (:class:`ImageAbstractor`) and drawing
the cuboids over the picture through the predicted viewpoint."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from .. import primitives
from ..io import atomic_output
from ..model.bundled import resolve_model
from ..model.modelfile import ModelFileError, check_tensors, load_model_file, read_header, write_model
from ..model.cuboids_file import cuboids_document
from ..model.parts import default_part_names
from ..primitives.palette import part_colors
from .camera import OrbitCamera, project, ViewSettings
from .network import ImageNet, ImageNetConfig, ImagePrediction, images_to_float, image_net_state_shapes

__all__ = ["KIND", "read_image", "read_image_network", "ImageAbstraction", "ImageAbstractor", "draw_over_image"]


KIND = "image-abstractor"


def read_image_network(path) -> tuple[ImageNetConfig, dict]:
    """The network config and metadata of an image model file, validated against its header before
    any weight is read (as :func:`primkit.model.network.read_network` for volume models)."""
    meta, tensors = read_header(path)
    if meta.get("kind") != KIND:
        raise ModelFileError(path, f"not an image model (kind {meta.get('kind', 'volume')!r}); use it with shape files")
    try:
        config = ImageNetConfig.from_dict(meta["network"])
    except (TypeError, ValueError) as exc:
        raise ModelFileError(path, f"bad image network description in the metadata: {exc}") from None
    names = meta.get("part_names")
    if names is not None and not (isinstance(names, list) and len(names) == config.parts
                                  and all(isinstance(n, str) for n in names)):
        raise ModelFileError(path, f"part_names must be a list of {config.parts} strings (one per part slot)")
    check_tensors(path, image_net_state_shapes(config), tensors, what="image network")
    return config, meta


def read_image(path, size: int) -> np.ndarray:
    """An image file as ``(size, size, 3) uint8``: transparency composited over white, the central
    square cropped, resized with antialiasing. Raises ``ValueError`` naming the file when unreadable."""
    from PIL import Image, UnidentifiedImageError

    try:
        with Image.open(path) as im:
            im.load()
            if im.mode in ("RGBA", "LA", "P"):
                im = im.convert("RGBA")
                white = Image.new("RGBA", im.size, (255, 255, 255, 255))
                im = Image.alpha_composite(white, im)
            im = im.convert("RGB")
    except (UnidentifiedImageError, OSError) as exc:
        raise ValueError(f"{path}: not a readable image ({exc.__class__.__name__})") from None
    w, h = im.size
    side = min(w, h)
    im = im.crop(((w - side) // 2, (h - side) // 2, (w - side) // 2 + side, (h - side) // 2 + side))
    return np.asarray(im.resize((size, size), Image.LANCZOS), np.uint8)


@dataclass(frozen=True)
class ImageAbstraction:
    """The abstraction of one picture.

    cuboids : primitives.Cuboids in the canonical frame of the shape (+Y up, front +X, longest side 1)
    azimuth_deg, elevation_deg : float, the viewpoint the network reads off the picture
    image : (S, S, 3) uint8, what the network saw
    model : str, the image model as given (a bundled name or a path; "" unknown)
    part_names : tuple of str, the model's name of each part slot (empty: ``part<k>``)
    """

    name: str
    cuboids: primitives.Cuboids
    azimuth_deg: float
    elevation_deg: float
    image: np.ndarray
    source: str = ""
    model: str = ""
    part_names: tuple = ()

    def camera(self, distance: float, view_angle_deg: float):
        return OrbitCamera(self.azimuth_deg, self.elevation_deg, distance, view_angle_deg)

    def to_dict(self) -> dict:
        """The JSON of ``<name>.cuboids.json`` (:mod:`primkit.model.cuboids_file`; the canonical frame,
        whose place in the picture's scene is unknown, and the ``viewpoint`` read off the picture)."""
        return cuboids_document(self.cuboids, name=self.name, source=self.source, frame="canonical",
                                model=self.model or None, part_names=list(self.part_names) or None,
                                viewpoint={"azimuth_deg": self.azimuth_deg, "elevation_deg": self.elevation_deg})


class ImageAbstractor:
    """A trained image abstractor: network plus model-file metadata.

    ``ImageAbstractor.load("chair-image")`` (a bundled name or a path); ``predict(images)`` for
    ``(s, S, S, 3) uint8`` arrays; ``predict_files(paths)`` for image files.
    """

    def __init__(self, network: ImageNet, metadata: dict, *, model: str = ""):
        self.network = network.eval()
        self.metadata = metadata
        #: the model as given to :meth:`load` (a bundled name or a path), recorded in the results
        self.model = str(model)

    @classmethod
    def load(cls, path) -> "ImageAbstractor":
        """A bundled image model's name or a model file, validated (:func:`read_image_network`) before allocation."""
        given, path = path, resolve_model(path)
        config, _ = read_image_network(path)
        weights, meta = load_model_file(path)
        net = ImageNet(config)
        net.load_state_dict(weights)
        return cls(net, meta, model=str(given))

    def save(self, path, metadata: dict, *, overwrite: bool = False) -> Path:
        meta = {"kind": KIND, "network": self.network.config.to_dict(), **metadata}
        return write_model(path, self.network.state_dict(), meta, overwrite=overwrite)

    @property
    def size(self) -> int:
        return self.network.config.size

    @property
    def part_names(self) -> list:
        names = self.metadata.get("part_names")
        return list(names) if names else default_part_names(self.network.config.parts)

    @property
    def view_settings(self):
        v = self.metadata.get("views")
        return ViewSettings.from_dict(v) if v else ViewSettings(size=self.size)

    def predict_raw(self, images: np.ndarray, batch_size: int = 128) -> ImagePrediction:
        """Raw network output for ``(s, S, S, 3) uint8`` images: an :class:`ImagePrediction` of
        NumPy arrays ``(s, ...)``, float64."""
        images = np.asarray(images)
        s = self.size
        if images.ndim != 4 or images.shape[1:] != (s, s, 3):
            raise ValueError(f"`images` must be (s, {s}, {s}, 3) uint8, got {images.shape}")
        out = {}
        with torch.no_grad():
            for i in range(0, len(images), batch_size):
                pred = self.network(images_to_float(torch.from_numpy(images[i: i + batch_size])))
                for k, v in pred.arrays().items():
                    out.setdefault(k, []).append(v.double().numpy())
        return ImagePrediction(**{k: np.concatenate(v) for k, v in out.items()})

    def predict(self, images: np.ndarray, names=None, sources=None, existence_threshold: float = 0.5,
                prune_threshold: float | None = 0.6) -> list[ImageAbstraction]:
        """Cuboids per image (kept and pruned as :meth:`primkit.model.abstractor.Abstractor.predict` does)."""
        raw = self.predict_raw(images)
        results = []
        for i in range(len(images)):
            cub = primitives.Cuboids(raw.half_extents[i], raw.quaternions[i], raw.translations[i],
                                     raw.existence[i] > existence_threshold, probabilities=raw.existence[i])
            if prune_threshold is not None and cub.existence.sum() > 1:
                cub = primitives.prune_covered(cub, prune_threshold)
            c, s_, el = raw.viewpoint[i]
            results.append(ImageAbstraction(
                names[i] if names is not None else f"image{i}", cub, float(np.degrees(np.arctan2(s_, c)) % 360),
                float(np.degrees(el)), np.asarray(images[i]), sources[i] if sources is not None else "",
                model=self.model, part_names=tuple(self.part_names)))
        return results

    def predict_files(self, paths, **kwargs):
        """Read and abstract image files; returns ``(results, errors)`` (one line per unreadable file)."""
        from ..data import shape_names

        images, names, sources, errors = [], [], [], []
        paths = list(paths)
        for p, name in zip(paths, shape_names(paths)):  # two files called x.png get two names
            try:
                images.append(read_image(p, self.size))
            except ValueError as exc:
                errors.append(str(exc))
                continue
            names.append(name)
            sources.append(str(p))
        if not images:
            return [], errors
        return self.predict(np.stack(images), names, sources, **kwargs), errors


def draw_over_image(result: ImageAbstraction, path, *, distance: float, view_angle_deg: float, scale: int = 4) -> None:
    """A PNG of the picture with the cuboids' edges drawn over it, projected with an assumed camera:
    the predicted azimuth and elevation, and the training views' mean distance and view angle (the
    network does not estimate those). Left: the picture; right: the picture with the cuboids.
    Returns the picture, ``(4 S, 8 S + 8, 3) uint8`` for ``scale=4``; ``path`` None writes nothing."""
    from PIL import Image, ImageDraw

    s = result.image.shape[0]
    big = Image.fromarray(result.image).resize((s * scale, s * scale), Image.BICUBIC)
    over = big.copy()
    draw = ImageDraw.Draw(over)
    cam = result.camera(distance, view_angle_deg)
    colors = part_colors(result.cuboids.count)
    corners = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float)
    edges = [(a, b) for a in range(8) for b in range(a + 1, 8) if bin(a ^ b).count("1") == 1]
    c = result.cuboids
    for k in c.present:
        pts = corners * c.half_extents[k] @ c.rotations[k].T + c.translations[k]
        uv = project(pts, cam, s) * scale
        for a, b in edges:
            if np.all(np.isfinite(uv[[a, b]])):
                draw.line([tuple(uv[a]), tuple(uv[b])], fill=tuple(int(v) for v in colors[k]), width=2)
    canvas = Image.new("RGB", (2 * s * scale + 8, s * scale), (255, 255, 255))
    canvas.paste(big, (0, 0))
    canvas.paste(over, (s * scale + 8, 0))
    if path is None:
        return np.asarray(canvas)
    with atomic_output(path, overwrite=True) as tmp:
        canvas.save(str(tmp), format="PNG")
    return np.asarray(canvas)
