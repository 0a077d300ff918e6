"""``labeller="auto"``: one lookup (:func:`primkit.segmentation.resolve_labeller`) for the segmenter,
the report and the plugins."""

import pytest

from primkit.model.bundled import resolve_model
from primkit.segmentation import labeller as lab
from primkit.segmentation import resolve_labeller


def test_auto_is_the_model_files_labeller_and_anything_else_is_kept():
    chair = resolve_labeller("chair")
    assert chair is not None and chair.names == lab.read_labeller(resolve_model("chair")).names
    assert resolve_labeller(resolve_model("chair"), "auto").names == ["back", "seat", "legs", "arms"]  # a path
    assert not lab.has_labeller(resolve_model("chair-image")) and resolve_labeller("chair-image") is None
    assert resolve_labeller(object(), "auto") is None  # a model object: no file to read
    assert resolve_labeller("chair", None) is None and resolve_labeller("chair", chair) is chair
    with pytest.raises(FileNotFoundError, match="no such model file"):
        resolve_labeller("no-such-model")


def test_the_report_the_plugins_and_the_segmenter_use_the_one_lookup():
    import primkit.report
    from primkit.plugins import common
    from primkit.segmentation import Segmenter

    assert primkit.report.resolve_labeller is resolve_labeller and common.resolve_labeller is resolve_labeller
    assert not hasattr(primkit.report, "_labeller")
    assert Segmenter("chair").labeller.names == resolve_labeller("chair").names
    assert Segmenter("chair", labeller=None).labeller is None
