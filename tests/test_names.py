"""One name per concept: no public name is defined in two modules of ``primkit`` (issue 34).

A name is public when it has no leading underscore; it is *defined* in a module when the module's
top level binds it with ``def``, ``class`` or an assignment (an ``import`` is a re-export of the
same object and is left alone, as the ``__init__`` files do). The package is walked with
``pkgutil.walk_packages`` and each module's source read with ``ast``, so nothing is imported and
optional dependencies do not matter. Run with ``-s`` to see the names still shared and why.
"""

from __future__ import annotations

import ast
import pkgutil
from collections import defaultdict
from pathlib import Path

import primkit

#: Names that several modules define on purpose: the modules allowed (``pkg.*``: any module under
#: ``pkg``) and the reason. Everything else must be defined once.
SHARED = {
    # the same role in every module that has it
    "main": ({"primkit.cli", "primkit.plugins.paraview_worker"},
             "the entry point of a program (`primkit`, `python -m primkit.plugins.paraview_worker`)"),
    "register": ({"primkit.cli.*"}, "each command module's hook that adds its subcommand to the parser"),
    "PrimkitSegmentation": ({"primkit.plugins.paraview_plugin", "primkit.plugins.vtk_filter"},
                            "the same VTK filter twice: ParaView loads paraview_plugin.py as a file on its "
                            "own VTK, so it cannot import vtk_filter (see its module notes)"),
    "AXES": ({"primkit.plugins.paraview_plugin", "primkit.plugins.vtk_filter"},
             "the same filter property's choices, for the same reason as PrimkitSegmentation"),
}


def public_definitions() -> dict[str, list[str]]:
    """Public name -> the modules of ``primkit`` whose top level defines it."""
    defined = defaultdict(list)
    for info in pkgutil.walk_packages(primkit.__path__, "primkit."):
        spec = info.module_finder.find_spec(info.name)
        tree = ast.parse(Path(spec.origin).read_text())
        for node in tree.body:
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
                names = [node.name]
            elif isinstance(node, ast.Assign):
                names = [t.id for t in node.targets if isinstance(t, ast.Name)]
            elif isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name):
                names = [node.target.id]
            else:
                names = []
            for name in names:
                if not name.startswith("_") and info.name not in defined[name]:
                    defined[name].append(info.name)
    return defined


def _allowed(module: str, patterns) -> bool:
    return any(module == p or (p.endswith(".*") and module.startswith(p[:-1])) for p in patterns)


def test_the_walk_sees_the_package():
    defined = public_definitions()
    # a few names whose home is known, so the walk cannot silently find nothing
    assert defined["Cuboids"] == ["primkit.primitives.cuboids"]
    assert defined["default_part_names"] == ["primkit.model.parts"]
    assert defined["part_colors"] == ["primkit.primitives.palette"]  # viz.palette only re-exports it
    assert len(defined) > 300


def test_no_public_name_is_defined_in_two_modules():
    shared = {name: sorted(modules) for name, modules in public_definitions().items() if len(modules) > 1}
    for name, modules in sorted(shared.items()):
        print(f"{name}: {', '.join(modules)}" + (f"  [allowed: {SHARED[name][1]}]" if name in SHARED else ""))
    offences = [f"{name} is defined in {', '.join(modules)}" for name, modules in shared.items()
                if name not in SHARED or not all(_allowed(m, SHARED[name][0]) for m in modules)]
    assert not offences, "\n".join(offences)


# ---------------------------------------------------------------------------------------------
# Results come back as dataclasses: no public function returns a bare dict
# ---------------------------------------------------------------------------------------------

#: Methods whose dict is a serialisation protocol (JSON, torch state), never a result.
SERIALISERS = {"to_dict", "state_dict"}

#: Public functions whose dict is a document in someone else's format, or a mapping keyed by data.
DOCUMENTS = {
    "primkit.model.modelfile.read_metadata": "the model file's JSON metadata",
    "primkit.model.cuboids_file.cuboids_document": "the JSON of a <name>.cuboids.json file",
    "primkit.model.presets.Recipe.description": "the `training.data` JSON entry of a model file",
    "primkit.model.training.check_checkpoint": "the checkpoint's JSON metadata",
    "primkit.viz.web.scene_figure": "a plotly figure (plotly's JSON layout)",
    "primkit.report.page_scene_figure": "a plotly figure (plotly's JSON layout)",
    "primkit.segmentation.evaluation.parse_label_names": "label value -> name, keyed by the data",
    "primkit.labelling.trees.TreeEnsemble.arrays": "the arrays of the model file, by tensor name",
    "primkit.labelling.post.step_to_dict": "a post-step as a labeller file stores it (JSON)",
    "primkit.data.cache.CacheSegment.row_arrays": "the arrays of a cache file, by array name",
    "primkit.data.cache.encode_row": "the arrays of a cache file, by array name",
}

#: Left for later steps of issue 34, with the reason: none left (keep the mechanism for the next rename).
PENDING: dict[str, str] = {}


def _untyped_dict(annotation) -> bool:
    """``dict``, ``Dict``, ``dict[K, Any]`` or ``dict[K, object]``: a dict whose values say nothing.
    ``dict[str, Path]`` and the like are mappings keyed by data, and pass."""
    text = ast.unparse(annotation).replace(" ", "")
    base = text.split("[")[0].split(".")[-1]
    if base not in ("dict", "Dict"):
        return False
    return "[" not in text or text.endswith(",Any]") or text.endswith(",object]")


def dict_returning_functions() -> list[str]:
    """Qualified names of public functions and methods annotated to return an untyped dict, or
    returning a dict literal without an annotation."""
    found = []
    for info in pkgutil.walk_packages(primkit.__path__, "primkit."):
        spec = info.module_finder.find_spec(info.name)
        tree = ast.parse(Path(spec.origin).read_text())

        def visit(body, prefix):
            for node in body:
                if isinstance(node, ast.ClassDef) and not node.name.startswith("_"):
                    visit(node.body, f"{prefix}{node.name}.")
                elif isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)) and not node.name.startswith("_"):
                    if node.name in SERIALISERS:
                        continue
                    if node.returns is not None:
                        bad = _untyped_dict(node.returns)
                    else:
                        bad = any(isinstance(n, ast.Return) and isinstance(n.value, (ast.Dict, ast.DictComp))
                                  for n in ast.walk(node))
                    if bad:
                        found.append(f"{info.name}.{prefix}{node.name}")

        visit(tree.body, "")
    return found


def test_the_dict_check_can_fail():
    assert _untyped_dict(ast.parse("dict", mode="eval").body)
    assert _untyped_dict(ast.parse("dict[str, Any]", mode="eval").body)
    assert not _untyped_dict(ast.parse("dict[str, Path]", mode="eval").body)
    assert "primkit.segmentation.evaluation.SegmentationEvaluation.to_dict" not in dict_returning_functions()
    assert "primkit.model.modelfile.read_metadata" in dict_returning_functions()  # a document, so still found


def test_no_public_function_returns_a_dict_of_results():
    found = dict_returning_functions()
    for name in found:
        print(f"{name}: {DOCUMENTS.get(name) or PENDING.get(name) or 'NOT ALLOWED'}")
    offences = [name for name in found if name not in DOCUMENTS and name not in PENDING]
    assert not offences, "return a dataclass (or a typed mapping) from:\n" + "\n".join(offences)
