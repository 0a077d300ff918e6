"""Batches beyond one machine: ``--shard K/N`` (job arrays) and ``--executor`` (a Dask cluster)
give the outputs of one local run, named alike, without clashes."""

import json
import sys

import numpy as np
import pytest

from primkit import data, parallel, synthetic
from primkit.cli import main

pytestmark = pytest.mark.integration  # Dask and Ray clusters started


def _outputs(folder):
    return {p.name: p.read_bytes() for p in sorted(folder.iterdir())}


@pytest.fixture(scope="module")
def shapes(tmp_path_factory):
    root = tmp_path_factory.mktemp("scale")
    # two folders of the same file names: the shards must name them as one run does (a-..., b-...)
    synthetic.write_collection(root / "in" / "a", "chair", 3, seed=2)
    synthetic.write_collection(root / "in" / "b", "chair", 2, seed=5)
    one = root / "one"
    assert main(["abstract", str(root / "in"), "--model", "chair", "-o", str(one), "--cache", str(root / "cache-one"),
                 "--workers", "1"]) == 0
    return root, _outputs(one)


def test_shards_together_give_one_runs_outputs(shapes, tmp_path):
    root, reference = shapes
    out = tmp_path / "sharded"
    seen = []
    for k in (1, 2):
        assert main(["abstract", str(root / "in"), "--model", "chair", "-o", str(out), "--cache", str(tmp_path / "cache"),
                     "--workers", "1", "--shard", f"{k}/2"]) == 0
        seen.append(set(_outputs(out)))
    assert seen[0] and seen[0] < seen[1]  # the first shard wrote a part, the second the rest
    got = _outputs(out)
    assert sorted(got) == sorted(reference)
    # the same cuboids: the network sees other batches (other shapes beside each), which moves
    # float32 results in the 7th digit, so numbers are compared, not bytes
    for name in (n for n in reference if n.endswith(".json")):
        a, b = json.loads(reference[name]), json.loads(got[name])
        assert [p["index"] for p in a["parts"]] == [p["index"] for p in b["parts"]], name
        for pa, pb in zip(a["parts"], b["parts"]):
            for key in ("translation", "half_extents", "quaternion_wxyz"):
                assert np.allclose(pa[key], pb[key], atol=1e-5), (name, key)
    assert any(name.startswith("a-") for name in reference) and any(name.startswith("b-") for name in reference)


def test_prepare_shards_fill_one_cache(shapes, tmp_path, capsys):
    root, _ = shapes
    cache = tmp_path / "cache"
    for k in (1, 2, 3):
        assert main(["prepare", str(root / "in"), "--cache", str(cache), "--workers", "1", "--shard", f"{k}/3"]) == 0
    capsys.readouterr()
    coll = data.prepare_collection(root / "in", cache_dir=cache, workers=1, progress=False)
    assert len(coll) == 5 and "preparing" not in capsys.readouterr().err  # every shape found, none prepared


def test_shard_option(monkeypatch):
    assert parallel.parse_shard("2/5") == (2, 5) and parallel.parse_shard(None) is None
    for bad in ("0/2", "3/2", "1", "a/b"):
        with pytest.raises(ValueError, match="shard"):
            parallel.parse_shard(bad)
    for var in ("RANK", "WORLD_SIZE", "SLURM_ARRAY_TASK_ID", "SLURM_ARRAY_TASK_MIN", "SLURM_ARRAY_TASK_COUNT",
                "SLURM_PROCID", "SLURM_NTASKS"):
        monkeypatch.delenv(var, raising=False)
    assert parallel.parse_shard("auto") is None
    monkeypatch.setenv("SLURM_PROCID", "3")
    monkeypatch.setenv("SLURM_NTASKS", "4")
    assert parallel.parse_shard("auto") == (4, 4)
    monkeypatch.setenv("SLURM_ARRAY_TASK_ID", "5")
    monkeypatch.setenv("SLURM_ARRAY_TASK_MIN", "1")
    monkeypatch.setenv("SLURM_ARRAY_TASK_COUNT", "8")
    assert parallel.parse_shard("auto") == (5, 8)
    monkeypatch.setenv("RANK", "0")
    monkeypatch.setenv("WORLD_SIZE", "2")
    assert parallel.parse_shard("auto") == (1, 2)  # torchrun's first
    shards = [parallel.shard_indices(11, (k, 3)) for k in (1, 2, 3)]
    assert sorted(sum(shards, [])) == list(range(11)) and not set(shards[0]) & set(shards[1])


def test_executor_on_a_dask_local_cluster(shapes, tmp_path):
    distributed = pytest.importorskip("distributed")
    root, reference = shapes
    out = tmp_path / "dask"
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as cluster:
        assert main(["abstract", str(root / "in"), "--model", "chair", "-o", str(out), "--cache", str(tmp_path / "cache"),
                     "--executor", cluster.scheduler_address]) == 0
    assert _outputs(out) == reference


# ------------------------------------------------------------------ segment


def _segment(root, out, cache, *extra):
    return main(["segment", str(root / "in"), "--model", "chair", "-o", str(out), "--cache", str(cache), "--workers", "1",
                 "--semantic", *extra])


@pytest.fixture(scope="module")
def segmented(shapes):
    """One local segment run over the five chairs (the cache abstract's run filled: the same settings)."""
    root, _ = shapes
    one = root / "seg-one"
    assert _segment(root, one, root / "cache-one") == 0
    return _outputs(one)


def _same_cuboids(a, b, name):
    a, b = json.loads(a), json.loads(b)
    assert [p["index"] for p in a["parts"]] == [p["index"] for p in b["parts"]], name
    for pa, pb in zip(a["parts"], b["parts"]):
        for key in ("translation", "half_extents", "quaternion_wxyz"):
            assert np.allclose(pa[key], pb[key], atol=1e-5), (name, key)


def _rows(text):
    lines = text.decode().splitlines()
    return lines[0], {line.split(",")[0]: line.split(",")[1:] for line in lines[1:]}


def test_segment_shards_together_give_one_runs_outputs(shapes, segmented, tmp_path, capsys):
    root, _ = shapes
    out = tmp_path / "sharded"
    for k in (1, 2):
        assert _segment(root, out, tmp_path / "cache", "--shard", f"{k}/2") == 0
    assert "summary of shard 2/2" in capsys.readouterr().out
    got = _outputs(out)
    shard_summaries = ["summary.shard-1-of-2.csv", "summary.shard-2-of-2.csv"]
    assert sorted(got) == sorted(set(segmented) - {"summary.csv"} | set(shard_summaries))
    shapes_of = [_rows(got[name])[1] for name in shard_summaries]
    assert len(shapes_of[0]) == 3 and len(shapes_of[1]) == 2 and not set(shapes_of[0]) & set(shapes_of[1])
    header, reference_rows = _rows(segmented["summary.csv"])
    assert all(_rows(got[name])[0] == header for name in shard_summaries)
    rows = {**shapes_of[0], **shapes_of[1]}
    assert sorted(rows) == sorted(reference_rows)
    for name, row in rows.items():  # faces, parts present alike; areas within float32 noise
        assert row[:2] == reference_rows[name][:2], name
        assert np.allclose(np.array(row[2:], float), np.array(reference_rows[name][2:], float), rtol=1e-5), name
    # labels and coloured meshes byte for byte: a face changes part only if its nearest cuboids tie
    # within the 1e-7 by which the shards' cuboids differ (other batch neighbours in the network)
    for name, content in segmented.items():
        if name.endswith((".seg", ".parts.ply")) or name == "labels.csv":
            assert got[name] == content, name
        elif name.endswith(".cuboids.json"):
            _same_cuboids(content, got[name], name)


def test_segment_shard_refuses_whole_collection_work(shapes, tmp_path, capsys):
    root, _ = shapes
    out = tmp_path / "out"
    assert _segment(root, out, tmp_path / "cache", "--shard", "1/2", "--gt", str(root / "in")) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--gt" in err[0] and "--shard" in err[0]
    assert _segment(root, out, tmp_path / "cache", "--shard", "2/2", "--png", str(tmp_path / "seg.png")) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--png" in err[0] and "--shard" in err[0]
    assert _segment(root, out, tmp_path / "cache", "--shard", "7/7") == 0  # 5 inputs: shard 7 holds none
    assert "none of the 5 inputs" in capsys.readouterr().out
    assert not out.exists()


def test_segment_rerun_of_a_shard_needs_force(shapes, segmented, tmp_path, capsys):
    """A shard rerun after a lost worker or a kill: what exists is refused without --force (each
    output was written whole), and --force redoes the shard's files."""
    root, _ = shapes
    out = tmp_path / "out"
    assert _segment(root, out, root / "cache-one", "--shard", "2/2") == 0
    lost = sorted(n for n in _outputs(out) if n.endswith(".seg"))[0]
    (out / lost).unlink()
    capsys.readouterr()
    assert _segment(root, out, root / "cache-one", "--shard", "2/2") == 2
    assert "exists" in capsys.readouterr().err and not (out / lost).exists()
    assert _segment(root, out, root / "cache-one", "--shard", "2/2", "--force") == 0
    assert (out / lost).read_bytes() == segmented[lost]


def test_segment_on_a_dask_local_cluster(shapes, segmented, tmp_path):
    distributed = pytest.importorskip("distributed")
    root, _ = shapes
    out = tmp_path / "dask"
    # a cold cache: preparation and labelling both run on the workers
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as cluster:
        assert _segment(root, out, tmp_path / "cache", "--executor", cluster.scheduler_address) == 0
        assert {"prepare_row", "segment_file"} <= set(cluster.scheduler.task_prefixes)  # dask drops the _
    assert _outputs(out) == segmented


def test_executor_on_a_local_ray_instance(shapes, segmented, tmp_path, monkeypatch):
    """abstract and segment with --executor ray on a Ray instance started here (2 CPUs): the
    outputs of the local runs, byte for byte."""
    ray = pytest.importorskip("ray")
    root, reference = shapes
    sent = []
    pool_map = parallel.distribute._PoolExecutor.map

    def map_(self, func, jobs):
        jobs = list(jobs)
        sent.append((func.__name__, len(jobs)))
        return pool_map(self, func, jobs)

    monkeypatch.setattr(parallel.distribute._PoolExecutor, "map", map_)
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    try:
        assert main(["abstract", str(root / "in"), "--model", "chair", "-o", str(tmp_path / "abstract"),
                     "--cache", str(tmp_path / "cache"), "--executor", "ray"]) == 0
        assert _segment(root, tmp_path / "seg", tmp_path / "cache-seg", "--executor", "ray") == 0
        assert ray.is_initialized()  # the caller's instance is left running
        # abstract: 5 shapes prepared there; segment (its own cold cache): 5 prepared, 5 labelled
        assert sent == [("_prepare_row", 5), ("_prepare_row", 5), ("_segment_file", 5)]
    finally:
        ray.shutdown()
    assert _outputs(tmp_path / "abstract") == reference
    assert _outputs(tmp_path / "seg") == segmented


def test_ray_addresses():
    assert parallel.distribute._ray_address("ray") is None
    assert parallel.distribute._ray_address("ray:auto") == "auto"
    assert parallel.distribute._ray_address("ray:10.0.0.1:6379") == "10.0.0.1:6379"
    assert parallel.distribute._ray_address("ray://head:10001") == "ray://head:10001"
    with pytest.raises(ValueError, match="ray:auto"):
        parallel.distribute._ray_address("ray:")


def test_a_missing_engine_is_one_line(shapes, tmp_path, monkeypatch, capsys):
    root, _ = shapes
    for module, address, words in (("ray", "ray", "needs Ray"), ("distributed", "tcp://127.0.0.1:8786", "needs dask")):
        monkeypatch.setitem(sys.modules, module, None)  # not installed
        assert main(["abstract", str(root / "in"), "--model", "chair", "-o", str(tmp_path / "out"),
                     "--cache", str(root / "cache-one"), "--executor", address]) == 2
        err = [line for line in capsys.readouterr().err.splitlines() if not line.startswith("primkit: note:")]
        assert len(err) == 1 and words in err[0] and address in err[0], err
    assert not (tmp_path / "out").exists()


def test_skip_done_reruns_only_what_is_missing(shapes, tmp_path, capsys):
    """A killed shard's rerun with --skip-done: no --force needed, the missing outputs (a whole pair,
    and the other half of a pair cut in two) are written under the names of one run, the rest left."""
    root, reference = shapes
    out = tmp_path / "out"
    cache = tmp_path / "cache"
    args = ["abstract", str(root / "in"), "--model", "chair", "-o", str(out), "--cache", str(cache), "--workers", "1"]
    assert main(args + ["--shard", "1/2"]) == 0
    first = sorted(_outputs(out))
    assert first
    # the worker "died": one pair lost, one cut in two; the untouched ones keep their times
    lost = first[0].split(".cuboids")[0]
    half = first[-1].split(".cuboids")[0]
    for p in out.glob(f"{lost}.cuboids.*"):
        p.unlink()
    (out / f"{half}.cuboids.ply").unlink()
    kept = {p.name: p.stat().st_mtime_ns for p in out.iterdir()}
    capsys.readouterr()
    assert main(args + ["--shard", "1/2", "--skip-done"]) == 0
    assert sorted(_outputs(out)) == first
    assert "1 of 3 input(s) already done" in capsys.readouterr().err
    assert all(out.joinpath(n).stat().st_mtime_ns == t for n, t in kept.items() if not n.startswith(half))
    # then the second shard, and a rerun of everything that finds it all done
    assert main(args + ["--shard", "2/2", "--skip-done"]) == 0
    assert sorted(_outputs(out)) == sorted(reference)
    capsys.readouterr()
    assert main(args + ["--skip-done"]) == 0
    assert "5 of 5 input(s) already done" in capsys.readouterr().err
    # without --skip-done a rerun still refuses to overwrite
    assert main(args) != 0


def test_segment_skip_done_redoes_only_what_a_cut_run_left(shapes, segmented, tmp_path, capsys):
    """A shard cut short, rerun with --skip-done: a shape with all its files stays untouched, a
    shape lost whole or in part (a missing cuboids file, a missing summary row) is redone, and the
    summary is rewritten with every row of the shard, in input order, without --force."""
    root, _ = shapes
    out = tmp_path / "out"
    cache = root / "cache-one"
    assert _segment(root, out, cache, "--shard", "1/2") == 0
    full = _outputs(out)
    summary = "summary.shard-1-of-2.csv"
    header, rows = _rows(full[summary])
    first, second, third = list(rows)
    for p in out.glob(f"{first}.*"):  # lost whole
        p.unlink()
    (out / f"{second}.cuboids.json").unlink()  # cut before its cuboids
    lines = full[summary].decode().splitlines(keepends=True)  # and the third's row never written
    (out / summary).write_text("".join(line for line in lines if not line.startswith(f"{third},")))
    capsys.readouterr()
    assert _segment(root, out, cache, "--shard", "1/2", "--skip-done") == 0
    assert "0 of 3 input(s) already done" in capsys.readouterr().err
    got = _outputs(out)
    assert sorted(got) == sorted(full)
    assert _rows(got[summary]) == (header, rows) and list(_rows(got[summary])[1]) == [first, second, third]
    for name, content in full.items():
        if name.endswith((".seg", ".parts.ply")) or name in ("labels.csv", summary):
            assert got[name] == content, name
    # a rerun finds it all done and writes nothing
    times = {n: (out / n).stat().st_mtime_ns for n in got}
    capsys.readouterr()
    assert _segment(root, out, cache, "--shard", "1/2", "--skip-done") == 0
    assert "3 of 3 input(s) already done" in capsys.readouterr().err
    assert {n: (out / n).stat().st_mtime_ns for n in got} == times
    # one shape lost again: only it is redone, the others' files keep their times
    (out / f"{second}.seg").unlink()
    kept = {n: (out / n).stat().st_mtime_ns for n in got if not n.startswith(second) and n != summary}
    assert _segment(root, out, cache, "--shard", "1/2", "--skip-done") == 0
    assert "2 of 3 input(s) already done" in capsys.readouterr().err
    assert _outputs(out) == got and all((out / n).stat().st_mtime_ns == t for n, t in kept.items())
    # the whole collection needs one run without --skip-done for --gt and --png
    assert _segment(root, out, cache, "--skip-done", "--png", str(tmp_path / "seg.png")) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--png" in err[0] and "--skip-done" in err[0]
