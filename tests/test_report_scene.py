"""The report's interactive 3D scene (:func:`primkit.report.page_scene_figure`) on hand-built shapes:
coloured by part index, or with a labeller's names by name (the thumbnails' palette) with a legend
entry per name; no network, no abstraction."""

import numpy as np
import pytest

from primkit.primitives import Cuboids
from primkit.report import ReportShape, page_scene_figure
from primkit.viz.palette import UNLABELLED, label_colors, part_colors

NAMES = ["back", "seat", "legs", "arms"]


def _rgb(c) -> str:
    return f"rgb({int(c[0])},{int(c[1])},{int(c[2])})"


def _shapes():
    """Two shapes, each the surface of 3 small boxes (12 triangles each) in the canonical cube; faces
    of box k are part k, and named by a rule that differs from the parts (so the two colourings differ)."""
    cub = Cuboids(half_extents=np.full((3, 3), 0.1), quaternions=np.tile([1.0, 0, 0, 0], (3, 1)),
                  translations=np.array([[-0.25, 0, 0], [0, 0.1, 0], [0.25, -0.2, 0.1]]), existence=np.ones(3, bool))
    v, f, part = cub.to_mesh()
    named = [np.where(part == 0, 3, np.where(part == 1, 0, -1)),  # arms, back, none
             np.where(part == 2, 1, 0)]  # seat, back
    return [ReportShape(f"s{i}", "", v, f, cub, part.astype(np.int64), named=n) for i, n in enumerate(named)]


def _surfaces(figure):
    return [t for t in figure["data"] if t.get("meta", {}).get("kind") == "surface"]


@pytest.mark.parametrize("by_name", [False, True])
def test_the_scene_is_coloured_by_name_with_a_labeller_and_by_part_without(by_name):
    shapes = _shapes()
    figure = page_scene_figure(shapes, ["a", "b", "c"], 3, label_names=NAMES if by_name else None)
    for i, s in enumerate(shapes):
        surface = [t for t in _surfaces(figure) if t["meta"]["shape"] == i]
        want = s.named if by_name else s.labels
        assert sum(len(t["i"]) for t in surface) == len(s.faces)  # every face once (no decimation: 36 faces)
        for t in surface:
            key = t["meta"]["label"] if by_name else t["meta"]["part"]
            assert ("part" in t["meta"]) != by_name
            assert len(t["i"]) == np.sum(want == key)
            colour = (label_colors(4)[key] if key >= 0 else UNLABELLED) if by_name else part_colors(3)[key]
            assert t["color"] == _rgb(colour)
            assert t["legendgroup"] == (f"label{key}" if key >= 0 else "unnamed") if by_name else f"part{key}"
        cuboids = [t for t in figure["data"] if t.get("meta", {}) == {"shape": i, "part": 1, "kind": "cuboid"}]
        assert len(cuboids) == 1 and cuboids[0]["color"] == _rgb(part_colors(3)[1])  # cuboids by part always
    legend = {t["name"]: t["legendrank"] for t in figure["data"] if t.get("showlegend")}
    if by_name:  # one entry per name in use (and for none), before the parts
        assert {"back", "seat", "arms", "no name"} <= set(legend) and "legs" not in legend
        assert max(legend[n] for n in ("back", "seat", "arms", "no name")) < min(legend[f"{k} {n}"] for k, n in enumerate("abc"))
        assert "by name" in figure["layout"]["legend"]["title"]["text"]
    else:
        assert set(legend) == {"0 a", "1 b", "2 c"} and "by name" not in figure["layout"]["legend"]["title"]["text"]
