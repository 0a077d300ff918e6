"""The learned abstractor: a 3D CNN that reads a shape's occupancy grid and predicts ``m`` indexed
cuboids, trained without supervision on a whole category (Tulsiani et al. 2017).

Modules, each importing only those listed after it (``lint-imports`` checks the order):
:mod:`~primkit.model.presets` (the bundled models' recipes) -> :mod:`~primkit.model.training` ->
:mod:`~primkit.model.abstraction` (the one way in: files, meshes or arrays to abstractions) ->
:mod:`~primkit.model.abstractor` (inference) -> :mod:`~primkit.model.cuboids_file` (the
``<name>.cuboids.json`` schema) -> :mod:`~primkit.model.fitting` (the method's losses
of given cuboids, refinement), :mod:`~primkit.model.orientation` (``align="auto"``),
:mod:`~primkit.model.parts` (part names) -> :mod:`~primkit.model.losses`,
:mod:`~primkit.model.network`, :mod:`~primkit.model.bundled` (the shipped model files) ->
:mod:`~primkit.model.distance_field`, :mod:`~primkit.model.modelfile` (the file format). Inference
never imports training. Below the model, it may import :mod:`primkit.data`, :mod:`primkit.primitives`
(with the palette of written meshes), :mod:`primkit.geometry` and :mod:`primkit.io` (with the
conversions of pyvista and Open3D inputs, :mod:`primkit.io.objects`); torch is imported by the modules
that need it. The drawing kit, :mod:`primkit.viz`, sits above the model.

Four names for four things (from the model to a batch of shapes):

* :class:`~primkit.model.abstractor.Abstractor`: a trained model (network, part names, model-file
  metadata), loaded once; ``predict`` turns prepared shapes into results.
* :class:`~primkit.model.abstractor.AbstractionResult`: the cuboids the model gives one prepared
  shape (input and canonical frames, the frame between them, alignment and refinement), a value
  with no geometry of the shape; ``save`` writes ``<name>.cuboids.json`` and ``.cuboids.ply``.
* :class:`~primkit.model.abstraction.Abstraction`: one shape as the user gave it *with* its
  :class:`AbstractionResult` (``.result``): its vertices, faces and prepared grids on demand.
* :class:`~primkit.model.abstraction.Abstractions`: what :func:`~primkit.model.abstraction.abstract_shapes`
  returns for a batch: the usable shapes (:class:`Abstraction`), one error line per input that
  could not be used, the model, and its model-card check.

The names stay as they are: ``AbstractionResult`` alone appears in 15 files of the package, its
tests, scripts and docs, several of them being rewritten by other work at the same time.
"""
