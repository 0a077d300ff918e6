"""Labelling by hand in ``primkit view abstraction --label-to``: the viewer built off screen, its
handlers called as clicks and key presses call them, the files it saves read back by
``name-parts`` (library and CLI); the procedural chair's own face labels are the independent check."""

import json
import numpy as np
import pytest

from primkit import synthetic
from primkit.cli import main
from primkit.model.abstraction import abstract_shapes
from primkit.model.modelfile import read_metadata
from primkit.segmentation.evaluation import read_ground_truth
from primkit.viewers import common
from primkit.viewers.abstraction_viewer import abstraction_viewer


@pytest.fixture(scope="module")
def chair(tmp_path_factory):
    folder = tmp_path_factory.mktemp("hand")
    path = synthetic.write_collection(folder / "chairs", "chair", 1, seed=3, rates={"has_arms": 0.0})[0]
    out = abstract_shapes([path], "chair")
    a = common.drawable(out[0])
    truth = read_ground_truth(path.with_suffix(".seg"), len(a.faces))  # seat / back / legs per face
    groups = np.array(truth.names)[truth.labels]
    return folder, path, a, out.model, groups


def _majority(groups, parts, k):
    g, c = np.unique(groups[parts == k], return_counts=True)
    return str(g[np.argmax(c)])


#: the names typed: not the procedural chair's own (seat, back, legs), so that what name-parts
#: learns can only come from the hand-written files
WORDS = {"seat": "Sitz", "back": "Lehne", "legs": "Beine"}


def _label_by_clicks(viewer, a, groups):
    """Click each cuboid (the others hidden, so the click cannot miss it), type the name (in
    German) most of its faces carry on the procedural chair, Enter; Ctrl+S. Returns {part: name}."""
    ctl = viewer.labelling
    present = list(viewer.part_actors)
    viewer.plotter.render()
    given = {}
    for k in present:
        if not (ctl.labels.parts == k).any():
            continue
        for j in present:
            viewer.toggle_part(j, j == k)
        x, y = common.display_position(viewer.plotter, a.cuboids.translations[k])
        assert viewer.pick_at(x, y) == k
        given[k] = WORDS[_majority(groups, ctl.labels.parts, k)]
        for ch in given[k]:
            ctl.key(ch, ch)
        assert ctl.typed == given[k] and f"name: {given[k]}_" in ctl.text
        ctl.key("Return")
    for j in present:
        viewer.toggle_part(j, True)
    ctl.key("s", "\x13", ctrl=True)
    assert ctl.saved, ctl.message
    return given


@pytest.mark.slow
def test_label_by_clicking_cuboids_then_name_parts(chair, tmp_path):
    folder, path, a, model, groups = chair
    hand = tmp_path / "hand"
    viewer = abstraction_viewer(a.vertices, a.faces, a.cuboids, model.part_names, off_screen=True,
                                window_size=(640, 480), label_to=hand / f"{path.stem}.seg", source=path)
    ctl = viewer.labelling
    given = _label_by_clicks(viewer, a, groups)
    assert set(given.values()) == set(WORDS.values())
    # the file: each face the name of its cuboid, codes in the order the names were first typed
    order = list(dict.fromkeys(given.values()))
    doc = json.loads((hand / f"{path.stem}.names.json").read_text())
    assert doc["names"] == {str(i + 1): n for i, n in enumerate(order)}
    written = np.loadtxt(hand / f"{path.stem}.seg", dtype=int)
    want = np.array([order.index(given[k]) + 1 if k in given else 0 for k in ctl.labels.parts])
    np.testing.assert_array_equal(written, want)
    # and how much of the chair the clicks got right, against its own labels (a sanity floor)
    named = np.array(["-"] + order)[written]
    assert (named == np.array([WORDS[g] for g in groups])).mean() > 0.8

    # undo takes back one step; a second save replaces its own file
    ctl.key("z", "\x1a", ctrl=True)
    assert (ctl.labels.codes == 0).sum() == (ctl.labels.parts == list(given)[-1]).sum()
    ctl.key("s", "\x13", ctrl=True)
    assert ctl.saved and "saved" in ctl.message
    ctl.key("Return")  # the last name again, on the last cuboid clicked
    ctl.save()
    k = viewer.selected
    ctl.type_text("-")
    ctl.key("Return")  # the eraser
    assert not ctl.labels.codes[ctl.labels.parts == k].any() and ctl.labels.codes.any()
    ctl.key("z", "\x1a", ctrl=True)
    ctl.save()

    # name-parts, the library way: the segmenter's part of each face, the hand labels by name
    from primkit.model.parts import names_from_labels
    from primkit.segmentation import Segmenter
    from primkit.segmentation.evaluation import labelled_shapes

    seg = Segmenter("chair", labeller=None)
    results, errors = seg.abstract_files([path])
    segs, errors = seg.segment_results(results, errors=errors)
    shapes = labelled_shapes(segs, results, hand)
    assert not errors and not shapes.errors and sorted(shapes.names) == sorted(order)
    names, _ = names_from_labels(shapes.assignments, shapes.labels, shapes.weights, shapes.names, model.parts)
    parts = segs[0].face_labels
    for k in np.unique(parts[parts >= 0]):  # independent: the procedural labels' majority per index
        assert names[k] == WORDS[_majority(groups, parts, k)], k

    # name-parts, the command: the names and a labeller learned from the hand-labelled chair
    out = tmp_path / "named.safetensors"
    assert main(["name-parts", str(path), "--model", "chair", "--labels", str(hand), "-o", str(out), "-q"]) == 0
    meta = read_metadata(out)
    assert meta["part_names"] == names
    assert sorted(meta["part_naming"]["labels"]) == sorted(order)


def test_view_abstraction_label_to_cli(chair, tmp_path, capsys):
    folder, path, a, model, groups = chair
    label = tmp_path / "lab" / f"{path.stem}.seg"
    png = tmp_path / "view.png"
    args = ["view", "abstraction", str(path), "--model", "chair", "--size", "480x360"]
    assert main(args + ["--label-to", str(label), "--png", str(png)]) == 0 and png.stat().st_size > 0
    assert not label.exists()  # a picture saves nothing
    assert main(args + ["--label-to", str(tmp_path / "x.labels.npy"), "--png", str(png), "--force"]) == 2
    assert "<stem>.seg" in capsys.readouterr().err
    label.parent.mkdir()
    label.write_text("1\n")
    assert main(args + ["--label-to", str(label), "--png", str(tmp_path / "v2.png")]) != 0  # never over a file
    assert "exists" in capsys.readouterr().err and label.read_text() == "1\n"
    # starting from a label file that does not fit the mesh: one line naming it
    assert main(args + ["--label-to", str(label), "--label-from", str(label), "--force", "--png", str(png)]) != 0
    assert f"{label}" in capsys.readouterr().err
    assert main(args + ["--label-from", str(label), "--png", str(png), "--force"]) == 2
    # starting from the bundled chair labeller's guess
    assert main(args + ["--label-to", str(tmp_path / "g.seg"), "--label-guess", "--png", str(png), "--force"]) == 0
    assert main(args + ["--label-to", str(label), "--label-guess", "--label-from", str(label), "--png", str(png),
                        "--force"]) == 2


def test_brush_paints_where_the_mouse_presses(chair):
    """Press and drag through the interactor with the brush on: the faces around the point
    under the cursor take the name; the camera does not move."""
    folder, path, a, model, groups = chair
    viewer = abstraction_viewer(a.vertices, a.faces, a.cuboids, model.part_names, off_screen=True,
                                window_size=(640, 480), label_to=folder / "unused.seg")
    ctl = viewer.labelling
    for k in viewer.part_actors:
        viewer.toggle_part(k, False)
    ctl.type_text("seat")
    ctl.key("Tab")
    ctl.key("Return")
    assert ctl.brush_on and ctl.current == "seat"
    p = viewer.plotter
    p.render()
    seat = np.flatnonzero(groups == "seat")
    centroids = ctl.labels.points
    top = centroids[seat].mean(0)
    top[1] = centroids[seat, 1].max()
    target = seat[np.argmin(np.linalg.norm(centroids[seat] - top, axis=1))]  # the middle of the seat's top
    camera = p.camera.position
    inter = p.iren.interactor
    x, y = common.display_position(p, centroids[target])
    inter.SetEventInformation(int(round(x)), int(round(y)), 0, 0, "\0", 0, None)
    inter.InvokeEvent("LeftButtonPressEvent")
    inter.SetEventInformation(int(round(x)) + 4, int(round(y)), 0, 0, "\0", 0, None)
    inter.InvokeEvent("MouseMoveEvent")
    inter.InvokeEvent("LeftButtonReleaseEvent")
    painted = np.flatnonzero(ctl.labels.codes > 0)
    assert len(painted) > 10
    assert np.all(np.linalg.norm(centroids[painted] - centroids[target], axis=1) <= ctl.radius * 1.5)
    assert (groups[painted] == "seat").mean() > 0.9
    assert np.allclose(p.camera.position, camera)
    ctl.key("Tab")
    assert not ctl.brush_on


def test_typing_a_name_runs_no_single_key_command(chair):
    """In labelling mode the window's keys type: q, e, w, s, r, v (quit, exit, wireframe, surface,
    reset camera, isometric in VTK and pyvista) only add to the name."""
    folder, path, a, model, groups = chair
    viewer = abstraction_viewer(a.vertices, a.faces, a.cuboids, model.part_names, off_screen=True,
                                window_size=(320, 240), label_to=folder / "unused.seg")
    p = viewer.plotter
    p.render()
    inter = p.iren.interactor
    camera = p.camera.position
    for ch in "qewsrv3":
        inter.SetEventInformation(5, 5, 0, 0, ch, 0, ch)
        inter.InvokeEvent("KeyPressEvent")
        inter.InvokeEvent("CharEvent")
    inter.SetEventInformation(5, 5, 0, 0, "\b", 0, "BackSpace")
    inter.InvokeEvent("KeyPressEvent")
    assert viewer.labelling.typed == "qewsrv"
    assert not p._closed and np.allclose(p.camera.position, camera)
    assert all(a.GetProperty().GetRepresentation() == 2 for a in viewer.part_actors.values())  # still surfaces
