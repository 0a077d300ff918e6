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
        assert agreement["per_label"][part]["agreement"] >= 0.9, (part, agreement["per_label"][part])
    summary = summarize([score(r.canonical, s, ChamferConvention()) for r, s in zip(results, held_out)])
    assert summary["iou"]["mean"] > 0.3
