"""``primkit adapt``: a model fitted to the user's own collection, without labels
(:func:`primkit.model.adaptation.adapt`)."""

from __future__ import annotations

from pathlib import Path

from ._common import add_force, add_output, check_outputs, collect, err, input_paths, model_file, report_errors


def register(sub) -> None:
    p = sub.add_parser("adapt", help="continue a model's training on your own shapes, without labels")
    p.add_argument("inputs", nargs="+", help="shape files or folders (meshes, point clouds, voxel grids)")
    p.add_argument("--model", default="chair", help="the parent: a bundled model's name or a model file")
    add_output(p, "the adapted model file (.safetensors)")
    p.add_argument("--steps", type=int, default=600, help="stage-2 steps (default 600)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--workers", type=int, default=None, help="processes preparing the shapes")
    add_force(p)
    p.set_defaults(func=run)


def run(args) -> int:
    from ..data import prepare_collection
    from ..model.abstraction import load_model
    from ..model.adaptation import AdaptConfig, adapt, save_adapted

    try:
        files = collect(args.inputs)
        output = Path(args.output)
        if output.suffix != ".safetensors":
            raise ValueError(f"{output}: the adapted model is written as '.safetensors'")
        check_outputs(args, [output], input_paths(files, model_file(args.model)))
        if args.steps < 1:
            raise ValueError(f"--steps must be at least 1, got {args.steps}")
        parent = load_model(args.model)
    except (ValueError, FileNotFoundError, FileExistsError, OSError) as exc:
        err(str(exc).splitlines()[0])
        return 2
    coll = prepare_collection(files, parent.settings, workers=args.workers)
    shapes = [coll[i] for i in range(len(coll))]
    status = report_errors(coll.errors)
    if not shapes:
        err("no usable shapes to adapt to")
        return 1
    child = adapt(parent, shapes, AdaptConfig(steps=args.steps, seed=args.seed), parent_name=str(args.model),
                  progress=True)
    save_adapted(child, output, overwrite=args.force)
    a = child.metadata["adaptation"]
    print(f"{output}: {a['parent']} adapted to {a['shapes']} shapes (digest {a['digest']}), {args.steps} steps, "
          f"{a['seconds']:.0f} s")
    return status
