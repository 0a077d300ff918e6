"""``segment --semantic --png`` colours every element by its name (the label palette,
:func:`primkit.viz.palette.label_colors`) with a legend of the names under the tiles; without
``--semantic`` by part index as before. Checked on procedural chairs (two meshes and a voxel grid)
against the labels the same run wrote (``.seg``, ``.voxlabels.npy``, ``labels.csv``)."""

from __future__ import annotations

import numpy as np
import pytest

from primkit import data, io, synthetic
from primkit.cli import main
from primkit.viz.palette import label_colors

TILE = 260


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    """Two procedural chairs (one with arms) and a third's prepared grid, segmented with --semantic --png."""
    folder = tmp_path_factory.mktemp("semantic-png")
    shapes = folder / "shapes"
    shapes.mkdir()
    chairs = synthetic.generate("chair", 3, seed=5)
    for i, c in enumerate(chairs[:2]):
        io.write_mesh(shapes / f"chair{i}.ply", c.vertices, c.faces)
    grid = data.prepare(io.Mesh(chairs[2].vertices, chairs[2].faces), name="grid").occupancy
    io.write_voxels(shapes / "grid.binvox", io.VoxelGrid(grid, translate=np.full(3, -0.5), scale=1.0))
    out, png = folder / "out", folder / "seg.png"
    assert main(["segment", str(shapes), "--model", "chair", "--semantic", "-o", str(out), "--png", str(png),
                 "--workers", "1"]) == 0
    return out, png


def test_the_legend_holds_each_name_in_its_colour(run):
    from pictures import read_picture

    out, png = run
    names = [line.split(",", 1)[1] for line in (out / "labels.csv").read_text().splitlines()[1:]]
    assert names == ["back", "seat", "legs", "arms"]  # the bundled chair labeller's
    pic = read_picture(png)
    assert pic.size[1] > TILE  # a strip under the row of tiles
    strip = pic.rgb[TILE:]
    colours = label_colors(len(names))
    for colour in colours:  # the swatches: the palette's colours exactly (no shading)
        assert np.all(strip == colour, axis=-1).sum() >= 100, colour


def test_each_tile_shows_the_names_the_run_wrote(run):
    """Per shape: every name holding at least 5% of its faces (voxels) shows in its colour, and a name
    it never gives does not show at all."""
    from pictures import read_picture

    out, png = run
    pic = read_picture(png)
    colours = label_colors(4)
    order = sorted(["chair0", "chair1", "grid"])  # the run's order: the folder's files, sorted
    for i, name in enumerate(order):
        codes = np.loadtxt(out / f"{name}.seg", dtype=int) if name != "grid" else np.load(out / "grid.voxlabels.npy")
        codes = codes[codes > 0]
        share = np.bincount(codes - 1, minlength=4) / len(codes)
        tile = pic.crop((2 * i + 1) * TILE, (2 * i + 2) * TILE)  # the segmented one, right of the plain one
        tile = type(tile)(tile.rgb[:TILE], tile.background, tile.foreground[:TILE])
        shown = [tile.colour_pixels(c) for c in colours]
        assert shown[0] + shown[1] + shown[2] > 0.3 * tile.foreground.sum(), (name, shown)
        for j in range(4):
            if share[j] >= 0.05:
                assert shown[j] > 30, (name, j, share, shown)
            elif share[j] == 0:
                assert shown[j] == 0, (name, j, share, shown)
