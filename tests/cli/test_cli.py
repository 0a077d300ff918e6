"""The command line end to end: generate, prepare, train, abstract, eval, info, demo; bad input."""

import hashlib
import json
from pathlib import Path

import pytest

from primkit import primitives
from primkit.cli import main


def digest(folder):
    return {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in sorted(folder.iterdir()) if p.is_file()}


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    root = tmp_path_factory.mktemp("cli")
    shapes = root / "shapes"
    assert main(["generate", "chair", "-n", "6", "-o", str(shapes), "--seed", "3"]) == 0
    model = root / "m.safetensors"
    code = main(["train", str(shapes), "-o", str(model), "--stage1", "30", "--stage2", "20", "--parts", "6",
                 "--batch-size", "6", "--cache", str(root / "cache"), "--workers", "1", "--data-terms", "procedural"])
    assert code == 0
    return root, shapes, model


def test_train_writes_model_plot_and_metadata(trained, capsys):
    root, shapes, model = trained
    from pictures import read_picture

    plot = read_picture(root / "m.training.png")  # the losses and the parts in use, as coloured curves
    assert plot.foreground_fraction > 0.02 and plot.coloured_pixels > 300
    assert main(["info", str(model)]) == 0
    meta = json.loads(capsys.readouterr().out)
    assert meta["training"]["iterations"] == 50 and meta["training"]["data"]["terms"] == "procedural"
    assert meta["format_version"] == 1


def test_abstract_batch_goes_on_past_a_bad_file(trained, tmp_path, capsys):
    root, shapes, model = trained
    inputs = tmp_path / "in"
    inputs.mkdir()
    for p in sorted(shapes.glob("*.ply"))[:2]:
        (inputs / p.name).write_bytes(p.read_bytes())
    (inputs / "empty.obj").write_text("")
    before = digest(inputs)
    out = tmp_path / "out"
    code = main(["abstract", str(inputs), "--model", str(model), "-o", str(out), "--cache", str(tmp_path / "c"), "--workers", "1"])
    err = capsys.readouterr().err
    assert code == 1
    assert "empty.obj" in err and len([l for l in err.splitlines() if "empty.obj" in l]) == 1
    assert digest(inputs) == before  # inputs never modified
    jsons = sorted(out.glob("*.cuboids.json"))
    assert len(jsons) == 2 and len(list(out.glob("*.cuboids.ply"))) == 2
    d = json.loads(jsons[0].read_text())
    assert d["schema_version"] == 2 and len(d["parts"]) == 6  # absent parts kept, indices stable
    assert d["frame"] == "input" and d["canonical_frame"] is not None and Path(d["model"]).name == Path(model).name
    assert len(d["part_names"]) == 6 and d["present"] == [p["index"] for p in d["parts"] if p["present"]]
    cub = primitives.Cuboids.from_dict(d)
    assert [p["index"] for p in d["parts"]] == list(range(6))
    # results are in the input's frame: the cuboids overlap the input mesh's bounding box
    import trimesh

    mesh = trimesh.load(inputs / jsons[0].name.replace(".cuboids.json", ".ply"), process=False)
    lo, hi = mesh.bounds
    centres = cub.translations[cub.existence]
    assert ((centres > lo - 0.1 * (hi - lo)) & (centres < hi + 0.1 * (hi - lo))).all()
    # nothing is overwritten without --force: refused before any work, in one line
    stamp = jsons[0].stat().st_mtime_ns
    code = main(["abstract", str(inputs / jsons[0].name.replace(".cuboids.json", ".ply")), "--model", str(model),
                 "-o", str(out), "--cache", str(tmp_path / "c"), "--workers", "1"])
    assert code == 2 and jsons[0].stat().st_mtime_ns == stamp
    err = capsys.readouterr().err
    assert "--force" in err and len(err.strip().splitlines()) == 1


def test_eval_prints_the_convention(trained, tmp_path, capsys):
    root, shapes, model = trained
    code = main(["eval", str(shapes), "--model", str(model), "--cache", str(root / "cache"), "--workers", "1",
                 "--json", str(tmp_path / "scores.json")])
    out = capsys.readouterr().out
    assert code == 0
    assert "Chamfer-L1" in out and "unsquared" in out and "10000" in out
    scores = json.loads((tmp_path / "scores.json").read_text())
    assert scores["summary"]["count"] == 6
    assert 0 <= scores["summary"]["iou"]["mean"] <= 1


def test_bad_model_and_existing_output(trained, tmp_path, capsys):
    root, shapes, model = trained
    bogus = tmp_path / "bogus.safetensors"
    bogus.write_bytes(b"\x00" * 100)
    assert main(["abstract", str(shapes), "--model", str(bogus), "-o", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("primkit: error: ") and str(bogus) in err and "\n" not in err
    assert main(["train", str(shapes), "-o", str(model)]) == 2
    assert "exists" in capsys.readouterr().err
    assert main(["abstract", str(tmp_path / "missing"), "--model", str(model), "-o", str(tmp_path / "o")]) == 2


@pytest.mark.integration  # the main job end to end
def test_demo_quick(tmp_path):
    out = tmp_path / "demo"
    assert main(["demo", "--quick", "-o", str(out)]) == 0
    report = json.loads((out / "report.json").read_text())
    assert "Chamfer" in report["convention"] and report["summary"]["count"] == 4
    import numpy as np
    from pictures import read_picture

    from primkit.primitives import Cuboids

    present = set()
    for f in (out / "abstractions").glob("*.cuboids.json"):
        present |= set(np.flatnonzero(Cuboids.from_dict(json.loads(f.read_text())).existence))
    shown = read_picture(out / "abstractions.png").part_colours_shown(present)
    assert sum(n >= 20 for n in shown.values()) >= len(shown) // 2, shown  # each part in its colour
    assert len(list((out / "abstractions").glob("*.cuboids.json"))) == 4
    bundled = json.loads((out / "bundled.json").read_text())  # the bundled chair model's step
    assert set(bundled) >= {"as given", "turned, align auto", "refined"}
    bundled_picture = read_picture(out / "bundled.png")
    assert bundled_picture.foreground_fraction > 0.05 and bundled_picture.coloured_pixels > 2000
    assert main(["demo", "--quick", "-o", str(out)]) == 2  # refuses to overwrite without --force


def test_hold_out_is_recorded_and_eval_split_uses_it(tmp_path, capsys):
    shapes = tmp_path / "shapes"
    assert main(["generate", "chair", "-n", "6", "-o", str(shapes), "--seed", "5"]) == 0
    model = tmp_path / "h.safetensors"
    assert main(["train", str(shapes), "-o", str(model), "--stage1", "4", "--stage2", "4", "--parts", "4", "--batch-size", "4",
                 "--hold-out", "3", "--cache", str(tmp_path / "c"), "--workers", "1"]) == 0
    assert "(2 held out)" in capsys.readouterr().err
    assert main(["info", str(model)]) == 0
    meta = json.loads(capsys.readouterr().out)
    assert meta["training"]["shapes"] == 4
    assert meta["training"]["data"]["hold_out_every"] == 3 and meta["training"]["data"]["held_out"] == 2
    report = tmp_path / "held.json"
    assert main(["eval", str(shapes), "--model", str(model), "--split", "held-out", "--json", str(report),
                 "--cache", str(tmp_path / "c"), "--workers", "1"]) == 0
    held = json.loads(report.read_text())["shapes"]
    # sorted .ply files of rank 2 and 5 (rank % 3 == 2) are the held-out ones
    names = sorted(p.stem for p in shapes.glob("*.ply"))
    assert sorted(held) == [names[2], names[5]]


def test_eval_split_needs_a_recorded_rule(trained, capsys):
    root, shapes, model = trained
    assert main(["eval", str(shapes), "--model", str(model), "--split", "held-out", "--cache", str(root / "cache")]) == 2
    assert "held-out rule" in capsys.readouterr().err


def test_abstract_align_and_refine_are_recorded_in_the_input_frame(trained, tmp_path, capsys):
    root, shapes, model = trained
    src = sorted(shapes.glob("*.ply"))[0]
    out = tmp_path / "out"
    assert main(["abstract", str(src), "--model", str(model), "-o", str(out), "--align", "auto", "--refine", "25",
                 "--cache", str(root / "cache"), "--workers", "1"]) == 0
    assert "oriented with up" in capsys.readouterr().out
    d = json.loads((out / f"{src.stem}.cuboids.json").read_text())
    assert set(d["alignment"]) >= {"rotation", "up", "front", "loss", "loss_as_given"}
    assert d["alignment"]["loss"] <= d["alignment"]["loss_as_given"]
    assert d["refinement"]["steps"] == 25 and d["refinement"]["loss_after"] < d["refinement"]["loss_before"]
    import trimesh

    mesh = trimesh.load(src, process=False)
    cub = primitives.Cuboids.from_dict(d)
    lo, hi = mesh.bounds
    centres = cub.translations[cub.existence]
    assert ((centres > lo - 0.1 * (hi - lo)) & (centres < hi + 0.1 * (hi - lo))).all()


def test_unknown_model_name_lists_the_bundled_ones(tmp_path, capsys):
    from primkit.model.bundled import bundled_models

    assert main(["abstract", str(tmp_path), "--model", "no-such-model", "-o", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip()
    assert "no-such-model" in err and "bundled" in err and "\n" not in err
    assert main(["models"]) == 0
    out = capsys.readouterr().out
    for name in bundled_models():
        assert f"== {name}" in out


def test_generate_rates_and_their_bad_forms(tmp_path, capsys):
    out = tmp_path / "armed"
    assert main(["generate", "chair", "-n", "3", "-o", str(out), "--rate", "has_arms=1"]) == 0
    assert all(json.loads(p.read_text())["attributes"]["has_arms"] for p in sorted(out.glob("*.json")))
    capsys.readouterr()
    for bad, words in ((["--rate", "has_arms=lots"], "ATTRIBUTE=FRACTION"), (["--rate", "wheels=0.5"], "yes/no"),
                       (["--rate", "has_arms=2"], "[0, 1]")):
        assert main(["generate", "chair", "-n", "1", "-o", str(tmp_path / "bad"), *bad]) == 2
        err = capsys.readouterr().err.strip()
        assert err.startswith("primkit: error: ") and words in err and "\n" not in err
    assert not (tmp_path / "bad").exists()
