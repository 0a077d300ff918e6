"""The drawing kit: part colours, the camera convention, off-screen pyvista, conversions to and from
Open3D and pyvista, pictures of shapes and their cuboids, and 3D scenes for web pages (plotly.js).

Everything that draws uses it, so it sits low: it imports only :mod:`primkit.primitives` and
:mod:`primkit.io` (no model, no application). Inside, :mod:`~primkit.viz.render` (pictures) and
:mod:`~primkit.viz.web` (plotly scenes) import :mod:`~primkit.viz.interop`, which imports
:mod:`~primkit.viz.camera`, :mod:`~primkit.viz.palette` and :mod:`~primkit.viz.backend`. The pictures that know the applications (the HTML report, the
viewers) live above them: :mod:`primkit.report`, :mod:`primkit.viewers`.
"""
