"""Tests for primkit.model.modelfile: round trip, refusal to overwrite, rejection of foreign files."""

import json
import os
import pickle

import numpy as np
import pytest
import torch
from safetensors.torch import save_file

from primkit.model.modelfile import FORMAT_VERSION, ModelFileError, load_model_file, read_metadata, save_model
from primkit.model.network import AbstractionNet, NetworkConfig


def example_metadata():
    return {
        "network": NetworkConfig(parts=4).to_dict(),
        "canonical_frame": {"up": "+Y", "front": "+X", "centre": "bbox", "scale": "longest side 1"},
        "grid": 32,
        "training": {"data": "test", "iterations": [2, 3], "seed": 0, "time_s": 1.5},
        "metrics": {"chamfer_l1": 0.012},
        "part_names": ["seat", "back", "", "leg"],
        "created": "2024-01-01T00:00:00+00:00",
        "primkit_version": "0.1.0",
    }


def saved_model(tmp_path, name="model.safetensors"):
    torch.manual_seed(0)
    net = AbstractionNet(NetworkConfig(parts=4))
    net.set_head_scales(0.5, 0.2)
    path = save_model(tmp_path / name, net.state_dict(), example_metadata())
    return path, net


def assert_one_line_naming(err, path):
    message = str(err)
    assert "\n" not in message
    assert message.startswith(f"{path}: ")


def test_round_trip(tmp_path):
    path, net = saved_model(tmp_path)
    assert path == tmp_path / "model.safetensors" and path.is_file()
    assert [p.name for p in tmp_path.iterdir()] == ["model.safetensors"]  # no temporary left behind
    weights, metadata = load_model_file(path)
    state = net.state_dict()
    assert weights.keys() == state.keys()
    for name, tensor in state.items():
        assert weights[name].dtype == tensor.dtype and weights[name].shape == tensor.shape
        assert torch.equal(weights[name], tensor), name  # bit-identical
    assert metadata == {**example_metadata(), "format": "primkit-model", "format_version": FORMAT_VERSION}
    assert read_metadata(path) == metadata
    # the weights rebuild the same network
    other = AbstractionNet(NetworkConfig.from_dict(metadata["network"]))
    other.load_state_dict(weights)
    assert other.shape_scale == pytest.approx(0.5)


def test_defaults_filled_and_input_untouched(tmp_path):
    meta = {"network": NetworkConfig().to_dict(), "part_names": None}
    path = save_model(tmp_path / "m.safetensors", {"w": torch.arange(6.0).view(2, 3)}, meta)
    assert meta == {"network": NetworkConfig().to_dict(), "part_names": None}
    loaded = read_metadata(path)
    assert loaded["part_names"] is None
    assert loaded["primkit_version"] and loaded["created"]


def test_refuses_to_overwrite(tmp_path):
    path, _ = saved_model(tmp_path)
    before = path.read_bytes()
    with pytest.raises(FileExistsError) as info:
        save_model(path, {"w": torch.zeros(2)}, example_metadata())
    assert_one_line_naming(info.value, path)
    assert "--force" in str(info.value)
    assert path.read_bytes() == before
    save_model(path, {"w": torch.zeros(2)}, example_metadata(), overwrite=True)
    weights, _ = load_model_file(path)
    assert list(weights) == ["w"]


def test_rejects_non_json_metadata(tmp_path):
    meta = example_metadata()
    meta["metrics"] = {"chamfer": np.float32(0.1)}
    with pytest.raises(TypeError, match="chamfer"):
        save_model(tmp_path / "a.safetensors", {"w": torch.zeros(1)}, meta)
    meta["metrics"] = {"chamfer": float("nan")}
    with pytest.raises(ValueError, match="chamfer"):
        save_model(tmp_path / "a.safetensors", {"w": torch.zeros(1)}, meta)
    with pytest.raises(ValueError, match="network"):
        save_model(tmp_path / "a.safetensors", {"w": torch.zeros(1)}, {"grid": 32})
    assert not list(tmp_path.iterdir())


class _Payload:
    """Unpickling this creates the marker file: a stand-in for malicious code in a pickle."""

    def __init__(self, marker):
        self.marker = str(marker)

    def __reduce__(self):
        return (open, (self.marker, "w"))


def test_rejects_pickle_without_running_it(tmp_path):
    marker = tmp_path / "marker"
    evil = tmp_path / "evil.pt"
    torch.save({"weights": torch.zeros(3), "payload": _Payload(marker)}, evil)
    disguised = tmp_path / "evil.safetensors"  # same bytes under our extension
    disguised.write_bytes(evil.read_bytes())
    legacy = tmp_path / "legacy.pt"
    torch.save({"payload": _Payload(marker)}, legacy, _use_new_zipfile_serialization=False)
    raw = tmp_path / "raw.pkl"
    raw.write_bytes(pickle.dumps(_Payload(marker)))
    assert not marker.exists()

    # the payload is live: unpickling the file the unsafe way does create the marker
    # (torch.load reads files named *.safetensors as safetensors, hence the .pt copy)
    torch.load(evil, weights_only=False)
    assert marker.exists()
    marker.unlink()

    for path in (evil, disguised, legacy, raw):
        with pytest.raises(ModelFileError) as info:
            load_model_file(path)
        assert_one_line_naming(info.value, path)
        with pytest.raises(ModelFileError):
            read_metadata(path)
        assert not marker.exists(), path


def test_rejects_random_bytes_and_empty_file(tmp_path):
    noise = tmp_path / "noise.safetensors"
    noise.write_bytes(np.random.default_rng(0).bytes(4096))
    empty = tmp_path / "empty.safetensors"
    empty.write_bytes(b"")
    for path in (noise, empty):
        with pytest.raises(ModelFileError) as info:
            load_model_file(path)
        assert_one_line_naming(info.value, path)


def test_rejects_truncated_file(tmp_path):
    path, _ = saved_model(tmp_path)
    data = path.read_bytes()
    for keep in (len(data) - 100, len(data) // 2, 12, 5):
        cut = tmp_path / f"cut{keep}.safetensors"
        cut.write_bytes(data[:keep])
        with pytest.raises(ModelFileError) as info:
            load_model_file(cut)
        assert_one_line_naming(info.value, cut)


def test_rejects_missing_file_and_directory(tmp_path):
    for path in (tmp_path / "nope.safetensors", tmp_path):
        with pytest.raises(ModelFileError) as info:
            load_model_file(path)
        assert_one_line_naming(info.value, path)


def test_rejects_plain_safetensors(tmp_path):
    plain = tmp_path / "plain.safetensors"
    save_file({"w": torch.zeros(2)}, plain)
    other = tmp_path / "other.safetensors"
    save_file({"w": torch.zeros(2)}, other, metadata={"format": "pt"})
    foreign = tmp_path / "foreign.safetensors"
    save_file({"w": torch.zeros(2)}, foreign, metadata={"primkit": json.dumps({"hello": 1})})
    for path in (plain, other, foreign):
        with pytest.raises(ModelFileError, match="not a primkit model file") as info:
            load_model_file(path)
        assert_one_line_naming(info.value, path)
    bad_json = tmp_path / "bad.safetensors"
    save_file({"w": torch.zeros(2)}, bad_json, metadata={"primkit": "{not json"})
    with pytest.raises(ModelFileError, match="JSON") as info:
        read_metadata(bad_json)
    assert_one_line_naming(info.value, bad_json)


def _rewrite_metadata(path, target, change):
    """Copy the model file at ``path`` to ``target`` with its primkit metadata passed through ``change``."""
    from safetensors import safe_open

    with safe_open(str(path), framework="pt") as f:
        meta = json.loads(f.metadata()["primkit"])
        tensors = {k: f.get_tensor(k) for k in f.keys()}
    change(meta)
    save_file(tensors, target, metadata={"primkit": json.dumps(meta)})
    return target


def test_rejects_newer_format_version(tmp_path):
    path, _ = saved_model(tmp_path)
    newer = _rewrite_metadata(
        path, tmp_path / "newer.safetensors", lambda m: m.update(format_version=FORMAT_VERSION + 1)
    )
    for read in (load_model_file, read_metadata):
        with pytest.raises(ModelFileError) as info:
            read(newer)
        assert_one_line_naming(info.value, newer)
        expected = (
            f"format version {FORMAT_VERSION + 1} is newer than this primkit supports "
            f"({FORMAT_VERSION}); upgrade primkit"
        )
        assert expected in str(info.value)


def test_rejects_missing_required_keys(tmp_path):
    path, _ = saved_model(tmp_path)
    lacking = _rewrite_metadata(path, tmp_path / "lacking.safetensors", lambda m: m.pop("network"))
    with pytest.raises(ModelFileError, match="network") as info:
        load_model_file(lacking)
    assert_one_line_naming(info.value, lacking)


def test_error_is_value_error_with_path(tmp_path):
    err = ModelFileError(tmp_path / "x", "line one\nline two")
    assert isinstance(err, ValueError)
    assert str(err) == f"{tmp_path / 'x'}: line one line two"


def test_saves_to_relative_path(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    path = save_model("rel.safetensors", {"w": torch.ones(2)}, example_metadata())
    assert load_model_file(path)[1]["grid"] == 32
    assert os.listdir(tmp_path) == ["rel.safetensors"]


_REFERENCE = {"median": 0.006, "log_spread": 0.7, "shapes": 400, "data": "held-out chairs"}


@pytest.mark.parametrize("reference", [None, "x", [1], {**_REFERENCE, "median": 0}, {**_REFERENCE, "median": -1.0},
                                       {**_REFERENCE, "median": float("nan")}, {**_REFERENCE, "log_spread": -0.1},
                                       {**_REFERENCE, "log_spread": True}, {**_REFERENCE, "shapes": 1},
                                       {**_REFERENCE, "shapes": 2.5}, {**_REFERENCE, "data": 3},
                                       {k: v for k, v in _REFERENCE.items() if k != "data"}, {**_REFERENCE, "extra": 1}])
def test_a_hostile_fit_reference_is_refused_in_one_line(tmp_path, reference):
    path, _ = saved_model(tmp_path)
    good = _rewrite_metadata(path, tmp_path / "good.safetensors", lambda m: m.update(fit_reference=_REFERENCE))
    assert read_metadata(good)["fit_reference"] == _REFERENCE
    bad = _rewrite_metadata(path, tmp_path / "bad.safetensors", lambda m: m.update(fit_reference=reference))
    for read in (load_model_file, read_metadata):
        with pytest.raises(ModelFileError, match="fit_reference") as info:
            read(bad)
        assert_one_line_naming(info.value, bad)
