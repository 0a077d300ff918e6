"""The drawing kit: part colours, the camera convention, off-screen pyvista, conversions to and from
Open3D and pyvista, pictures of shapes and their cuboids, and 3D scenes for web pages (plotly.js).

It sits above the model and below the applications (segmentation, embedding, image, report,
viewers): it may import :mod:`primkit.model` (part names) and what lies below it, never an
application. The part colours (:mod:`primkit.primitives.palette`) and the conversions of Open3D and
pyvista inputs (:mod:`primkit.io.objects`) live below the model, which needs them; :mod:`~primkit.viz.palette`
and :mod:`~primkit.viz.interop` re-export them. Inside, :mod:`~primkit.viz.render` (pictures) and
:mod:`~primkit.viz.web` (plotly scenes) import :mod:`~primkit.viz.interop`, which imports
:mod:`~primkit.viz.camera`, :mod:`~primkit.viz.palette` and :mod:`~primkit.viz.backend`. The pictures that know the applications (the HTML report, the
viewers) live above them: :mod:`primkit.report`, :mod:`primkit.viewers`.
"""
