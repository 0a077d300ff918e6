"""The learned abstractor: a 3D CNN that reads a shape's occupancy grid and predicts ``m`` indexed
cuboids, trained without supervision on a whole category (Tulsiani et al. 2017).

Modules, each importing only those listed after it (``lint-imports`` checks the order):
:mod:`~primkit.model.presets` (the bundled models' recipes) -> :mod:`~primkit.model.training` ->
:mod:`~primkit.model.abstraction` (the one way in: files, meshes or arrays to abstractions) ->
:mod:`~primkit.model.abstractor` (inference) -> :mod:`~primkit.model.fitting` (the method's losses
of given cuboids, refinement), :mod:`~primkit.model.orientation` (``align="auto"``),
:mod:`~primkit.model.parts` (part names) -> :mod:`~primkit.model.losses`,
:mod:`~primkit.model.network`, :mod:`~primkit.model.bundled` (the shipped model files) ->
:mod:`~primkit.model.distance_field`, :mod:`~primkit.model.modelfile` (the file format). Inference
never imports training. Below the model, it may import :mod:`primkit.data`, :mod:`primkit.primitives`
(with the palette of written meshes), :mod:`primkit.geometry` and :mod:`primkit.io` (with the
conversions of pyvista and Open3D inputs, :mod:`primkit.io.objects`); torch is imported by the modules
that need it. The drawing kit, :mod:`primkit.viz`, sits above the model.
"""
