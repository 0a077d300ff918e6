"""The core commands: ``demo`` (the main job), ``generate``, ``prepare``, ``train``, ``abstract``,
``eval``, ``models`` and ``info``; each parses, asks the library, prints."""

from __future__ import annotations

import json
import sys
from pathlib import Path

from ._common import add_command
from ._common import (
    abstraction_options,
    add_abstraction_options,
    add_force,
    add_output,
    add_png,
    add_prepare_options,
    add_quiet,
    add_scale_out,
    check_command_outputs,
    collect,
    err,
    input_paths,
    model_file,
    progress_of,
    report_errors,
    settings_from_args,
)

__all__ = ["register"]


def _cmd_generate(args) -> int:
    from ..synthetic import write_collection

    rates = {}
    for text in args.rate or []:
        key, _, value = text.partition("=")
        try:
            rates[key] = float(value)
        except ValueError:
            raise ValueError(f"--rate wants ATTRIBUTE=FRACTION (for example has_arms=0.5), got {text!r}") from None
    paths = write_collection(args.output, args.category, args.count, seed=args.seed, rates=rates, overwrite=args.force)
    print(f"wrote {len(paths)} {args.category} shapes (.ply + .seg labels + .json attributes) to {args.output}")
    return 0


def _cmd_prepare(args) -> int:
    from ..data import plan_run, prepare_collection

    plan = plan_run(args.inputs, shard=args.shard)
    coll = prepare_collection(plan, settings_from_args(args), cache_dir=args.cache, workers=args.workers,
                              executor=args.executor, progress=progress_of(args))
    shard = f" (shard {args.shard})" if args.shard else ""
    print(f"prepared {len(coll)} shape(s){shard} into {args.cache or 'the default cache'}")
    return report_errors(coll.errors)


def _cmd_train(args) -> int:
    from ..model.training import claim_output

    with claim_output(args.output, args.force):  # a second run into the same -o is refused before any work
        return _train_claimed(args)


def _train_claimed(args) -> int:
    from ..data import PrepareSettings, prepare_collection, split_files
    from ..model.network import NetworkConfig
    from ..model.presets import recipe
    from ..model.training import ShapeTensors, check_checkpoint, check_training_outputs, train

    out = Path(args.output)
    plan = recipe(args.preset, stage1=args.stage1, stage2=args.stage2, full_schedule=args.full_schedule,
                  hold_out_every=args.hold_out, up=args.up, front=args.front, parts=args.parts,
                  batch_size=args.batch_size, encoder=args.encoder, seed=args.seed, learning_rate=args.lr,
                  symmetry_weight=args.symmetry)
    collected = collect(args.inputs)
    settings = settings_from_args(args, PrepareSettings(up=plan.up, front=plan.front))
    # before preparing and training: the outputs can be written, and a checkpoint resumed fits this run
    check_training_outputs(out, overwrite=args.force, resume=args.resume, inputs=input_paths(collected))
    if args.resume is not None:
        c = plan.config
        check_checkpoint(args.resume, NetworkConfig(parts=c.parts, grid=settings.resolution, encoder=c.encoder,
                                                    fc_width=c.fc_width))
    files, held = split_files(collected, plan.hold_out_every)
    coll = prepare_collection(files, settings, cache_dir=args.cache, workers=args.workers, progress=progress_of(args))
    status = report_errors(coll.errors)
    if len(coll) == 0:
        err("no usable shapes to train on")
        return 2
    shapes = ShapeTensors(coll)
    config = plan.schedule(len(shapes))
    print(f"training on {len(shapes)} shapes ({len(held)} held out): {config.stage1_iterations} + {config.stage2_iterations} "
          f"iterations, {config.parts} parts, batch {config.batch_size}", file=sys.stderr)
    description = plan.description(args.inputs, len(held), args.data_terms)
    result = train(shapes, out, config, device=args.device, resume=args.resume, description=description, overwrite=args.force,
                   progress=progress_of(args))
    if result.interrupted:
        return 130
    if result.model_path is not None:
        last = result.history[-1] if result.history else {}
        print(f"wrote {out} ({result.seconds:.0f} s; final coverage {last.get('coverage', float('nan')):.2e}, "
              f"consistency {last.get('consistency', float('nan')):.2e}, parts {last.get('parts', float('nan')):.1f}); "
              f"losses plotted in {out.with_suffix('')}.training.png")
    return status


def _picture_path(path):
    """``--png PATH`` checked: a ``.png`` file name (None when not asked for)."""
    from ..io import check_suffix

    return None if path is None else check_suffix(path, ".png", "a picture")


def _output_suffixes(args) -> tuple[str, str]:
    """The two files ``abstract`` writes per shape: the JSON and the mesh (``--format``)."""
    return (".cuboids.json", ".glb") if args.format == "glb" else (".cuboids.json", ".cuboids.ply")


def _cmd_abstract(args) -> int:
    from ..model.bundled import resolve_model
    from ..model.modelfile import read_metadata

    model_path = resolve_model(args.model)
    if read_metadata(model_path).get("kind") == "image-abstractor":
        from .image import run_abstract_images

        if args.format != "ply":
            err(f"--format {args.format}: shapes only (an image model writes JSON and PLY)")
            return 2

        return run_abstract_images(args)
    from ..data import plan_run
    from ..model.abstraction import abstract_shapes, load_model

    model = load_model(model_path)  # validated before the inputs are read
    if args.shard and args.png:
        err("--png draws the whole collection: not with --shard")
        return 2
    # with --shard, this shard's outputs only, named as one run over all the inputs names them; with
    # --skip-done, without what a cut run finished (both files there; one of the two is redone)
    plan = plan_run(args.inputs, args.output, outputs=_output_suffixes(args), shard=args.shard,
                    skip_done=args.skip_done, extra=[_picture_path(args.png)], reads=[model_path])
    plan.check(args.force)
    out = abstract_shapes(plan, model, existence_threshold=args.threshold,
                          prune_threshold=None if args.prune <= 0 else args.prune, **abstraction_options(args))
    for a in out:
        print(_abstraction_line(a, _save_abstraction(a, out.model, args)))
    if args.png and out.shapes:
        _draw_abstractions(out, args.png)
    return report_errors(out.errors)


def _save_abstraction(a, model, args):
    """Write one shape's JSON and mesh (``--format``); returns the JSON's path."""
    if args.format == "glb":  # the input's surface split by part and the cuboids, a node per part
        from ..export import save_glb

        return save_glb(a, model.part_names, args.output, overwrite=args.force)[0]
    return a.result.save(args.output, overwrite=args.force)[0]


def _abstraction_line(a, path) -> str:
    r = a.result
    extra = ""
    if r.alignment is not None:
        extra += f"; oriented with up {r.alignment.up}, front {r.alignment.front}"
    if r.refinement is not None:
        extra += f"; refined: loss {r.refinement.loss_before:.2e} -> {r.refinement.loss_after:.2e}"
    return f"{r.name}: {int(r.cuboids.existence.sum())} parts{extra} -> {path}"


def _draw_abstractions(out, path) -> None:
    """The first 16 meshes beside their cuboids (a point cloud or a voxel grid is left out of the picture)."""
    from ..viz.render import render_abstractions

    shown = []
    for a in out:
        try:
            a.mesh
        except ValueError:
            continue
        shown.append(a)
        if len(shown) == 16:
            break
    if shown:
        render_abstractions([a.result for a in shown], [(a.vertices, a.faces) for a in shown], path)
        print(f"picture: {path}")


def _split_inputs(files, abstractor, split: str) -> list:
    from ..data import split_files

    if split == "all":
        return files
    every = abstractor.hold_out_every
    if not every:
        raise ValueError(f"--split {split}: the model records no held-out rule (it was trained without --hold-out)")
    train_files, held = split_files(files, every)
    return held if split == "held-out" else train_files


def _cmd_eval(args) -> int:
    from ..metrics import ChamferConvention, score, summarize
    from ..model.abstraction import abstract_shapes, load_model

    abstractor = load_model(args.model)
    files = _split_inputs(collect(args.inputs), abstractor, args.split)
    if args.limit:
        files = files[: args.limit]
    if args.json:
        from ..io import check_suffix

        check_command_outputs(args, [check_suffix(args.json, ".json", "a scores file")], input_paths(files, model_file(args.model)))
    out = abstract_shapes(files, abstractor, **abstraction_options(args))
    conv = ChamferConvention(power=args.chamfer_power)
    scores = [score(a.canonical, a.canonical_shape(), conv) for a in out]
    summary = summarize(scores).to_dict() if scores else {}
    print(f"metric convention: {conv.describe()}")
    for key in ("chamfer", "iou", "coverage", "consistency", "parts"):
        if key in summary:
            st = summary[key]
            print(f"{key:12s} mean {st['mean']:.5f}  median {st['median']:.5f}  std {st['std']:.5f}")
    print(f"shapes: {len(scores)}")
    if args.json:
        from ..io import atomic_output

        with atomic_output(args.json, overwrite=args.force) as tmp:
            Path(tmp).write_text(json.dumps({"convention": conv.describe(), "summary": summary,
                                             "shapes": {a.name: s.to_dict() for a, s in zip(out, scores)}}, indent=1))
    return report_errors(out.errors)


def _cmd_models(args) -> int:
    from ..model.modelfile import read_metadata
    from ..model.bundled import bundled_models

    models = bundled_models()
    if not models:
        print("no bundled models installed")
        return 0
    for name, path in models.items():
        meta = read_metadata(path)
        card = meta.get("card") or {}
        if args.name and name not in args.name:
            continue
        print(f"== {name} ({path.stat().st_size / 1024:.0f} KiB): {card.get('summary', '')}")
        if args.verbose:
            print(card.get("text", json.dumps(card, indent=1)))
        else:
            for key in ("data", "terms", "schedule", "metrics"):
                if key in card:
                    print(f"  {key}: {card[key] if isinstance(card[key], str) else json.dumps(card[key])}")
        names = meta.get("part_names") or []
        named = [f"{k} {n}" for k, n in enumerate(names) if n and not n.startswith("part")]
        if named:
            print(f"  part names: {', '.join(named)} (learned from {meta.get('part_naming', {}).get('shapes', '?')} labelled shapes)")
    return 0


def _cmd_info(args) -> int:
    """The metadata, after the checks loading the model makes (architecture against the tensors)."""
    from ..model.bundled import resolve_model
    from ..model.modelfile import read_metadata

    path = resolve_model(args.model)
    if read_metadata(path).get("kind") == "image-abstractor":
        from ..image.inference import read_image_network

        _, meta = read_image_network(path)
    else:
        from ..model.network import read_network

        _, meta = read_network(path)
    print(json.dumps(meta, indent=1))
    return 0


def _cmd_demo(args) -> int:
    from ..demo import run_demo

    return run_demo(args.output, quick=args.quick, force=args.force, progress=progress_of(args))


def register(sub) -> None:
    p = add_command(sub, "demo", help="the main job: generate procedural chairs, train, abstract, draw a picture",
        description="The main job: generate part-labelled procedural chairs, abstract the held-out ones with the bundled chair model, train an abstractor from scratch, and run the applications into one folder (report/index.html, pictures, cuboids, report.json).",
        examples=["primkit demo", "primkit demo -o /tmp/demo --quick --force"])
    add_output(p, "output folder (default primkit-demo)", default="primkit-demo", required=False)
    p.add_argument("--quick", action="store_true", help="a much shorter run (for tests)")
    add_quiet(p)
    add_force(p)
    p.set_defaults(func=_cmd_demo)

    p = add_command(sub, "generate", help="write procedural part-labelled shapes",
        description="Write procedural part-labelled shapes: for each shape a mesh (.ply), a part label per face (.seg) and its attributes (.json).",
        examples=["primkit generate chair -n 200 -o chairs/", "primkit generate chair -n 200 -o chairs/ --rate has_arms=0.5"])
    p.add_argument("category", choices=["chair", "table", "airplane", "animal"], help="the kind of shape to generate")
    p.add_argument("-n", "--count", type=int, default=10, help="how many shapes (default 10)")
    add_output(p, "output folder")
    p.add_argument("--seed", type=int, default=0, help="random seed: the same seed gives the same shapes (default 0)")
    p.add_argument("--rate", action="append", metavar="ATTRIBUTE=FRACTION",
                   help="fraction of shapes with a yes/no attribute, e.g. --rate has_arms=0.5 (repeatable)")
    add_force(p)
    p.set_defaults(func=_cmd_generate)

    p = add_command(sub, "prepare", help="prepare shapes into the cache (grids, samples, distances)",
        description="Prepare shapes into the cache (occupancy grids, surface samples, distance fields), so that train, abstract and the applications start at once.",
        examples=["primkit prepare chairs/", "primkit prepare chairs/ --cache /shared/cache --shard 3/16"])
    p.add_argument("inputs", nargs="+", help="shape files or folders (searched recursively)")
    add_prepare_options(p)
    add_scale_out(p)
    p.set_defaults(func=_cmd_prepare)

    p = add_command(sub, "train", help="train an abstractor on a folder of shapes",
        description="Train a cuboid abstractor on a collection of shapes (unsupervised). Writes the model file, a checkpoint beside it (Ctrl-C saves and stops; --resume goes on) and a plot of the losses.",
        examples=["primkit train chairs/ -o chair.safetensors", "primkit train SHAPENETVOX32/03001627 --preset chair -o chair.safetensors"])
    p.add_argument("inputs", nargs="+", help="folders or files of shapes")
    add_output(p, "model file to write (.safetensors)")
    p.add_argument("--preset", default=None, help="a bundled model's recipe (chair, table, airplane, animal): schedule, "
                   "hold-out rule, data terms; other flags override it")
    p.add_argument("--parts", type=int, default=None, help="part slots M (default 20)")
    p.add_argument("--batch-size", type=int, default=None, help="default 32")
    p.add_argument("--lr", type=float, default=None, help="Adam learning rate (default 1e-3)")
    p.add_argument("--encoder", choices=["paper", "released"], default=None, help="default: paper")
    p.add_argument("--symmetry", type=float, default=None, help="weight of the reflection-symmetry loss (default 0: off)")
    p.add_argument("--hold-out", type=int, default=None, metavar="K",
                   help="hold out every K-th file (sorted paths, rank %% K == K-1) from training; recorded for eval --split")
    p.add_argument("--stage1", type=int, default=None, help="stage-1 iterations (all parts on)")
    p.add_argument("--stage2", type=int, default=None, help="stage-2 iterations (existence learned)")
    p.add_argument("--full-schedule", action="store_true", help="the paper's 20k + 30k iterations whatever the collection size")
    p.add_argument("--seed", type=int, default=None, help="random seed of the initialisation and batches (default 0)")
    p.add_argument("--device", default=None, help="cpu or cuda (default: cuda when available)")
    p.add_argument("--resume", default=None, help="checkpoint to resume from (<model>.checkpoint.safetensors)")
    p.add_argument("--data-terms", default=None, help="the training data's terms of use, recorded in the model file")
    add_force(p)
    add_prepare_options(p)
    p.set_defaults(func=_cmd_train)

    p = add_command(sub, "abstract", help="abstract shapes (or pictures, with an image model) with a trained model: JSON + "
                       "coloured cuboid mesh per shape; --png: the shapes beside their cuboids (for an image model, each "
                       "picture with its cuboids drawn over it)",
        description="Abstract shapes (or pictures, with an image model) with a trained model: for each input <name>.cuboids.json (the indexed cuboids) and <name>.cuboids.ply (a mesh coloured by part).",
        examples=["primkit abstract chairs/ --model chair -o out/", "primkit abstract chairs/ --model chair -o out/ --align auto --refine 200 --png out.png", "primkit abstract photo.png --model chair-image -o out/ --png over.png"])
    p.add_argument("inputs", nargs="+", help="shape files or folders (searched recursively)")
    add_output(p, "output folder")
    add_abstraction_options(p)
    add_scale_out(p)
    add_png(p)
    p.add_argument("--threshold", type=float, default=0.5, help="existence probability above which a part exists")
    p.add_argument("--prune", type=float, default=0.6, help="drop parts more than this fraction inside others (0: off)")
    p.add_argument("--format", choices=("ply", "glb"), default="ply",
                   help="the mesh beside each shape's JSON: ply (the coloured cuboids, <name>.cuboids.ply) or glb "
                        "(a glTF scene, <name>.glb: the input's surface split by part and the cuboids, one named "
                        "node per part with its index, name and existence probability; docs/export.md)")
    p.add_argument("--skip-done", action="store_true",
                   help="leave out inputs whose two outputs already exist (a rerun of a shard after a lost worker "
                        "does only what is missing; an input with one of its two outputs is redone)")
    add_force(p)
    p.set_defaults(func=_cmd_abstract)

    p = add_command(sub, "eval", help="Chamfer, IoU, coverage, consistency and parts of a model's abstractions",
        description="Score a model's abstractions: Chamfer-L1, IoU, coverage, consistency and parts per shape, printed with their convention.",
        examples=["primkit eval chairs/ --model chair", "primkit eval FOLDER --model chair --split held-out --json scores.json"])
    p.add_argument("inputs", nargs="+", help="shape files or folders (searched recursively)")
    add_abstraction_options(p)
    p.add_argument("--split", choices=["all", "held-out", "train"], default="all",
                   help="evaluate on the files the model held out from training (its recorded rule), or those it trained on")
    p.add_argument("--limit", type=int, default=0, help="evaluate at most this many files (0: all)")
    p.add_argument("--chamfer-power", type=int, choices=[1, 2], default=1, help="1: unsquared distances, 2: squared")
    p.add_argument("--json", default=None, help="also write the scores to this JSON file")
    add_force(p)
    p.set_defaults(func=_cmd_eval)

    p = add_command(sub, "models", help="list the bundled models with their model cards",
        description="List the bundled models with their model cards (data, terms, schedule, training time, held-out metrics, part names).",
        examples=["primkit models", "primkit models chair -v"])
    p.add_argument("name", nargs="*", help="only these models")
    p.add_argument("-v", "--verbose", action="store_true", help="print the whole card")
    p.set_defaults(func=_cmd_models)

    p = add_command(sub, "info", help="print a model file's metadata (without loading its weights)",
        description="Print a model file's metadata as JSON, after the checks loading makes (architecture against the tensors), without loading its weights.",
        examples=["primkit info chair.safetensors", "primkit info chair"])
    p.add_argument("model", help="a model file (.safetensors) or a bundled model's name")
    p.set_defaults(func=_cmd_info)
