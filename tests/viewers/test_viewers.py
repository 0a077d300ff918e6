"""The viewers (primkit.viewers): built off screen, their widgets driven as a user would (checkbox state
changes, slider moves, clicks at the display position of a cuboid), the effect checked on the scene.

One test opens a real window under Xvfb (skipped, with the reason, when xvfb-run is missing;
scripts/setup.sh installs it)."""

import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from primkit.viewers import abstraction_viewer as av_module
from primkit.viewers import collection_browser as cb_module
from primkit.viewers import common as common_module
from primkit.viewers import deformation_viewer as dv_module
from primkit.viewers import embedding_explorer as ee_module

ROOT = Path(__file__).resolve().parents[2]


def _click_widget(widget, state):
    """What a click on a checkbox button does: its representation changes state, then the event."""
    widget.GetRepresentation().SetState(int(state))
    widget.InvokeEvent("StateChangedEvent")


def _move_slider(widget, value):
    widget.GetRepresentation().SetValue(value)
    widget.InvokeEvent("InteractionEvent")


def test_abstraction_viewer_controls(shapes):
    av, common = av_module, common_module
    (s, *_), model = shapes
    names = [f"name{k}" for k in range(s.cuboids.count)]
    viewer = av.abstraction_viewer(s.vertices, s.faces, s.cuboids, names, off_screen=True, window_size=(400, 300))
    p = viewer.plotter
    present = list(s.cuboids.present)
    assert sorted(viewer.part_actors) == present and sorted(viewer.checkboxes) == present
    k = present[0]
    assert sorted(viewer.edge_actors) == present
    for j in present:  # each cuboid shows its 12 edges, not its triangles' diagonals
        assert viewer.edge_actors[j].GetMapper().GetInput().GetNumberOfLines() == 12
    _click_widget(viewer.checkboxes[k], False)
    assert not viewer.part_actors[k].GetVisibility() and not viewer.edge_actors[k].GetVisibility()
    assert all(viewer.part_actors[j].GetVisibility() for j in present[1:])
    _click_widget(viewer.checkboxes[k], True)
    assert viewer.part_actors[k].GetVisibility()
    _click_widget(viewer.mesh_checkbox, False)
    assert not viewer.mesh_actor.GetVisibility()
    _move_slider(viewer.slider, 0.3)
    assert all(np.isclose(a.GetProperty().GetOpacity(), 0.3) for a in viewer.part_actors.values())
    p.render()

    # click each part at the display position of its centre, the others hidden: that part is picked
    for k in present:
        for j in present:
            viewer.toggle_part(j, j == k)
        x, y = common.display_position(p, s.cuboids.translations[k])
        assert viewer.pick_at(x, y) == k
        text = viewer.info
        assert f"part {k}: name{k}" in text
        assert "size " + " x ".join(f"{2 * z:.3f}" for z in s.cuboids.half_extents[k]) in text
        assert viewer.outline_actor is not None
    # a click on the background clears the selection
    assert viewer.pick_at(1, 1) is None and viewer.info == "click a cuboid"
    # hiding the selected part clears it too
    viewer.toggle_part(present[0], True)
    viewer.select(present[0])
    viewer.toggle_part(present[0], False)
    assert viewer.selected is None
    p.close()


def test_collection_browser_modes_and_picking(shapes):
    cb, common = cb_module, common_module
    shape_list, model = shapes
    browser = cb.collection_browser(shape_list, model.part_names, columns=2, off_screen=True, window_size=(500, 400))
    p = browser.plotter
    assert browser.mode == "cuboids"
    assert list(browser.buttons) == ["mesh", "cuboids", "segmentation"]  # no names without a labeller
    for mode in browser.buttons:
        _click_widget(browser.buttons[mode], True)
        assert browser.mode == mode
        for m, actors in browser.actors.items():
            assert all(bool(a.GetVisibility()) == (m == mode) for a in actors)
        assert len(browser.edge_actors) == len(shape_list)
        assert all(bool(a.GetVisibility()) == (mode == "cuboids") for a in browser.edge_actors)
        assert [bool(w.GetRepresentation().GetState()) for w in browser.buttons.values()] == [m == mode for m in browser.buttons]
    # unchecking the current mode's button keeps the mode (radio buttons)
    _click_widget(browser.buttons["segmentation"], False)
    assert browser.mode == "segmentation" and browser.buttons["segmentation"].GetRepresentation().GetState() == 1
    # same part index, same colour on every shape
    first = browser.actors["cuboids"][0].GetMapper().GetInput()
    for a in browser.actors["cuboids"]:
        poly = a.GetMapper().GetInput()
        from vtk.util.numpy_support import vtk_to_numpy

        part = vtk_to_numpy(poly.GetCellData().GetArray("part"))
        rgb = vtk_to_numpy(poly.GetCellData().GetArray("rgb"))
        ref_part = vtk_to_numpy(first.GetCellData().GetArray("part"))
        ref_rgb = vtk_to_numpy(first.GetCellData().GetArray("rgb"))
        for k in set(part) & set(ref_part):
            assert np.all(rgb[part == k] == ref_rgb[ref_part == k][0])
    p.render()
    for i in range(len(shape_list)):
        x, y = common.display_position(p, browser.offsets[i])
        assert browser.pick_at(x, y) == i
        assert browser.info.startswith(f"{shape_list[i].name}:")
    # the grid lines up: every shape's centre is the same distance from the previous one on screen
    xy = np.array([common.display_position(p, o) for o in browser.offsets])
    assert np.isclose(xy[1, 0] - xy[0, 0], xy[3, 0] - xy[2, 0], atol=1e-6) and np.isclose(xy[0, 1], xy[1, 1], atol=1e-6)
    p.close()


@pytest.mark.integration  # a window under Xvfb, in a subprocess
@pytest.mark.skipif(shutil.which("xvfb-run") is None, reason="xvfb-run not installed (scripts/setup.sh installs xvfb)")
def test_viewer_opens_a_real_window_under_xvfb(tmp_path):
    """``primkit view abstraction`` in a real X window, closed after its first frame."""
    from primkit import synthetic

    synthetic.write_collection(tmp_path / "in", "chair", 1, seed=4)
    shape = sorted((tmp_path / "in").glob("*.ply"))[0]
    png = tmp_path / "window.png"
    code = ("import sys; from primkit.cli import main; "
            f"sys.exit(main(['view', 'abstraction', '{shape}', '--model', 'chair', '--png', '{png}', '--window']))")
    env = {k: v for k, v in __import__("os").environ.items() if k != "VTK_DEFAULT_OPENGL_WINDOW"}
    out = subprocess.run(["xvfb-run", "-a", "-s", "-screen 0 1280x1024x24", sys.executable, "-c", code],
                         capture_output=True, text=True, timeout=240, env=env, cwd=ROOT)
    assert out.returncode == 0, out.stderr[-2000:]
    assert "X display" in out.stdout or "window" in out.stdout
    from pictures import read_picture

    # the chair's seat and back cuboids drawn in their part colours (indices 16 and 18; measured
    # off screen on this chair: 2,061 and 827 pixels of 1280 x 900)
    shown = read_picture(png).part_colours_shown({16, 18})
    assert min(shown.values()) > 300, shown


def test_embedding_explorer_click_shows_nearest_neighbours(shapes, chairs, prepared_chairs):
    ee, common = ee_module, common_module
    from primkit import embedding

    shape_list, model = shapes
    coords = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0], [1.0, 1.0]])  # a fixed map: no t-SNE needed here
    explorer = ee.embedding_explorer(shape_list, model.part_names, neighbors=2, coords=coords, off_screen=True,
                                     window_size=(500, 400))
    p = explorer.plotter
    p.render()
    X = embedding.PartDescriptor(part_names=model.part_names).fit_transform([s.result for s in shape_list])
    D = embedding.descriptor_distances(X)
    for i in range(len(shape_list)):
        x, y = common.display_position(p, explorer.positions[i])
        assert explorer.pick_at(x, y) == i
        # neighbours: brute force over the distance matrix, self excluded
        want = [j for j in np.argsort(D[i], kind="stable") if j != i][:2]
        assert sorted(explorer.neighbors.indices[i]) == sorted(want)
        colours = [tuple(np.round(a.GetProperty().GetColor(), 3)) for a in explorer.map_actors]
        assert colours[i] == tuple(np.round(ee._rgb(ee.ORANGE), 3))
        assert all(colours[j] == tuple(np.round(ee._rgb(ee.BLUE), 3)) for j in want)
        assert explorer.info.startswith(f"{shape_list[i].name}: nearest")
        assert len(explorer.row_actors) == 2 * 3  # the chosen shape and 2 neighbours, each with a label
    p.close()


def test_deformation_viewer_blend_and_part_edit(shapes):
    dv, common = dv_module, common_module
    from primkit import deformation

    (a, b, *_), model = shapes
    viewer = dv.deformation_viewer(a, b, model.part_names, off_screen=True, window_size=(600, 400))
    rest = viewer.binding.vertices
    _move_slider(viewer.sliders["blend"], 0.0)
    assert np.allclose(viewer.result_poly.points - viewer.offset, rest, atol=1e-12)
    _move_slider(viewer.sliders["blend"], 1.0)
    full = np.asarray(viewer.result_poly.points) - viewer.offset
    # at 1 the result is primkit.deformation.deform with the same binding
    want = deformation.deform(rest, a.result.canonical, b.result.canonical, falloff=viewer.binding.falloff,
                              faces=a.faces).vertices
    assert np.allclose(full, want, atol=1e-9)
    _move_slider(viewer.sliders["blend"], 0.5)
    half = np.asarray(viewer.result_poly.points) - viewer.offset
    assert np.allclose(half - rest, 0.5 * (full - rest), atol=1e-9)  # displacement linear in the blend
    # edit: raising the chosen part at blend 0 moves its vertices up by that much
    _move_slider(viewer.sliders["blend"], 0.0)
    k = viewer.part
    _move_slider(viewer.sliders["raise"], 0.1)
    moved = np.asarray(viewer.result_poly.points) - viewer.offset
    e = deformation.edit(rest, a.result.canonical, move={k: (0.0, 0.1, 0.0)}, falloff=viewer.binding.falloff)
    assert np.allclose(moved, e.vertices, atol=1e-9) and not np.allclose(moved, rest)
    assert "raise 0.10" in viewer.info
    # clicking another source cuboid chooses it and resets the edit
    p = viewer.plotter
    p.render()
    other = next(j for j in viewer.source_actors if j != k)
    for j, actor in viewer.source_actors.items():
        actor.SetVisibility(j == other)
    x, y = common.display_position(p, a.result.canonical.translations[other] + viewer.offset - 2 * viewer.offset)
    assert viewer.pick_at(x, y) == other and viewer.part == other
    assert np.allclose(np.asarray(viewer.result_poly.points) - viewer.offset, rest, atol=1e-12)
    p.close()
