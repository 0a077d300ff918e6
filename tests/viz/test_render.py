"""Off-screen pictures: the camera convention against closed forms, and reference images (pyvista's
image-cache approach: render, compare with a stored PNG with a tolerance).

Regenerate the reference images after an intended change of the pictures with
``PRIMKIT_UPDATE_REFERENCE_IMAGES=1 pytest tests/test_render.py`` and look at them before committing.
"""

import os
from pathlib import Path

import numpy as np
import pytest

from primkit.viz import render
from primkit.viz.camera import CAMERA
from primkit.primitives import Cuboids

REFERENCE = Path(__file__).parent / "reference_images"
TILE = 200


def _box(center=(0.0, 0.0, 0.0), half=0.25):
    return Cuboids(np.full((1, 3), half), [[1.0, 0, 0, 0]], [center], [True])


def _silhouette(image):
    """(rows, cols) bool: pixels that are not the white background."""
    return np.abs(image.astype(int) - 255).sum(-1) > 30


def _extent(mask):
    rows, cols = np.flatnonzero(mask.any(1)), np.flatnonzero(mask.any(0))
    return rows[-1] - rows[0] + 1, cols[-1] - cols[0] + 1, np.array([rows.mean(), cols.mean()])


def _compare(image, name, threshold=200.0):
    """pyvista.compare_images (mean absolute difference of edge-filtered greyscale images)."""
    import pyvista as pv

    path = REFERENCE / name
    if os.environ.get("PRIMKIT_UPDATE_REFERENCE_IMAGES"):
        from PIL import Image

        REFERENCE.mkdir(exist_ok=True)
        Image.fromarray(image).save(path)
    if not path.exists():
        pytest.fail(f"{path} missing: run with PRIMKIT_UPDATE_REFERENCE_IMAGES=1 once and check the picture")
    ref = pv.read(path)
    new = pv.ImageData(dimensions=(image.shape[1], image.shape[0], 1))
    new.point_data["rgb"] = np.ascontiguousarray(image[::-1]).reshape(-1, 3)  # VTK images start at the bottom row
    error = pv.compare_images(ref, new)
    assert error < threshold, f"{name}: image error {error:.1f} >= {threshold} against the reference"


def test_cube_projects_to_the_closed_form_size():
    half = 0.25
    img = render.render_tiles([render.Tile("", [render.cuboid_layer(_box(half=half), edges=False)])], tile=TILE)
    h, w, centre = _extent(_silhouette(img))
    _, up, right = CAMERA.basis()
    scale = half * np.sqrt(3) * (1 + CAMERA.margin)  # radius of the framed sphere, plus margin
    # an axis-aligned cube's shadow along a unit screen axis a spans 2 h (|a_x| + |a_y| + |a_z|)
    want_h = 2 * half * np.abs(up).sum() / (2 * scale) * TILE
    want_w = 2 * half * np.abs(right).sum() / (2 * scale) * TILE
    assert abs(h - want_h) <= 2 and abs(w - want_w) <= 2, (h, want_h, w, want_w)
    assert np.allclose(centre, (TILE - 1) / 2, atol=2)


def test_collection_tiles_line_up():
    """A moved shape is drawn the same; a shape half as large is drawn half as large."""
    tiles = [render.Tile("", [render.cuboid_layer(_box())]),
             render.Tile("", [render.cuboid_layer(_box(center=(3.0, -1.0, 2.0)))]),
             render.Tile("", [render.cuboid_layer(_box(half=0.125))])]
    img = render.render_tiles(tiles, tile=TILE, columns=3)
    a, b, c = (img[:, i * TILE:(i + 1) * TILE] for i in range(3))
    assert np.abs(a.astype(int) - b.astype(int)).max() <= 8
    ha, wa, ca = _extent(_silhouette(a))
    hc, wc, cc = _extent(_silhouette(c))
    assert abs(hc - ha / 2) <= 2 and abs(wc - wa / 2) <= 2
    assert np.allclose(ca, cc, atol=2)


def test_thumbnail_renderer_matches_grid_and_is_reusable(tmp_path):
    tile = render.Tile("", [render.cuboid_layer(_box(center=(0.1, 0.2, 0.0)))])
    other = render.Tile("", [render.cuboid_layer(_box(half=0.4))])
    grid = render.render_tiles([tile], tile=TILE)
    with render.ThumbnailRenderer(size=TILE) as thumbs:
        first = thumbs.render(tile)
        thumbs.render(other)  # the previous shape's actors must be gone
        again = thumbs.render(tile, path=tmp_path / "t.png")
    assert np.abs(first.astype(int) - grid.astype(int)).max() <= 8
    assert np.array_equal(first, again)
    from PIL import Image

    written = np.asarray(Image.open(tmp_path / "t.png"))
    assert np.array_equal(written, again[..., : written.shape[-1]])  # the file holds the picture rendered


def test_write_png_keeps_existing_files(tmp_path):
    tile = render.Tile("x", [render.cuboid_layer(_box())])
    path = render.write_png(tmp_path / "a.png", [tile], tile=64)
    with pytest.raises(FileExistsError):
        render.write_png(path, [tile], tile=64)
    render.write_png(path, [tile], tile=64, overwrite=True)


def test_segmentation_layer_uses_part_colours():
    from primkit.viz.palette import part_colors

    layer = render.segmentation_layer(np.eye(3), [[0, 1, 2], [0, 2, 1]], [3, -1], count=5)
    assert np.array_equal(layer.face_colors[0], part_colors(5)[3])
    assert np.array_equal(layer.face_colors[1], [200, 200, 200])


def test_reference_image_of_a_chair_and_its_parts(chairs):
    """The convention's picture of a procedural chair, its segmentation colours and cuboids."""
    s = chairs[0]
    names = np.array(s.part_names)
    boxes = Cuboids([[0.2, 0.03, 0.2], [0.2, 0.2, 0.02]], [[1.0, 0, 0, 0]] * 2,
                       [[0.0, 0.0, 0.0], [0.0, 0.2, -0.2]], [True, True])
    tiles = [render.Tile("", [render.mesh_layer(s.vertices, s.faces)]),
             render.Tile("", [render.segmentation_layer(s.vertices, s.faces, s.face_labels, count=len(names))]),
             render.Tile("", [render.cuboid_layer(boxes)])]
    img = render.render_tiles(tiles, tile=128, columns=3)
    _compare(img, "chair_tiles.png")


def test_render_abstractions_for_its_callers(tmp_path, prepared_chairs, chairs):
    from primkit.model.abstractor import Abstractor

    results = Abstractor.load("chair").predict(prepared_chairs[:2])
    path = tmp_path / "pairs.png"
    render.render_abstractions(results, [(c.vertices, c.faces) for c in chairs[:2]], path, tile=100)
    render.render_abstractions(results, [(c.vertices, c.faces) for c in chairs[:2]], path, tile=100, canonical=True)
    from PIL import Image

    assert Image.open(path).size == (400, 100)
    from pictures import read_picture

    picture = read_picture(path)  # shape, cuboids, shape, cuboids: 100 px tiles
    assert all(picture.crop(x, x + 100).foreground_fraction > 0.02 for x in range(0, 400, 100))
    present = set(np.flatnonzero(results[0].canonical.existence)) | set(np.flatnonzero(results[1].canonical.existence))
    shown = picture.part_colours_shown(present, min_pixels=1)
    assert sum(n >= 10 for n in shown.values()) >= len(shown) // 2, shown  # small parts may hide behind others
