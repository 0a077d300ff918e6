"""primkit inside the tools people already use: pyvista, VTK and ParaView, Open3D.

* :mod:`~primkit.plugins.pyvista_accessor`: ``mesh.primkit.segment(model="chair")`` on any pyvista
  dataset, registered through the ``pyvista.accessors`` entry point (no ``import primkit`` needed),
  and :mod:`~primkit.plugins.pyvista_readers`: ``pv.read`` of ``.off``, ``.binvox``, ``.xyz``,
  ``.npy`` (the ``pyvista.readers`` entry points);
* :mod:`~primkit.plugins.vtk_filter`: a ``VTKPythonAlgorithmBase`` filter for VTK pipelines (pip's VTK);
* :mod:`~primkit.plugins.paraview_plugin`: the ParaView plugin, on ParaView's own VTK and NumPy only,
  with primkit run by :mod:`~primkit.plugins.paraview_worker` in primkit's Python;
* :mod:`~primkit.plugins.open3d_geometry`: Open3D's tensor geometry with a ``part`` attribute per
  triangle or point, the cuboids as tensor meshes and line sets, and files that keep ``part``.

Each plugin (the ParaView one through its worker) is a thin adapter over
:mod:`primkit.plugins.common` (the shapes abstracted through
:func:`primkit.model.abstraction.abstract_shapes` and co-segmented by the rule of
:mod:`primkit.segmentation`), so they all give the same labels for the same shape. The plugins
import the applications and the drawing kit's conversions (:mod:`primkit.viz.interop`) below them;
the viewers import them (the Open3D viewer), nothing else does.
"""
