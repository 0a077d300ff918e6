"""primkit inside the tools people already use: pyvista, VTK and ParaView, Open3D.

* :mod:`~primkit.plugins.pyvista_accessor`: ``mesh.primkit.segment(model="chair")`` on any pyvista
  dataset, registered through the ``pyvista.accessors`` entry point (no ``import primkit`` needed);
* :mod:`~primkit.plugins.vtk_filter`: a ``VTKPythonAlgorithmBase`` filter for VTK pipelines, also a
  ParaView Python plugin (load the file in ParaView's plugin manager);
* :mod:`~primkit.plugins.open3d_geometry`: Open3D's tensor geometry with a ``part`` attribute per
  triangle or point, and the cuboids as tensor meshes and line sets.

Each plugin is a thin adapter over :mod:`primkit.plugins.common` (the shapes abstracted through
:func:`primkit.model.abstraction.abstract_shapes` and co-segmented by the rule of
:mod:`primkit.segmentation`), so the three give the same labels for the same shape. The plugins
import the applications and the drawing kit's conversions (:mod:`primkit.viz.interop`) below them;
the viewers import them (the Open3D viewer), nothing else does.
"""
