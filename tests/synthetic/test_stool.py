"""The procedural stool: a seat on three or four legs or a column, no back, chair part names."""

import numpy as np
import pytest

from primkit import synthetic

NAMES = synthetic.PART_NAMES["chair"]


@pytest.mark.parametrize("base, parts", [("legs4", {"seat", "leg_front_left", "leg_front_right", "leg_back_left",
                                                    "leg_back_right"}),
                                         ("legs3", {"seat", "leg_front_left", "leg_front_right", "leg_back_left"}),
                                         ("column", {"seat", "column", "star_base"})])
def test_each_base_has_its_parts_and_never_a_back(base, parts):
    for seed in range(2):
        s = synthetic.stool(seed, base=base)
        labelled = {NAMES[k] for k in np.unique(s.face_labels)}
        assert labelled == parts
        # the seat is on top: its faces above every other part's, on average
        centres = s.vertices[s.faces].mean(axis=1)
        seat_y = centres[s.face_labels == NAMES.index("seat"), 1].mean()
        for k in set(np.unique(s.face_labels)) - {NAMES.index("seat")}:
            assert centres[s.face_labels == k, 1].mean() < seat_y


def test_stools_are_seeded_and_generated_as_a_collection():
    a, b = synthetic.generate("stool", 3, seed=4), synthetic.generate("stool", 3, seed=4)
    for x, y in zip(a, b):
        np.testing.assert_array_equal(x.vertices, y.vertices)
        assert x.attributes == y.attributes
    assert synthetic.stool(a[1].seed).attributes == a[1].attributes
    with pytest.raises(ValueError, match="base"):
        synthetic.stool(0, base="tripod")
