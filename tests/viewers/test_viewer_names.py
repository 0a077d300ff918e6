"""The viewers colour by the model's labeller's names when asked: the abstraction viewer's *by name*
checkbox, the collection browser's ``names`` mode, the Open3D viewer's ``colour by name``, and the
embedding explorer's ``parts`` by label. Built off screen on procedural chairs with the bundled chair
model's labeller; each drawn colour checked against the label palette of
:func:`primkit.segmentation.labeller.label_elements` called directly."""

from __future__ import annotations

import numpy as np
import pytest

from primkit import io
from primkit.model.bundled import resolve_model
from primkit.segmentation import labeller as lab
from primkit.viz.palette import UNLABELLED, label_colors

NAMES = ["back", "seat", "legs", "arms"]


@pytest.fixture(scope="module")
def labeller():
    return lab.read_labeller(resolve_model("chair"))


def _named(labeller, s):
    """Each face's label, the labeller called directly (the shape in its own frame)."""
    return lab.label_elements(labeller, lab.mesh_elements(s.vertices, s.faces, s.result.frame), s.result.canonical)


def _cell_rgb(actor):
    from vtk.util.numpy_support import vtk_to_numpy

    return vtk_to_numpy(actor.GetMapper().GetInput().GetCellData().GetArray("rgb"))


def test_abstraction_viewer_colours_by_name(shapes, labeller):
    from primkit.viewers import abstraction_viewer as av
    from primkit.viewers.common import part_labels

    (s, *_), model = shapes
    want = _named(labeller, s)
    viewer = av.abstraction_viewer(s.vertices, s.faces, s.cuboids, model.part_names, off_screen=True,
                                   window_size=(640, 480), named=(want, NAMES), by_name=True)
    table = np.vstack([label_colors(4), UNLABELLED])
    assert np.array_equal(_cell_rgb(viewer.names_actor), table[want])
    assert viewer.names_actor.GetVisibility() and not viewer.mesh_actor.GetVisibility()
    assert viewer.legend == [n for j, n in enumerate(NAMES) if (want == j).any()]
    # each cuboid is called by the name most of its faces get (counted here by hand)
    index = part_labels(s.vertices, s.faces, s.cuboids)
    for k in s.cuboids.present:
        counts = np.bincount(want[(index == k) & (want >= 0)], minlength=4)
        assert viewer.names[k] == (NAMES[int(np.argmax(counts))] if counts.any() else model.part_names[k])
    # the picture shows each name holding 5% of the faces in its colour
    for k in viewer.part_actors:
        viewer.toggle_part(k, False)
    picture = read_picture_of(viewer.plotter)
    for j in range(4):
        if np.mean(want == j) >= 0.05:
            assert picture.colour_pixels(label_colors(4)[j]) > 50, NAMES[j]
    # the checkbox turns it off (grey, no legend) and on again; the mesh checkbox hides either
    _click(viewer.names_checkbox, False)
    assert not viewer.names_actor.GetVisibility() and viewer.mesh_actor.GetVisibility() and viewer.legend == []
    _click(viewer.names_checkbox, True)
    _click(viewer.mesh_checkbox, False)
    assert not viewer.names_actor.GetVisibility() and not viewer.mesh_actor.GetVisibility()
    viewer.plotter.close()
    plain = av.abstraction_viewer(s.vertices, s.faces, s.cuboids, model.part_names, off_screen=True,
                                  window_size=(320, 240))
    assert plain.names_actor is None and plain.names == list(model.part_names)
    with pytest.raises(ValueError, match="no labeller"):
        plain.colour_by_name(True)
    plain.plotter.close()


def read_picture_of(plotter):
    import tempfile
    from pathlib import Path

    from pictures import read_picture

    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "shot.png"
        plotter.render()
        plotter.screenshot(str(path))
        return read_picture(path)


def _click(widget, state):
    widget.GetRepresentation().SetState(int(state))
    widget.InvokeEvent("StateChangedEvent")


def test_collection_browser_names_mode(shapes, labeller):
    from primkit.viewers import collection_browser as cb

    shape_list, model = shapes
    browser = cb.collection_browser(shape_list, model.part_names, columns=2, off_screen=True, window_size=(500, 400),
                                    mode="names", labeller=labeller)
    assert list(browser.buttons) == list(cb.MODES) and browser.mode == "names"
    table = np.vstack([label_colors(4), UNLABELLED])
    every = []
    for s, actor in zip(shape_list, browser.actors["names"]):
        want = _named(labeller, s)
        every.append(want)
        assert np.array_equal(_cell_rgb(actor), table[want]) and actor.GetVisibility()
    present = set(np.concatenate(every).tolist()) - {-1}
    assert browser.legend == [NAMES[j] for j in sorted(present)]
    browser.select(0)
    assert "names: back" in browser.info
    _click(browser.buttons["cuboids"], True)
    assert browser.mode == "cuboids" and browser.legend == [] and not browser.actors["names"][0].GetVisibility()
    browser.plotter.close()
    plain = cb.collection_browser(shape_list[:2], model.part_names, off_screen=True, window_size=(300, 200))
    with pytest.raises(ValueError, match="labeller"):
        plain.set_mode("names")
    plain.plotter.close()


def test_open3d_viewer_colours_by_name(chairs, labeller, tmp_path, recording_window):
    pytest.importorskip("open3d")
    from primkit.model.abstraction import abstract
    from primkit.viewers.open3d_viewer import open3d_viewer

    c = chairs[5]
    viewer = open3d_viewer((c.vertices, c.faces), "chair", name="c", names=True)
    a = abstract((c.vertices, c.faces), "chair")
    want = lab.label_elements(labeller, lab.mesh_elements(c.vertices, c.faces, a.result.frame), a.result.canonical)
    surfaces = [g for g in viewer.geometries() if g["group"] == "surface"]
    assert [g["name"] for g in surfaces] == [f"label {j} {NAMES[j]}" for j in sorted(set(want.tolist()) - {-1})]
    for g in surfaces:
        j = int(g["name"].split()[1])
        assert len(g["geometry"].triangle.indices) == int((want == j).sum())
        assert np.allclose(np.asarray(g["material"].base_color)[:3] * 255, label_colors(4)[j])
    assert "colour by name" in [label for label, _ in viewer.actions()]

    w = recording_window()
    assert viewer.toggle_names(w) is False  # now by part
    assert all(n.startswith(("surface", "cuboids")) for n in w.added)
    assert set(w.removed) >= {g["name"] for g in surfaces}
    viewer.toggle_names(w)
    image = viewer._with_legend(np.full((100, 300, 3), 255, np.uint8))
    assert image.shape[0] > 100 and np.all(image[100:] == label_colors(4)[0], axis=-1).sum() > 50  # back's swatch


def test_embedding_explorer_parts_by_label(shapes, labeller):
    from primkit import embedding
    from primkit.segmentation.bylabel import labelled_voxels
    from primkit.viewers import embedding_explorer as ee

    shape_list, model = shapes
    coords = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0], [1.0, 1.0]])
    explorer = ee.embedding_explorer(shape_list, model.part_names, parts="arms,back", neighbors=2, coords=coords,
                                     off_screen=True, window_size=(500, 400), labeller=labeller)
    # the regions of each shape's voxels named arms and back, their grids built here from labelled_voxels
    grids, grid_labels = [], []
    for s in shape_list:
        occupancy = s.canonical_shape().occupancy
        p, named = labelled_voxels(labeller, occupancy, s.result.canonical)
        cells = np.rint((p + 0.5) * occupancy.shape[0] - 0.5).astype(int)
        lab = np.full(occupancy.shape, -1)
        lab[tuple(cells.T)] = named
        grids.append(occupancy)
        grid_labels.append(lab)
    table = embedding.RegionTable.from_grids(grids, grid_labels, labeller.names)
    X = embedding.RegionDescriptor("arms,back").fit_transform(table)
    D = np.linalg.norm(X[:, None] - X[None], axis=-1)
    np.fill_diagonal(D, np.inf)
    for i in range(len(shape_list)):
        assert sorted(explorer.neighbors.indices[i]) == sorted(np.argsort(D[i], kind="stable")[:2])
        assert np.allclose(explorer.neighbors.distances[i], np.sort(D[i])[:2])  # index-based ones differ
    explorer.plotter.close()


def test_view_semantic_through_the_cli(chairs, tmp_path, capsys):
    """``view abstraction --semantic`` and ``view collection --mode names`` draw the label palette's
    colours; a model without a labeller is refused in one line."""
    from pictures import read_picture

    from primkit.cli import main
    from primkit.model.modelfile import load_model_file, save_model

    paths = []
    for i, c in enumerate(chairs[:2]):
        paths.append(tmp_path / f"chair{i}.ply")
        io.write_mesh(paths[-1], c.vertices, c.faces)
    assert main(["view", "abstraction", str(paths[1]), "--model", "chair", "--semantic", "--png",
                 str(tmp_path / "a.png"), "--size", "640x480"]) == 0
    assert main(["view", "collection", *map(str, paths), "--model", "chair", "--mode", "names", "--png",
                 str(tmp_path / "c.png"), "--size", "640x480"]) == 0
    for png in ("a.png", "c.png"):
        shown = [read_picture(tmp_path / png).colour_pixels(c) for c in label_colors(4)[:3]]
        assert min(shown) > 100, (png, shown)  # back, seat and legs
    weights, meta = load_model_file(resolve_model("chair"))
    plain = save_model(tmp_path / "plain.safetensors",
                       {k: v for k, v in weights.items() if not k.startswith(lab.LABELLER_PREFIX)},
                       {k: v for k, v in meta.items() if k not in (lab.LABELLER_KEY, "created")})
    capsys.readouterr()
    assert main(["view", "abstraction", str(paths[0]), "--model", str(plain), "--semantic", "--png",
                 str(tmp_path / "b.png")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "has no labeller" in err[0] and not (tmp_path / "b.png").exists()


def test_names_typed_by_hand_keep_the_models_colours(shapes, labeller, tmp_path):
    """In labelling mode a name the model's labeller knows (``legs``) is drawn in its colour
    everywhere (label_colors' third), whatever order the names were typed in; a new name takes the
    colour after the model's."""
    from primkit.viewers import abstraction_viewer as av
    from primkit.viewers.common import part_labels
    from primkit.viz.palette import name_colors

    (s, *_), model = shapes
    want = _named(labeller, s)
    viewer = av.abstraction_viewer(s.vertices, s.faces, s.cuboids, model.part_names, off_screen=True,
                                   window_size=(400, 300), label_to=tmp_path / "c.seg", named=(want, NAMES))
    ctl = viewer.labelling
    index = part_labels(s.vertices, s.faces, s.cuboids)
    first, second = [int(k) for k in s.cuboids.present[:2]]
    for k, name in ((first, "foot"), (second, "legs")):  # a new name first, then one the model knows
        viewer.select(k)
        ctl.type_text(name)
        ctl.enter()
    colours = ctl.colors()
    assert np.all(colours[index == second] == label_colors(4)[2])  # legs, as the model draws legs
    assert np.all(colours[index == first] == label_colors(5)[4])  # foot: the colour after the model's four
    assert np.array_equal(name_colors(["foot", "legs", "back"], NAMES), label_colors(5)[[4, 2, 0]])
    viewer.plotter.close()
