"""pyvista, imported for off-screen pictures.

The vtk wheel renders through EGL (Mesa) when there is no X display; we ask for EGL directly so
it does not first try (and warn about) an X server.
"""

from __future__ import annotations

import os

__all__ = ["pyvista_module"]


def pyvista_module():
    """Import pyvista, asking VTK for an EGL window when there is no X display."""
    if not os.environ.get("DISPLAY"):
        os.environ.setdefault("VTK_DEFAULT_OPENGL_WINDOW", "vtkEGLRenderWindow")
    import pyvista as pv

    return pv
