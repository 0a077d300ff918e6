"""Run a documented code block with every pyvista picture it draws captured off screen, each beside
the picture primkit's colours give the same meshes: ``python doc_pictures.py BLOCK.py OUT``.

Every ``pyvista.Plotter`` the block makes (``dataset.plot()`` makes one too) is off screen at
400 x 400. When the block shows it, or when the block ends for one it never shows, the harness
saves ``OUT/<n>.npz`` with ``doc`` (the block's picture, its scalar bars removed: their text is no
part colour), ``ref`` (the same meshes, in the same window and camera, drawn with
``scalars="part_rgb", rgb=True``), ``line`` (the block's line that drew it: ``plot(`` or
``add_mesh(``) and the block's source line text.
"""

from __future__ import annotations

import os
import sys
import traceback
from pathlib import Path

import numpy as np

os.environ.setdefault("VTK_DEFAULT_OPENGL_WINDOW", "vtkEGLRenderWindow")
import pyvista as pv  # noqa: E402

SIZE = (400, 400)
BLOCK = "<documented block>"
_plotters: list = []  # (plotter, [(mesh, line)], captured)


def _line() -> int:
    """The block's line running now (the innermost frame of the block)."""
    lines = [f.lineno for f in traceback.extract_stack() if f.filename == BLOCK]
    return lines[-1] if lines else -1


def _entry(plotter):
    for e in _plotters:
        if e[0] is plotter:
            return e
    e = [plotter, [], False]
    _plotters.append(e)
    return e


_init, _add_mesh, _show = pv.Plotter.__init__, pv.Plotter.add_mesh, pv.Plotter.show


def _patched_init(self, *args, **kwargs):
    kwargs["off_screen"] = True
    kwargs["window_size"] = list(SIZE)
    _init(self, *args, **kwargs)
    _entry(self)


def _patched_add_mesh(self, mesh, *args, **kwargs):
    _entry(self)[1].append((mesh, _line()))
    return _add_mesh(self, mesh, *args, **kwargs)


def _capture(entry, out: Path) -> None:
    plotter, meshes, done = entry
    if done or not meshes:
        return
    entry[2] = True
    for title in list(plotter.scalar_bars.keys()):
        plotter.remove_scalar_bar(title)
    plotter.render()
    doc = plotter.screenshot(return_img=True)
    camera = plotter.camera_position
    ref = pv.Plotter(off_screen=True, window_size=list(SIZE))
    for mesh, _ in meshes:
        _add_mesh(ref, mesh, scalars="part_rgb", rgb=True)
    ref.camera_position = camera
    ref.render()
    reference = ref.screenshot(return_img=True)
    ref.close()
    line = meshes[-1][1]
    source = SOURCE[line - 1] if 0 < line <= len(SOURCE) else ""
    n = len(list(out.glob("*.npz")))
    np.savez(out / f"{n}.npz", doc=doc, ref=reference, line=line, source=source)


def _patched_show(self, *args, **kwargs):
    _capture(_entry(self), OUT)
    self.close()


if __name__ == "__main__":
    block, OUT = Path(sys.argv[1]), Path(sys.argv[2])
    OUT.mkdir(parents=True, exist_ok=True)
    SOURCE = block.read_text().splitlines()
    pv.OFF_SCREEN = True
    pv.Plotter.__init__, pv.Plotter.add_mesh, pv.Plotter.show = _patched_init, _patched_add_mesh, _patched_show
    exec(compile(block.read_text(), BLOCK, "exec"), {"__name__": "__main__"})
    for e in _plotters:  # the plotters the block made and never showed
        _capture(e, OUT)
