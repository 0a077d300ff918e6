"""Adapting a model to a collection without labels: deterministic, indices kept, recorded, saved."""

import numpy as np
import pytest
import torch

from primkit import data, io, synthetic
from primkit.model.abstractor import Abstractor
from primkit.model.adaptation import AdaptConfig, adapt, collection_digest, index_agreement, save_adapted


@pytest.fixture(scope="module")
def parent():
    return Abstractor.load("chair")


@pytest.fixture(scope="module")
def shapes():
    made = synthetic.generate("chair", 3, seed=11)
    return [data.prepare(io.Mesh(s.vertices, s.faces), name=f"c{i}") for i, s in enumerate(made)]


def test_adapting_is_deterministic_keeps_the_parent_and_records_itself(parent, shapes, tmp_path):
    before = {k: v.clone() for k, v in parent.network.state_dict().items()}
    config = AdaptConfig(steps=4, batch_size=4, seed=3)
    a = adapt(parent, shapes, config)
    b = adapt(parent, shapes, config)
    for k, v in parent.network.state_dict().items():  # the parent is unchanged
        assert torch.equal(v, before[k]), k
    moved = False
    for (k, va), vb in zip(a.network.state_dict().items(), b.network.state_dict().values()):
        assert torch.equal(va, vb), k  # the same seed: the same weights
        moved |= not torch.equal(va, before[k])
    assert moved
    other = adapt(parent, shapes, AdaptConfig(steps=4, batch_size=4, seed=4))
    assert any(not torch.equal(x, y) for x, y in zip(a.network.parameters(), other.network.parameters()))
    info = a.metadata["adaptation"]
    assert info["shapes"] == 3 and info["digest"] == collection_digest(shapes) and info["labels_used"] is False
    assert info["config"]["steps"] == 4 and "adaptation" not in parent.metadata
    # a few small steps keep the part indices: nearly every surface sample keeps its part
    agreement = index_agreement(parent.predict(shapes, align="auto"), a.predict(shapes, align="auto"), shapes)
    assert agreement > 0.9
    path = save_adapted(a, tmp_path / "mine.safetensors")
    loaded = Abstractor.load(path)
    assert loaded.metadata["adaptation"]["digest"] == info["digest"]
    x = np.stack([s.occupancy for s in shapes])
    np.testing.assert_allclose(loaded.predict_canonical(x)["translations"], a.predict_canonical(x)["translations"],
                               atol=1e-6)


def test_bad_settings_are_refused(parent, shapes):
    with pytest.raises(ValueError, match="weights"):
        adapt(parent, shapes, AdaptConfig(steps=1, weights="encoder"))
    with pytest.raises(ValueError, match="no shapes"):
        adapt(parent, [], AdaptConfig(steps=1))
