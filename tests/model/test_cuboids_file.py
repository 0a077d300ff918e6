"""``<name>.cuboids.json``: one schema written by every writer, and a reader of the old layouts."""

from __future__ import annotations

import json

import numpy as np
import pytest

from primkit import primitives
from primkit.geometry import CanonicalFrame
from primkit.image.inference import ImageAbstraction
from primkit.model.abstractor import AbstractionResult, Refinement
from primkit.model.cuboids_file import CUBOIDS_FILE_VERSION, cuboids_document, read_cuboids_file, write_cuboids_file

#: the schema's own keys, in the order they are written (the module notes)
KEYS = ["schema_version", "type", "name", "source", "frame", "canonical_frame", "model", "part_names", "present",
        "parts"]


def _cuboids():
    rng = np.random.default_rng(3)
    q = rng.normal(size=(4, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    return primitives.Cuboids(rng.uniform(0.05, 0.3, (4, 3)), q, rng.uniform(-0.5, 0.5, (4, 3)),
                              np.array([True, False, True, True]), probabilities=np.array([0.9, 0.2, 0.7, 0.6]))


def _frame():
    rot = np.array([[0.0, 0, 1], [0, 1, 0], [-1, 0, 0]])
    return CanonicalFrame(rot, np.array([0.1, -0.2, 0.3]), 1.7)


def test_a_written_file_reads_back_whole(tmp_path):
    c, frame = _cuboids(), _frame()
    path = write_cuboids_file(tmp_path / "a.cuboids.json", c, name="a", source="in/a.off", canonical_frame=frame,
                              model="chair", part_names=["back", "seat", "legs", "legs"], refinement={"steps": 3})
    d = json.loads(path.read_text())
    assert list(d)[:len(KEYS)] == KEYS and d["schema_version"] == CUBOIDS_FILE_VERSION
    assert d["present"] == [0, 2, 3] and d["refinement"] == {"steps": 3}
    back = read_cuboids_file(path)
    for field in ("half_extents", "quaternions", "translations", "existence", "probabilities"):
        np.testing.assert_array_equal(getattr(back.cuboids, field), getattr(c, field))
    assert (back.name, back.source, back.frame, back.model) == ("a", "in/a.off", "input", "chair")
    assert back.part_names == ["back", "seat", "legs", "legs"] and back.present.tolist() == [0, 2, 3]
    np.testing.assert_array_equal(back.canonical_frame.matrix, frame.matrix)
    assert back.extra == {"refinement": {"steps": 3}} and back.schema_version == 2
    with pytest.raises(FileExistsError):
        write_cuboids_file(path, c, name="a")


def test_every_writer_writes_the_one_schema():
    c, frame = _cuboids(), _frame()
    result = AbstractionResult("a", c, c.transformed(frame.matrix), frame, "a.off", None, Refinement(5, 0.2, 0.1),
                               model="chair", part_names=("back", "seat", "legs", "legs"))
    picture = ImageAbstraction("b", c, 30.0, 10.0, np.zeros((4, 4, 3), np.uint8), "b.png", model="chair-image")
    for d, frame_name in ((result.to_dict(), "input"), (picture.to_dict(), "canonical"),
                          (cuboids_document(c, name="c"), "input")):
        assert list(d)[:len(KEYS)] == KEYS and d["schema_version"] == CUBOIDS_FILE_VERSION
        assert d["frame"] == frame_name and len(d["part_names"]) == c.count and d["present"] == [0, 2, 3]
    assert result.to_dict()["refinement"] == {"steps": 5, "loss_before": 0.2, "loss_after": 0.1}
    assert result.to_dict()["alignment"]["mode"] == "none"  # which axes were taken as up and front
    assert picture.to_dict()["viewpoint"] == {"azimuth_deg": 30.0, "elevation_deg": 10.0}
    assert picture.to_dict()["part_names"] == [f"part{k}" for k in range(c.count)]


def test_the_two_old_layouts_are_read(tmp_path):
    c, frame = _cuboids(), _frame()
    bare = c.save_json(tmp_path / "bare.cuboids.json")  # what `primkit segment` and the viewer wrote
    old = {**c.to_dict(), "name": "o", "source": "o.off", "frame": "input", "canonical_frame": frame.to_dict(),
           "alignment": {"mode": "none", "up": "+y", "front": "+x"}}  # what `primkit abstract` wrote
    (tmp_path / "o.cuboids.json").write_text(json.dumps(old))
    a, b = read_cuboids_file(bare), read_cuboids_file(tmp_path / "o.cuboids.json")
    assert a.schema_version == b.schema_version == 1
    assert (a.name, a.frame, a.model, a.canonical_frame) == ("bare", "input", None, None)
    assert a.part_names == b.part_names == ["part0", "part1", "part2", "part3"]
    np.testing.assert_array_equal(b.canonical_frame.matrix, frame.matrix)
    assert b.name == "o" and b.extra == {"alignment": {"mode": "none", "up": "+y", "front": "+x"}}
    np.testing.assert_array_equal(a.cuboids.translations, c.translations)


def test_bad_files_are_refused_naming_the_file(tmp_path):
    c = _cuboids()
    d = cuboids_document(c, name="x")
    cases = {"newer": {**d, "schema_version": CUBOIDS_FILE_VERSION + 1},
             "present": {**d, "present": [0]},
             "part_names": {**d, "part_names": ["a"]},
             "frame": {**d, "frame": "world"}}
    for what, doc in cases.items():
        path = tmp_path / f"{what}.cuboids.json"
        path.write_text(json.dumps(doc))
        with pytest.raises(ValueError, match=what) as caught:
            read_cuboids_file(path)
        assert str(path) in str(caught.value)
    with pytest.raises(ValueError, match="frame"):
        cuboids_document(c, name="x", frame="world")
    with pytest.raises(ValueError, match="replace"):
        cuboids_document(c, name="x", present=[1])
