"""``primkit segment`` as a thin command: its arguments go down into the library and come back up to
``cli/`` only a few times (issue 34: at most 3), and its picture is the library's picture."""

from __future__ import annotations

import os
import sys
from pathlib import Path

import numpy as np
import pytest

import primkit
from primkit import synthetic
from primkit.cli import main

PACKAGE = str(Path(primkit.__file__).parent) + os.sep


def _trace(argv) -> tuple[int, list[str]]:
    """Run the command and follow its calls: the primkit file execution is in, each time it
    changes (a call or a return), leaving out module bodies (imports) and what they call."""
    stops: list[str] = []

    def where(frame):
        found = None
        while frame is not None:
            name = frame.f_code.co_filename
            if name.startswith(PACKAGE):
                if frame.f_code.co_name == "<module>":
                    return None
                found = found or name[len(PACKAGE):]
            frame = frame.f_back
        return found

    def profile(frame, event, arg):
        if event in ("call", "return"):
            loc = where(frame if event == "call" else frame.f_back)
            if loc is not None and (not stops or stops[-1] != loc):
                stops.append(loc)

    sys.setprofile(profile)
    try:
        code = main(argv)
    finally:
        sys.setprofile(None)
    return code, stops


def _climbs(stops) -> list[tuple[str, str]]:
    """Each time execution came back up into ``cli/`` from the library: (from, to). The dispatcher
    (``cli/__init__.py``: SIGTERM as Ctrl-C, logging, the one-line errors) wraps every command alike
    and is no command's code: coming back to it is not counted."""
    cli = "cli" + os.sep
    return [(a, b) for a, b in zip(stops, stops[1:])
            if b.startswith(cli) and not a.startswith(cli) and b != cli + "__init__.py"]


@pytest.fixture(scope="module")
def segmented(tmp_path_factory):
    root = tmp_path_factory.mktemp("flow")
    synthetic.write_collection(root / "in", "chair", 3, seed=7)
    argv = ["segment", str(root / "in"), "--model", "chair", "-o", str(root / "seg"), "--cache", str(root / "cache"),
            "--workers", "1", "--png", str(root / "cli.png"), "--quiet"]
    code, stops = _trace(argv)
    assert code == 0
    return root, stops


@pytest.mark.integration  # the whole segment run traced: seconds, left to the default suite
def test_segment_climbs_back_into_the_command_line_at_most_three_times(segmented):
    _, stops = segmented
    climbs = _climbs(stops)
    assert len(climbs) <= 3, climbs
    # the arguments did go down: the plan, the segmenter and the pictures were reached
    for module in ("data/plan.py", "segmentation/segmenter.py", "segmentation/outputs.py", "viz/render.py"):
        assert module.replace("/", os.sep) in stops


def test_the_climb_counter_sees_a_command_that_calls_the_library_piecewise():
    """The counter can fail: a sequence that goes down and up four times is four climbs."""
    stops = ["cli/a.py", "data/x.py", "cli/a.py", "io/y.py", "cli/a.py", "cli/b.py", "io/y.py", "data/x.py", "cli/b.py",
             "parallel/z.py", "cli/_common.py"]
    assert len(_climbs([s.replace("/", os.sep) for s in stops])) == 4


@pytest.mark.integration  # segment run twice and drawn twice: seconds, left to the default suite
def test_the_segment_picture_is_the_librarys(segmented):
    """The PNG of ``primkit segment --png`` against one drawn by the library from shapes segmented
    one by one (:func:`primkit.segmentation.segment`, not the command's batch): the same tiles, the
    same parts in the same colours, pixel for pixel up to the network's float32 batch noise."""
    from pictures import read_picture
    from primkit.segmentation import segment
    from primkit.segmentation.outputs import write_picture

    root, _ = segmented
    files = sorted((root / "in").glob("*.ply"))
    shapes = [segment(f, "chair", labeller=None) for f in files]
    write_picture(shapes, root / "library.png")
    cli, library = read_picture(root / "cli.png"), read_picture(root / "library.png")
    assert cli.rgb.shape == library.rgb.shape
    assert cli.foreground_fraction > 0.05  # shapes drawn, not an empty canvas
    present = sorted({int(k) for s in shapes for k in np.unique(s.face_labels)})
    shown = cli.part_colours_shown(present)
    assert sum(pixels >= 20 for pixels in shown.values()) >= 3, shown  # parts in their palette colours
    differ = np.abs(cli.rgb.astype(int) - library.rgb.astype(int)).max(axis=-1) > 8
    assert differ.mean() < 0.005, f"{differ.mean():.4f} of the pixels differ"
