"""primkit's interactive viewers (pyvista windows, and one in Open3D's), launched by ``primkit view ...``.

Each viewer is a function that builds a ``pyvista.Plotter`` and returns it with its controls as a
small object (``plotter`` plus one method per widget callback), so tests drive the controls
without a window (``off_screen=True``) and check their effect on the scene; ``show()`` is the
caller's choice. They sit above the applications and the drawing kit, and import any layer below
the command line (never :mod:`primkit.cli`); ``primkit view`` builds them from the command line.

* :mod:`primkit.viewers.abstraction_viewer` - one shape and its cuboids: a toggle per part, opacity, picking.
* :mod:`primkit.viewers.collection_browser` - a grid of shapes, one colour per part index, mesh / cuboids /
  segmentation.
* :mod:`primkit.viewers.embedding_explorer` - the t-SNE map; clicking a shape shows it and its neighbours.
* :mod:`primkit.viewers.deformation_viewer` - source, target and result with a blend slider; part edits live.
* :mod:`primkit.viewers.open3d_viewer` - one mesh or point cloud in Open3D's own window: a button per part,
  refine, export (its actions are methods taking the window, so tests call them the same way).
"""
