"""The ``primkit`` command: each subcommand is a thin wrapper over one library call.

Exit codes: 0 success; 1 some inputs could not be used (each reported on one line, the batch goes
on); 2 bad usage or a fatal error (one line: ``primkit: error: ...``); 130 interrupted.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

__all__ = ["main"]


def _err(msg: str) -> None:
    print(f"primkit: error: {msg}", file=sys.stderr)


def _report_errors(errors) -> int:
    for e in errors:
        print(f"primkit: skipped {e}", file=sys.stderr)
    if errors:
        print(f"primkit: {len(errors)} input(s) could not be used", file=sys.stderr)
    return 1 if errors else 0


def _collect(inputs) -> list[Path]:
    from .data import find_shape_files

    files = []
    for item in inputs:
        files.extend(find_shape_files(item))
    return files


def _cmd_generate(args) -> int:
    from .synthetic import write_collection

    paths = write_collection(args.output, args.category, args.count, seed=args.seed, overwrite=args.force)
    print(f"wrote {len(paths)} {args.category} shapes (.ply + .seg labels + .json attributes) to {args.output}")
    return 0


def _settings(args):
    from .data import PrepareSettings

    return PrepareSettings(resolution=args.resolution, samples=args.samples, up=args.up, front=args.front)


def _cmd_prepare(args) -> int:
    from .data import prepare_collection

    coll = prepare_collection(_collect(args.inputs), _settings(args), cache_dir=args.cache, workers=args.workers)
    print(f"prepared {len(coll)} shape(s) into {args.cache or 'the default cache'}")
    return _report_errors(coll.errors)


def _cmd_train(args) -> int:
    from .data import prepare_collection
    from .training import ShapeTensors, TrainConfig, train

    out = Path(args.output)
    if out.exists() and not args.force:
        _err(f"{out}: exists (use --force to overwrite)")
        return 2
    coll = prepare_collection(_collect(args.inputs), _settings(args), cache_dir=args.cache, workers=args.workers)
    status = _report_errors(coll.errors)
    if len(coll) == 0:
        _err("no usable shapes to train on")
        return 2
    shapes = ShapeTensors(coll)
    config = TrainConfig(parts=args.parts, batch_size=args.batch_size, encoder=args.encoder,
                         symmetry_weight=args.symmetry, seed=args.seed, learning_rate=args.lr)
    if args.stage1 is not None or args.stage2 is not None:
        from dataclasses import replace

        config = replace(config, stage1_iterations=args.stage1 if args.stage1 is not None else config.stage1_iterations,
                         stage2_iterations=args.stage2 if args.stage2 is not None else config.stage2_iterations)
    elif not args.full_schedule:
        config = config.scaled_for(len(shapes))
    print(f"training on {len(shapes)} shapes: {config.stage1_iterations} + {config.stage2_iterations} iterations, "
          f"{config.parts} parts, batch {config.batch_size}", file=sys.stderr)
    description = {"inputs": [str(p) for p in args.inputs], "terms": args.data_terms or "not stated"}
    result = train(shapes, out, config, device=args.device, resume=args.resume, description=description, overwrite=args.force)
    if result.interrupted:
        return 130
    if result.model_path is not None:
        last = result.history[-1] if result.history else {}
        print(f"wrote {out} ({result.seconds:.0f} s; final coverage {last.get('coverage', float('nan')):.2e}, "
              f"consistency {last.get('consistency', float('nan')):.2e}, parts {last.get('parts', float('nan')):.1f}); "
              f"losses plotted in {out.with_suffix('')}.training.png")
    return status


def _cmd_abstract(args) -> int:
    from .abstractor import Abstractor

    abstractor = Abstractor.load(args.model)
    results, errors = abstractor.abstract_files(_collect(args.inputs), cache_dir=args.cache, workers=args.workers,
                                                existence_threshold=args.threshold,
                                                prune_threshold=None if args.prune <= 0 else args.prune)
    failed = list(errors)
    for r in results:
        try:
            j, m = r.save(args.output, overwrite=args.force)
        except FileExistsError as exc:
            failed.append(str(exc))
            continue
        print(f"{r.name}: {int(r.cuboids.existence.sum())} parts -> {j}")
    return _report_errors(failed)


def _cmd_eval(args) -> int:
    from .abstractor import Abstractor
    from .data import prepare_collection
    from .metrics import ChamferConvention, score, summarize

    abstractor = Abstractor.load(args.model)
    coll = prepare_collection(_collect(args.inputs), abstractor.settings, cache_dir=args.cache, workers=args.workers)
    shapes = list(coll)
    results = abstractor.predict(shapes)
    conv = ChamferConvention(power=args.chamfer_power)
    scores = [score(r.canonical, s, conv) for r, s in zip(results, shapes)]
    summary = summarize(scores) if scores else {}
    print(f"metric convention: {conv.describe()}")
    for key in ("chamfer", "iou", "coverage", "consistency", "parts"):
        if key in summary:
            st = summary[key]
            print(f"{key:12s} mean {st['mean']:.5f}  median {st['median']:.5f}  std {st['std']:.5f}")
    print(f"shapes: {len(scores)}")
    if args.json:
        from .io import atomic_output

        with atomic_output(args.json, overwrite=args.force) as tmp:
            Path(tmp).write_text(json.dumps({"summary": summary, "shapes": {r.name: s.to_dict() for r, s in zip(results, scores)}}, indent=1))
    return _report_errors(coll.errors)


def _cmd_info(args) -> int:
    from .modelfile import read_metadata

    meta = read_metadata(args.model)
    print(json.dumps(meta, indent=1))
    return 0


def _cmd_demo(args) -> int:
    from .demo import run_demo

    return run_demo(args.output, quick=args.quick, force=args.force)


def _add_prepare_options(p) -> None:
    p.add_argument("--resolution", type=int, default=32, help="grid cells per axis (default 32)")
    p.add_argument("--samples", type=int, default=10000, help="surface samples per shape (default 10000)")
    p.add_argument("--up", default="+y", help="the inputs' up axis, e.g. +y (COSEG, ShapeNet) or +z")
    p.add_argument("--front", default="+x", help="the inputs' front axis (default +x)")
    p.add_argument("--cache", default=None, help="cache folder (default $PRIMKIT_CACHE or ~/.cache/primkit/prepared)")
    p.add_argument("--workers", type=int, default=None, help="processes for preparation (default: all cores)")


def build_parser() -> argparse.ArgumentParser:
    from . import __version__

    parser = argparse.ArgumentParser(prog="primkit", description="Explain 3D shapes with a few cuboids (Tulsiani et al. 2017).")
    parser.add_argument("--version", action="version", version=f"primkit {__version__}")
    sub = parser.add_subparsers(dest="command", required=True)

    p = sub.add_parser("demo", help="the main job: generate procedural chairs, train, abstract, draw a picture")
    p.add_argument("-o", "--output", default="primkit-demo", help="output folder (default primkit-demo)")
    p.add_argument("--quick", action="store_true", help="a much shorter run (for tests)")
    p.add_argument("--force", action="store_true", help="overwrite an existing output folder's files")
    p.set_defaults(func=_cmd_demo)

    p = sub.add_parser("generate", help="write procedural part-labelled shapes")
    p.add_argument("category", choices=["chair", "table", "airplane", "animal"])
    p.add_argument("-n", "--count", type=int, default=10)
    p.add_argument("-o", "--output", required=True)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--force", action="store_true")
    p.set_defaults(func=_cmd_generate)

    p = sub.add_parser("prepare", help="prepare shapes into the cache (grids, samples, distances)")
    p.add_argument("inputs", nargs="+")
    _add_prepare_options(p)
    p.set_defaults(func=_cmd_prepare)

    p = sub.add_parser("train", help="train an abstractor on a folder of shapes")
    p.add_argument("inputs", nargs="+", help="folders or files of shapes")
    p.add_argument("-o", "--output", required=True, help="model file to write (.safetensors)")
    p.add_argument("--parts", type=int, default=20)
    p.add_argument("--batch-size", type=int, default=32)
    p.add_argument("--lr", type=float, default=1e-3)
    p.add_argument("--encoder", choices=["paper", "released"], default="paper")
    p.add_argument("--symmetry", type=float, default=0.0, help="weight of the reflection-symmetry loss (0: off)")
    p.add_argument("--stage1", type=int, default=None, help="stage-1 iterations (all parts on)")
    p.add_argument("--stage2", type=int, default=None, help="stage-2 iterations (existence learned)")
    p.add_argument("--full-schedule", action="store_true", help="the paper's 20k + 30k iterations whatever the collection size")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--device", default=None, help="cpu or cuda (default: cuda when available)")
    p.add_argument("--resume", default=None, help="checkpoint to resume from (<model>.checkpoint.safetensors)")
    p.add_argument("--data-terms", default=None, help="the training data's terms of use, recorded in the model file")
    p.add_argument("--force", action="store_true")
    _add_prepare_options(p)
    p.set_defaults(func=_cmd_train)

    p = sub.add_parser("abstract", help="abstract shapes with a trained model: JSON + coloured cuboid mesh per shape")
    p.add_argument("inputs", nargs="+")
    p.add_argument("--model", required=True)
    p.add_argument("-o", "--output", required=True, help="output folder")
    p.add_argument("--threshold", type=float, default=0.5, help="existence probability above which a part exists")
    p.add_argument("--prune", type=float, default=0.6, help="drop parts more than this fraction inside others (0: off)")
    p.add_argument("--cache", default=None)
    p.add_argument("--workers", type=int, default=None)
    p.add_argument("--force", action="store_true")
    p.set_defaults(func=_cmd_abstract)

    p = sub.add_parser("eval", help="Chamfer, IoU, coverage, consistency and parts of a model's abstractions")
    p.add_argument("inputs", nargs="+")
    p.add_argument("--model", required=True)
    p.add_argument("--chamfer-power", type=int, choices=[1, 2], default=1, help="1: unsquared distances, 2: squared")
    p.add_argument("--json", default=None, help="also write the scores to this JSON file")
    p.add_argument("--cache", default=None)
    p.add_argument("--workers", type=int, default=None)
    p.add_argument("--force", action="store_true")
    p.set_defaults(func=_cmd_eval)

    p = sub.add_parser("info", help="print a model file's metadata (without loading its weights)")
    p.add_argument("model")
    p.set_defaults(func=_cmd_info)
    return parser


def main(argv=None) -> int:
    from .io import ShapeFileError
    from .modelfile import ModelFileError

    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except KeyboardInterrupt:
        _err("interrupted")
        return 130
    except (ShapeFileError, ModelFileError, FileExistsError, FileNotFoundError, ValueError) as exc:
        _err(str(exc).splitlines()[0] if str(exc) else type(exc).__name__)
        return 2


if __name__ == "__main__":
    sys.exit(main())
