"""The viewers in apps/: built off screen, their widgets driven as a user would (checkbox state
changes, slider moves, clicks at the display position of a cuboid), the effect checked on the scene.

One test opens a real window under Xvfb (skipped, with the reason, when xvfb-run is missing;
scripts/setup.sh installs it)."""

import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from primkit.cli.view import load_app

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def shapes(chairs, prepared_chairs):
    from primkit.abstractor import Abstractor

    common = load_app("common")
    model = Abstractor.load("chair")
    results = model.predict(prepared_chairs[:4])
    return [common.Shape(r.name, c.vertices, c.faces, r) for r, c in zip(results, chairs[:4])], model


def _click_widget(widget, state):
    """What a click on a checkbox button does: its representation changes state, then the event."""
    widget.GetRepresentation().SetState(int(state))
    widget.InvokeEvent("StateChangedEvent")


def _move_slider(widget, value):
    widget.GetRepresentation().SetValue(value)
    widget.InvokeEvent("InteractionEvent")


def test_abstraction_viewer_controls(shapes):
    av, common = load_app("abstraction_viewer"), load_app("common")
    (s, *_), model = shapes
    names = [f"name{k}" for k in range(s.cuboids.count)]
    viewer = av.abstraction_viewer(s.vertices, s.faces, s.cuboids, names, off_screen=True, window_size=(400, 300))
    p = viewer.plotter
    present = list(s.cuboids.present)
    assert sorted(viewer.part_actors) == present and sorted(viewer.checkboxes) == present
    k = present[0]
    _click_widget(viewer.checkboxes[k], False)
    assert not viewer.part_actors[k].GetVisibility()
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
    cb, common = load_app("collection_browser"), load_app("common")
    shape_list, model = shapes
    browser = cb.collection_browser(shape_list, model.part_names, columns=2, off_screen=True, window_size=(500, 400))
    p = browser.plotter
    assert browser.mode == "cuboids"
    for mode in cb.MODES:
        _click_widget(browser.buttons[mode], True)
        assert browser.mode == mode
        for m, actors in browser.actors.items():
            assert all(bool(a.GetVisibility()) == (m == mode) for a in actors)
        assert [bool(w.GetRepresentation().GetState()) for w in browser.buttons.values()] == [m == mode for m in cb.MODES]
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
    from PIL import Image

    img = np.asarray(Image.open(png).convert("RGB"))
    assert (np.abs(img.astype(int) - 255).sum(-1) > 30).mean() > 0.02  # something drawn
