"""The command line's options: edits parsed from their flags."""

import numpy as np
import pytest

from primkit.cli.deform import parse_edit


def test_parse_edit_resolves_part_names():
    names = ["seat", "legs", "legs", "back"]
    assert parse_edit("legs=1.3", names, kind="scale") == {1: 1.3, 2: 1.3}
    r = parse_edit("part3,seat=0,0.05,0", names, kind="move")
    assert sorted(r) == [0, 3] and np.allclose(r[3], [0, 0.05, 0])
    assert parse_edit("3=15", names, kind="rotate") == {3: 15.0}
    with pytest.raises(ValueError, match="unknown part 'arms'.*seat, legs, back"):
        parse_edit("arms=2", names, kind="scale")
    with pytest.raises(ValueError, match="expected 3 number"):
        parse_edit("seat=0.1", names, kind="move")
