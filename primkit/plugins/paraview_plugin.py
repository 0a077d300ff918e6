"""primkit as a ParaView Python plugin: the filter *Primkit Segmentation*, on ParaView's own VTK.

Load this file in ParaView (tested: Debian 12's ParaView 5.11.0, Python 3.11, VTK 9.2):

* **GUI**: start ParaView with this file as its startup script, ``paraview --script=PATH`` (it puts
  back ``inspect.getargspec``, see below), then *Tools > Manage Plugins > Load New*, choose the same
  file, and apply *Filters > primkit > Primkit Segmentation* to a surface or point cloud.
* **pvpython**::

      import inspect; inspect.getargspec = inspect.getfullargspec     # Debian's 5.11 only, see below
      from paraview.simple import *
      LoadPlugin(PATH, ns=globals())
      seg = PrimkitSegmentation(Input=OpenDataFile("chair.ply"), Model="chair")

``PATH`` is this file: ``python -m primkit.plugins.paraview_worker --where`` prints it.

Out on port 0: the input surface (triangulated if it had polygons) with ``part`` cell data (the part
index of each face) and ``part`` point data (of each vertex, or each point of a cloud), ``rgb``
cell and point data (primkit's part colours, uint8: colour by ``rgb`` with *Map Scalars* off for
primkit's pictures) and ``part_names`` field data. On port 1: the present cuboids, 12 triangles
each, with ``part`` and ``rgb`` cell data.

How it reaches primkit
----------------------
This file imports only the standard library, NumPy and ParaView's VTK: ParaView's Python holds VTK
9.2, and primkit needs pip's VTK (9.3 or later, through pyvista), which cannot be imported into
the same process (on the path first it crashes ``pvpython``; after ParaView's, pyvista refuses to
load). So :meth:`PrimkitSegmentation.RequestData` writes the polydata's points and triangles to
a temporary ``.npz`` and hands it to :mod:`primkit.plugins.paraview_worker`, running in the Python
primkit is installed in, which writes the labels and the cuboids back as arrays. One worker is
started at the first apply and kept while ParaView runs (the imports and the model load, about
5 s, are paid once; a later apply takes the labelling's own time); it ends with ParaView, and a
worker that died is started again at the next apply. That Python is, in order:
the filter's ``Python`` property, ``$PRIMKIT_PYTHON``, the interpreter of the environment this file
is installed in (``<env>/bin/python`` for ``<env>/lib/pythonX.Y/site-packages/primkit/...``, or a
source checkout's ``.venv/bin/python``), then the interpreter of the ``primkit`` command on
``PATH``. The worker imports the primkit package this file belongs to.

ParaView versions
-----------------
The decorators used (``paraview.util.vtkAlgorithm``: ``smproxy``, ``smproperty``, ``smdomain``,
``smhint``) are those ParaView documents for Python plugins since 5.6, and the file needs NumPy in
ParaView's Python. Tested: 5.11.0 (Debian 12). ParaView 5.11.0's plugin loader
(``paraview/detail/pythonalgorithm.py``) imports ``inspect.getargspec``, which Python 3.11 removed,
*before* it reads any plugin file, so on Python 3.11 no Python plugin loads until something has
put the name back: the first lines below do that when this file runs as a script (``--script``),
and the one line above does it in ``pvpython``. ParaView builds on Python 3.10 or older need nothing.
"""

import inspect

if not hasattr(inspect, "getargspec"):  # ParaView 5.11 on Python >= 3.11 (see the module notes)
    # getfullargspec's result has the .args that ParaView's loader reads (its only use of it)
    inspect.getargspec = inspect.getfullargspec

import atexit  # noqa: E402
import json  # noqa: E402
import os  # noqa: E402
import shutil  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
from vtkmodules.util.numpy_support import numpy_to_vtk, numpy_to_vtkIdTypeArray, vtk_to_numpy  # noqa: E402
from vtkmodules.util.vtkAlgorithm import VTKPythonAlgorithmBase  # noqa: E402

try:  # inside ParaView: its decorators describe the filter's proxy
    from paraview.util.vtkAlgorithm import smdomain, smhint, smproperty, smproxy
except ImportError:  # a plain VTK (e.g. primkit's own tests): the decorators leave their target alone

    class _Inert:
        def __getattr__(self, name):
            return lambda *args, **kwargs: (lambda target: target)

    smproxy = smproperty = smdomain = smhint = _Inert()

__all__ = ["PrimkitSegmentation", "find_python", "worker", "close_workers", "PLUGIN_FILE"]

#: This file (what ParaView's *Load New* and ``LoadPlugin`` are given); None when run by ``--script``.
PLUGIN_FILE = globals().get("__file__")
AXES = ["auto", "+x", "-x", "+y", "-y", "+z", "-z"]
ALIGN = ["auto", "front", "any", "none"]


def _string_list(values) -> str:
    return "<StringListDomain name='list'>" + "".join(f"<String value='{v}'/>" for v in values) + "</StringListDomain>"


def _package_root() -> Path | None:
    """The folder holding the ``primkit`` package this file belongs to."""
    if PLUGIN_FILE is None:
        return None
    here = Path(PLUGIN_FILE).resolve()
    return here.parents[2] if here.parent.name == "plugins" and here.parents[1].name == "primkit" else None


def find_python(explicit: str = "") -> str:
    """The Python primkit is installed in (the order is in the module notes); raises RuntimeError."""
    candidates = [explicit, os.environ.get("PRIMKIT_PYTHON", "")]
    root = _package_root()
    if root is not None:
        if root.name == "site-packages":  # <env>/lib/pythonX.Y/site-packages
            candidates.append(str(root.parents[2] / "bin" / "python"))
        candidates.append(str(root / ".venv" / "bin" / "python"))
    command = shutil.which("primkit")
    if command:
        with open(command, "rb") as fh:
            first = fh.readline().decode(errors="replace").strip()
        if first.startswith("#!"):
            candidates.append(first[2:].strip().split()[0])
    for c in candidates:
        if c and os.path.isfile(c) and os.access(c, os.X_OK):
            return c
    raise RuntimeError("cannot find the Python primkit is installed in: set the filter's Python property "
                       "or $PRIMKIT_PYTHON to it")


def _worker_env() -> dict:
    """The worker's environment: ParaView's Python settings removed, this file's primkit first."""
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PYTHONHOME", "PYTHONSTARTUP")}
    root = _package_root()
    if root is not None and root.name != "site-packages":
        env["PYTHONPATH"] = str(root)
    return env


class _Worker:
    """One ``paraview_worker --serve`` process: requests on its stdin, answers on its stdout, its
    stderr in a temporary file (its last line is the message when it dies)."""

    def __init__(self, python: str):
        self.log = tempfile.TemporaryFile(mode="w+", encoding="utf-8", errors="replace")
        self.proc = subprocess.Popen([python, "-m", "primkit.plugins.paraview_worker", "--serve"],
                                     stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=self.log, text=True,
                                     encoding="utf-8", env=_worker_env(), bufsize=1)

    def alive(self) -> bool:
        return self.proc.poll() is None

    def ask(self, given: str, result: str):
        """``(status, message)``: 0 and "" when ``result`` was written; None as the status when the
        worker died (the message then is its last line on stderr)."""
        self.log.seek(0)
        self.log.truncate()
        try:
            self.proc.stdin.write(json.dumps({"in": given, "out": result}) + "\n")
            self.proc.stdin.flush()
            line = self.proc.stdout.readline()
        except OSError:
            line = ""
        if line:
            reply = json.loads(line)
            return int(reply["status"]), str(reply["error"])
        self.proc.wait()
        self.log.seek(0)
        lines = [ln for ln in self.log.read().splitlines() if ln.strip()]
        return None, lines[-1] if lines else f"primkit segmentation: the worker exited with {self.proc.returncode}"

    def close(self) -> None:
        try:
            self.proc.stdin.close()
            self.proc.wait(timeout=10)
        except (OSError, subprocess.TimeoutExpired):
            self.proc.kill()
        self.log.close()


#: The workers started, by the Python they run in.
_WORKERS: dict = {}


def worker(python: str) -> _Worker:
    """The running worker for ``python``, started when there is none (or it died)."""
    w = _WORKERS.get(python)
    if w is None or not w.alive():
        if w is not None:
            w.close()
        w = _WORKERS[python] = _Worker(python)
    return w


@atexit.register
def close_workers() -> None:
    """End every worker (ParaView exiting closes their stdin anyway)."""
    while _WORKERS:
        _WORKERS.popitem()[1].close()


def _triangles(poly):
    """``(points (n, 3) float64, faces (f, 3) int64, surface)``: the surface's triangles (polygons split
    by ``vtkTriangleFilter``; a point cloud has none), and the polydata the labels belong to."""
    from vtkmodules.vtkFiltersCore import vtkTriangleFilter

    if poly.GetNumberOfPolys() and (poly.GetNumberOfCells() != poly.GetNumberOfPolys() or poly.GetPolys().IsHomogeneous() != 3):
        split = vtkTriangleFilter()
        split.PassVertsOff()
        split.PassLinesOff()
        split.SetInputData(poly)
        split.Update()
        poly = split.GetOutput()
    points = vtk_to_numpy(poly.GetPoints().GetData()).astype(np.float64) if poly.GetNumberOfPoints() else np.zeros((0, 3))
    if poly.GetNumberOfPolys():
        faces = vtk_to_numpy(poly.GetPolys().GetConnectivityArray()).astype(np.int64).reshape(-1, 3)
    else:
        faces = np.zeros((0, 3), np.int64)
    return points, faces, poly


def _array(values, name: str):
    a = numpy_to_vtk(np.ascontiguousarray(values), deep=True)
    a.SetName(name)
    return a


def _names(names):
    from vtkmodules.vtkCommonCore import vtkStringArray

    a = vtkStringArray()
    a.SetName("part_names")
    for n in names:
        a.InsertNextValue(str(n))
    return a


def _colours(palette, labels):
    """uint8 rgb of each label; grey for -1 (no cuboid)."""
    table = np.vstack([palette, [[200, 200, 200]]]).astype(np.uint8)
    return table[np.where(labels < 0, len(palette), labels)]


@smproxy.filter(name="PrimkitSegmentation", label="Primkit Segmentation")
@smhint.xml("<ShowInMenu category='primkit'/>")
@smproperty.input(name="Input", port_index=0)
@smdomain.datatype(dataTypes=["vtkPolyData"], composite_data_supported=False)
class PrimkitSegmentation(VTKPythonAlgorithmBase):
    """Co-segment a surface or point cloud by its cuboids, in primkit's Python (see the module notes)."""

    def __init__(self):
        VTKPythonAlgorithmBase.__init__(self, nInputPorts=1, inputType="vtkPolyData", nOutputPorts=2,
                                        outputType="vtkPolyData")
        self._options = {"model": "chair", "refine": 0, "up": "auto", "front": "auto", "align": "auto"}
        self._python = ""

    def _set(self, key, value) -> None:
        if self._options[key] != value:
            self._options[key] = value
            self.Modified()

    @smproperty.stringvector(name="Model", default_values="chair")
    def SetModel(self, model):
        self._set("model", str(model))

    @smproperty.intvector(name="RefineSteps", default_values=0)
    @smdomain.intrange(min=0, max=2000)
    def SetRefineSteps(self, steps):
        self._set("refine", max(0, int(steps)))

    @smproperty.stringvector(name="Up", default_values="auto")
    @smdomain.xml(_string_list(AXES))
    def SetUp(self, axis):
        self._set("up", str(axis))

    @smproperty.stringvector(name="Front", default_values="auto")
    @smdomain.xml(_string_list(AXES))
    def SetFront(self, axis):
        self._set("front", str(axis))

    @smproperty.stringvector(name="Align", default_values="auto")
    @smdomain.xml(_string_list(ALIGN))
    def SetAlign(self, mode):
        self._set("align", str(mode))

    @smproperty.stringvector(name="Python", default_values="", panel_visibility="advanced")
    def SetPython(self, path):
        if str(path) != self._python:
            self._python = str(path)
            self.Modified()

    def _report(self, text: str) -> int:
        from vtkmodules.vtkCommonCore import vtkOutputWindow

        vtkOutputWindow.GetInstance().DisplayErrorText(text.rstrip() + "\n")
        return 0

    def RequestData(self, request, inInfo, outInfo):
        from vtkmodules.vtkCommonCore import vtkPoints
        from vtkmodules.vtkCommonDataModel import vtkCellArray, vtkPolyData

        given = vtkPolyData.GetData(inInfo[0], 0)
        points, faces, surface = _triangles(given)
        options = {k: v for k, v in self._options.items() if not (k in ("up", "front", "align") and v == "auto")}
        try:
            python = find_python(self._python)
        except RuntimeError as exc:
            return self._report(f"primkit segmentation: {exc}")
        with tempfile.TemporaryDirectory(prefix="primkit-paraview-") as tmp:
            given_file, result_file = os.path.join(tmp, "in.npz"), os.path.join(tmp, "out.npz")
            np.savez(given_file, points=points, faces=faces, options=np.array(json.dumps(options)))
            status, message = worker(python).ask(given_file, result_file)
            if status != 0:
                return self._report(message)
            with np.load(result_file, allow_pickle=False) as got:
                out = {k: got[k] for k in got.files}

        parts = vtkPolyData.GetData(outInfo, 0)
        parts.ShallowCopy(surface)
        if len(faces):
            parts.GetCellData().AddArray(_array(out["face_labels"], "part"))
            parts.GetCellData().AddArray(_array(_colours(out["colors"], out["face_labels"]), "rgb"))
        parts.GetPointData().AddArray(_array(out["point_labels"], "part"))
        parts.GetPointData().AddArray(_array(_colours(out["colors"], out["point_labels"]), "rgb"))
        parts.GetFieldData().AddArray(_names(out["part_names"]))

        boxes = vtkPolyData.GetData(outInfo, 1)
        corners = vtkPoints()
        corners.SetData(_array(out["cuboid_vertices"], "Points"))
        cells = vtkCellArray()
        f = out["cuboid_faces"]
        cells.SetData(numpy_to_vtkIdTypeArray(np.arange(0, 3 * len(f) + 1, 3, dtype=np.int64), deep=True),
                      numpy_to_vtkIdTypeArray(f.astype(np.int64).ravel(), deep=True))
        boxes.SetPoints(corners)
        boxes.SetPolys(cells)
        boxes.GetCellData().AddArray(_array(out["cuboid_part"], "part"))
        boxes.GetCellData().AddArray(_array(_colours(out["colors"], out["cuboid_part"]), "rgb"))
        boxes.GetFieldData().AddArray(_names(out["part_names"]))
        return 1
