"""primkit as a VTK filter, on pip's VTK (the one pyvista uses).

:class:`PrimkitSegmentation` is a ``VTKPythonAlgorithmBase``: a ``vtkPolyData`` in (a mesh, or a
point cloud); out on port 0 the same surface with ``part`` cell data (the part index of each face)
and ``part`` point data (of each vertex or point); out on port 1 the cuboids, one ``vtkPolyData`` of
12 triangles per present cuboid with ``part`` cell data. Both outputs carry ``part_names`` field
data. When the model file has a labeller (``primkit name-parts``, :mod:`primkit.segmentation.labeller`),
port 0 also carries ``label`` beside ``part`` (cell data of a mesh's faces, point data of a cloud's
points: each element's name, an index into the ``label_names`` field data). It re-executes when its input or its properties change, like any VTK filter::

    from primkit.plugins.vtk_filter import PrimkitSegmentation
    f = PrimkitSegmentation(Model="chair", RefineSteps=0)
    f.SetInputConnection(reader.GetOutputPort())
    f.Update()
    parts, cuboids = f.GetOutputDataObject(0), f.GetOutputDataObject(1)

Properties (``Set<Name>``/``Get<Name>``, or keywords of the constructor): ``Model`` (a bundled
model's name or a model file, default ``"chair"``), ``RefineSteps`` (gradient steps per shape,
default 0), ``Up`` and ``Front`` (the input's axes; default ``"auto"``: found by the model, as
``primkit segment`` finds them without ``--up``/``--front``; :func:`primkit.model.orientation.resolve_align`).

An update that cannot run (no such model, an input it cannot use) leaves the outputs empty and says
why on one line, ``primkit segmentation: nosuchmodel: no such model file, ...``, in VTK's output
window and in the filter's ``last_error``.

For ParaView see :mod:`primkit.plugins.paraview_plugin`: ParaView's Python carries its own VTK,
which cannot share a process with pip's, so its plugin is a separate, NumPy-only file.
"""

from __future__ import annotations

import numpy as np
from vtkmodules.util.vtkAlgorithm import VTKPythonAlgorithmBase

from ..model.abstraction import load_model
from ..viz.backend import pyvista_module
from ..viz.interop import from_pyvista, to_pyvista
from .common import label_shapes
from .pyvista_accessor import segmented_copy

__all__ = ["PrimkitSegmentation"]

AXES = ["auto", "+x", "-x", "+y", "-y", "+z", "-z"]  # "auto": not declared, found by the model


class PrimkitSegmentation(VTKPythonAlgorithmBase):
    """Co-segment a surface or point cloud by its cuboids (see the module notes)."""

    def __init__(self, **properties):
        VTKPythonAlgorithmBase.__init__(self, nInputPorts=1, inputType="vtkPolyData", nOutputPorts=2,
                                        outputType="vtkPolyData")
        self._model, self._refine, self._up, self._front = "chair", 0, "auto", "auto"
        self._loaded = None  # (model name, Abstractor, Labeller or None): loaded once per model
        #: why the last update failed, one line (None: it did not); also shown in VTK's output window
        self.last_error = None
        for name, value in properties.items():
            setter = getattr(self, f"Set{name}", None)
            if setter is None:
                raise TypeError(f"PrimkitSegmentation has no property {name!r} (Model, RefineSteps, Up, Front)")
            setter(value)

    # ---- properties --------------------------------------------------------------------------

    def SetModel(self, model) -> None:
        if str(model) != self._model:
            self._model = str(model)
            self.Modified()

    def GetModel(self) -> str:
        return self._model

    def SetRefineSteps(self, steps) -> None:
        steps = int(steps)
        if steps < 0:
            raise ValueError(f"RefineSteps must be 0 or more, got {steps}")
        if steps != self._refine:
            self._refine = steps
            self.Modified()

    def GetRefineSteps(self) -> int:
        return self._refine

    def SetUp(self, axis) -> None:
        self._set_axis("_up", axis)

    def GetUp(self) -> str:
        return self._up

    def SetFront(self, axis) -> None:
        self._set_axis("_front", axis)

    def GetFront(self) -> str:
        return self._front

    def _set_axis(self, attribute: str, axis) -> None:
        axis = str(axis).strip().lower()
        if axis not in AXES:
            raise ValueError(f"an axis is one of {', '.join(AXES)}, got {axis!r}")
        if axis != getattr(self, attribute):
            setattr(self, attribute, axis)
            self.Modified()

    # ---- pipeline ------------------------------------------------------------------------------

    def _abstractor(self):
        return self._load()[1]

    def _load(self):
        if self._loaded is None or self._loaded[0] != self._model:
            from ..model.bundled import resolve_model
            from ..segmentation.labeller import read_labeller

            self._loaded = (self._model, load_model(self._model), read_labeller(resolve_model(self._model)))
        return self._loaded

    def RequestData(self, request, inInfo, outInfo):
        from vtkmodules.vtkCommonCore import vtkOutputWindow
        from vtkmodules.vtkCommonDataModel import vtkPolyData

        pv = pyvista_module()
        source = pv.wrap(vtkPolyData.GetData(inInfo[0], 0))
        try:
            vertices, faces = from_pyvista(source)
            shape = (vertices, faces) if len(faces) else vertices
            _, abstractor, labeller = self._load()
            labelled = label_shapes([shape], abstractor, up=self._up, front=self._front, refine=self._refine,
                                    labeller=labeller)[0]
            parts = segmented_copy(source, labelled)
        except (ValueError, TypeError, OSError, KeyError) as exc:  # OSError: no such model file, unreadable
            # one line saying why, in VTK's output window (as ParaView's plugin says it), and on the filter
            self.last_error = f"primkit segmentation: {(str(exc) or type(exc).__name__).splitlines()[0]}"
            vtkOutputWindow.GetInstance().DisplayErrorText(self.last_error + "\n")
            return 0
        self.last_error = None
        cuboids = to_pyvista(labelled.cuboids)
        cuboids.field_data["part_names"] = np.array(labelled.part_names)
        vtkPolyData.GetData(outInfo, 0).ShallowCopy(parts)
        vtkPolyData.GetData(outInfo, 1).ShallowCopy(cuboids)
        return 1
