"""A run over a collection planned once, in the library (:func:`primkit.data.plan_run`): which files,
their unique names, the shard, what a cut run finished, the outputs checked before any work; and the
library functions that take the plan (prepare_collection, abstract_shapes, Segmenter.run) doing only
what it says, with shards, --skip-done and an executor from the library alone."""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor

import pytest

from primkit import data, io, parallel, synthetic


@pytest.fixture(scope="module")
def collection(tmp_path_factory):
    root = tmp_path_factory.mktemp("plan")
    # two folders with the same file names: the plan names them apart, as one run over all of them
    synthetic.write_collection(root / "in" / "a", "chair", 3, seed=2)
    synthetic.write_collection(root / "in" / "b", "chair", 2, seed=5)
    return root


def test_a_plan_names_every_file_once_and_shards_them_as_one_run(collection, tmp_path):
    plan = data.plan_run([collection / "in"], tmp_path, outputs=(".cuboids.json", ".cuboids.ply"))
    files = sorted((collection / "in").rglob("*.ply"))
    assert plan.files == files and len(set(plan.names)) == 5
    assert plan.names == data.shape_names(files)  # what prepare_collection names them
    assert plan.todo == [0, 1, 2, 3, 4] and plan.done == [] and plan.selection is None
    shards = [data.plan_run([collection / "in"], tmp_path, outputs=(".x",), shard=f"{k}/2") for k in (1, 2)]
    # disjoint, together every file, every n-th from the k-th, the names of the whole run
    assert shards[0].todo == [0, 2, 4] and shards[1].todo == [1, 3]
    assert all(s.names == plan.names for s in shards)
    assert [p.name for p in shards[1].written()] == [f"{plan.names[i]}.x" for i in (1, 3)]


def test_skip_done_leaves_what_a_cut_run_finished_and_removes_what_it_left(collection, tmp_path):
    plan = data.plan_run([collection / "in"], tmp_path, outputs=(".j", ".m"), shard=(1, 2))
    names = [plan.names[i] for i in plan.todo]
    for name in names:  # the first shape finished, the other two cut between their two files
        (tmp_path / f"{name}.j").write_text("old")
    (tmp_path / f"{names[0]}.m").write_text("old")
    again = data.plan_run([collection / "in"], tmp_path, outputs=(".j", ".m"), shard=(1, 2), skip_done=True)
    assert again.done == [plan.todo[0]] and again.todo == plan.todo[1:]
    assert isinstance(again.selection, parallel.Selection) and again.selection.positions == plan.todo[1:]
    assert sorted(p.name for p in again.leftovers) == sorted(f"{n}.j" for n in names[1:])
    again.check(overwrite=False)  # the leftovers go; nothing else stands in the way
    assert sorted(p.name for p in tmp_path.iterdir()) == [f"{names[0]}.j", f"{names[0]}.m"]
    with pytest.raises(FileExistsError):  # without skip_done the finished outputs are not overwritten
        plan.check(overwrite=False)


def test_a_plan_never_writes_over_what_it_reads(collection):
    plan = data.plan_run([collection / "in" / "a"], collection / "in" / "a", outputs=(".seg",))
    with pytest.raises(io.OutputError):
        plan.check(overwrite=True)


def test_an_empty_folder_is_one_line_before_any_work(tmp_path):
    (tmp_path / "empty").mkdir()
    with pytest.raises(FileNotFoundError, match="no shape files"):
        data.plan_run([tmp_path / "empty"])


def test_prepare_collection_takes_the_plan(collection, tmp_path):
    plan = data.plan_run([collection / "in"], shard="2/2")
    coll = data.prepare_collection(plan, data.PrepareSettings(samples=200), cache_dir=tmp_path / "cache", workers=1)
    assert [str(p) for p in coll.paths] == [str(plan.files[i]) for i in plan.todo]
    assert [coll.name(i) for i in range(len(coll))] == [plan.names[i] for i in plan.todo]


@pytest.mark.integration  # shards and an executor run in full: seconds, left to the default suite
def test_shards_skip_done_and_an_executor_from_the_library(collection, tmp_path):
    """Segmenter.run and abstract_shapes given a plan: a shard writes its shapes' outputs only; a
    rerun with skip_done redoes only the shape whose files were lost; an executor runs the work."""
    from primkit.model.abstraction import abstract_shapes
    from primkit.segmentation import Segmenter

    cache, out = tmp_path / "cache", tmp_path / "seg"
    segmenter = Segmenter("chair")
    with ThreadPoolExecutor(2) as pool:
        run = segmenter.run([collection / "in"], out, shard=(1, 2), cache_dir=cache, workers=1, executor=pool)
    assert not run.errors and [s.name for s in run.segmentations] == [run.plan.names[i] for i in (0, 2, 4)]
    written = sorted(p.name for p in out.iterdir())
    assert written == sorted([f"{n}{ext}" for n in run.plan.todo_names for ext in (".seg", ".parts.ply", ".cuboids.json")]
                             + ["summary.shard-1-of-2.csv"])
    from primkit.model.cuboids_file import read_cuboids_file

    kept = read_cuboids_file(out / f"{run.plan.todo_names[0]}.cuboids.json")  # the one schema, with the frame
    assert kept.schema_version == 2 and kept.canonical_frame is not None and kept.model == "chair"
    assert kept.part_names == segmenter.part_names
    lost = run.plan.todo_names[1]
    (out / f"{lost}.cuboids.json").unlink()
    again = segmenter.run([collection / "in"], out, shard="1/2", skip_done=True, cache_dir=cache, workers=1)
    assert again.plan.done == [0, 4] and [s.name for s in again.segmentations] == [lost]
    assert sorted(p.name for p in out.iterdir()) == written
    # abstract_shapes takes a plan too: what it does of the files, named by it
    plan = data.plan_run([collection / "in"], shard=(2, 2))
    shapes = abstract_shapes(plan, segmenter.abstractor, cache=cache, workers=1)
    assert [a.name for a in shapes] == plan.todo_names
