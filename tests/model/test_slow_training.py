"""The abstractor's done-criterion on procedural chairs (slow: about 5 minutes on 2 cores; `pytest -m slow`)."""

import numpy as np
import pytest

from primkit import data, io, synthetic
from primkit.model.abstractor import Abstractor
from primkit.metrics import ChamferConvention, part_label_agreement, score, summarize
from primkit.model.training import ShapeTensors, TrainConfig, train

pytestmark = pytest.mark.slow


def test_parts_keep_their_index_on_held_out_chairs(tmp_path):
    def prep(shapes, offset):
        return [data.prepare(io.Mesh(s.vertices, s.faces), face_labels=s.face_labels, name=f"c{offset + i}")
                for i, s in enumerate(shapes)]

    train_set = prep(synthetic.generate("chair", 96, seed=0), 0)
    held_out_shapes = synthetic.generate("chair", 24, seed=10_000)
    held_out = prep(held_out_shapes, 1000)
    config = TrainConfig(stage1_iterations=960, stage2_iterations=1440)
    result = train(ShapeTensors(train_set), tmp_path / "chair.safetensors", config, progress=False)
    stage1 = [h["parts"] for h in result.history if h["stage"] == 1]
    stage2 = [h["parts"] for h in result.history if h["stage"] == 2]
    assert np.mean(stage2[-10:]) < np.mean(stage1)  # stage 2 drops parts

    model = Abstractor.load(tmp_path / "chair.safetensors")
    results = model.predict(held_out)
    names = synthetic.PART_NAMES["chair"]
    agreement = part_label_agreement([r.canonical for r in results], [s.points for s in held_out],
                                     [s.point_labels for s in held_out], names=names)
    for part in ("seat", "back", "leg_front_left", "leg_front_right", "leg_back_left", "leg_back_right"):
        assert agreement.per_label[part].agreement >= 0.9, (part, agreement.per_label[part])
    summary = summarize([score(r.canonical, s, ChamferConvention()) for r, s in zip(results, held_out)])
    assert summary.iou.mean > 0.3


def test_existence_varies_with_the_shape_with_the_local_gradient(tmp_path):
    """Half the training chairs have arms. With the local-expectation existence gradient the number
    of parts differs between held-out chairs and some index is present on some chairs only.
    (At this scale, 1.2k + 1.8k iterations on 160 chairs, no index yet follows the arms: the largest
    difference in an index's presence between chairs with and without arms was 0.2, with parsimony
    2e-5 and 8e-5 alike; on ShapeNet chairs the bundled model's arm indices do, see the README.)"""
    def prep(shapes, offset):
        return [data.prepare(io.Mesh(s.vertices, s.faces), face_labels=s.face_labels, name=f"c{offset + i}")
                for i, s in enumerate(shapes)]

    train_set = prep(synthetic.generate("chair", 160, seed=0, rates={"has_arms": 0.5}), 0)
    held = synthetic.generate("chair", 40, seed=20_000, rates={"has_arms": 0.5})
    config = TrainConfig(stage1_iterations=1200, stage2_iterations=1800, existence_gradient="local", parsimony=2e-5)
    train(ShapeTensors(train_set), tmp_path / "chair.safetensors", config, progress=False)
    results = Abstractor.load(tmp_path / "chair.safetensors").predict(prep(held, 1000))
    present = np.array([r.canonical.existence for r in results])
    rate = present.mean(axis=0)
    assert len(set(present.sum(1).tolist())) >= 2, present.sum(1)
    assert np.any((rate >= 0.1) & (rate <= 0.9)), rate.round(2)
