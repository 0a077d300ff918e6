"""What the checks made before any work cost (issue 19), each against the straightforward alternative:

* ``io.check_outputs`` of a large batch's outputs (writable folder, not an input, not twice, exists)
  against ``io.refuse_existing`` alone (does each output exist);
* ``data.find_shape_files`` (``os.walk`` following symbolic links, once per folder, skipping killed
  writes' temporaries) against the former ``Path.rglob`` scan;
* ``data.shape_names`` (unique names) against ``shape_name`` of each path;
* loading a model with its checks (``network.read_network``: header, bounds, the tensors of a network
  built on torch's ``meta`` device) against loading it unchecked (read the file, build, load).

    python benchmarks/bench_checks.py [--files 20000]
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

from _common import table  # noqa: E402


def best(fn, repeats=5):
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return min(times)


def ms(seconds):
    return f"{1000 * seconds:.1f}"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--files", type=int, default=20000, help="shape files in the synthetic tree")
    args = parser.parse_args(argv)
    print(f"load average at start: {os.getloadavg()[0]:.1f}")

    import torch

    from primkit import data, io
    from primkit.model.bundled import resolve_model
    from primkit.model.modelfile import load_model_file
    from primkit.model.network import AbstractionNet, NetworkConfig, read_network

    torch.set_num_threads(1)
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp) / "shapes"
        per = 200  # files per folder
        for i in range(args.files):
            folder = root / f"d{i // per:03d}"
            if i % per == 0:
                folder.mkdir(parents=True)
            (folder / f"s{i:06d}.ply").touch()
        (root / "d000" / ".s000000.ply.0a1b2c3d.tmp.ply").touch()
        files = data.find_shape_files(root)
        old = sorted(p for p in root.rglob("*") if p.is_file() and io.is_shape_file(p))
        out = Path(tmp) / "out"
        outputs = [out / f"{n}.cuboids{ext}" for n in data.shape_names(files) for ext in (".json", ".ply")]
        inputs = [p for f in files for p in data.input_files(f)]
        rows = [
            [f"check_outputs: {len(outputs)} outputs, {len(inputs)} inputs", ms(best(lambda: io.check_outputs(outputs, inputs=inputs))),
             ms(best(lambda: io.refuse_existing(outputs))), "refuse_existing alone"],
            [f"find_shape_files: {args.files} files in {args.files // per} folders", ms(best(lambda: data.find_shape_files(root))),
             ms(best(lambda: sorted(p for p in root.rglob("*") if p.is_file() and io.is_shape_file(p)))), "Path.rglob"],
            [f"shape_names: {len(files)} paths", ms(best(lambda: data.shape_names(files))),
             ms(best(lambda: [data.shape_name(p) for p in files])), "shape_name of each"],
        ]
        dup = files + [Path(str(p).replace("shapes", "copy")) for p in files[:1000]]
        rows.append([f"shape_names: {len(dup)} paths, 1000 names shared", ms(best(lambda: data.shape_names(dup))),
                     ms(best(lambda: [data.shape_name(p) for p in dup])), "shape_name of each"])
    print(f"(the rglob scan found {len(old)} files, the temporary among them; find_shape_files {len(files)})")

    path = resolve_model("chair")

    def unchecked():
        weights, meta = load_model_file(path)
        net = AbstractionNet(NetworkConfig.from_dict(meta["network"]))
        net.load_state_dict(weights)

    def checked():
        config, _ = read_network(path)
        weights, _ = load_model_file(path)
        AbstractionNet(config).load_state_dict(weights)

    rows.append(["load the bundled chair model, checked", ms(best(checked, 10)), ms(best(unchecked, 10)), "unchecked load"])
    rows.append(["  of which the checks (read_network)", ms(best(lambda: read_network(path), 10)), "", ""])
    table("checks before any work (best of 5; ms)", ["what", "with the checks", "alternative", "alternative is"], rows)
    print(f"load average at end: {os.getloadavg()[0]:.1f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
