"""primkit's interactive viewers (pyvista windows), launched by ``primkit view ...``.

Each viewer is a function that builds a ``pyvista.Plotter`` and returns it with its controls as a
small object (``plotter`` plus one method per widget callback), so tests drive the controls
without a window (``off_screen=True``) and check their effect on the scene; ``show()`` is the
caller's choice. They sit above everything in primkit (viewers and the command line are the top
layer) and live outside the package: they need a source checkout, as ``primkit view`` says.

* :mod:`apps.abstraction_viewer` - one shape and its cuboids: a toggle per part, opacity, picking.
* :mod:`apps.collection_browser` - a grid of shapes, one colour per part index, mesh / cuboids /
  segmentation.
* :mod:`apps.embedding_explorer` - the t-SNE map; clicking a shape shows it and its neighbours.
* :mod:`apps.deformation_viewer` - source, target and result with a blend slider; part edits live.
"""
