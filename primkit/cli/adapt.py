"""``primkit adapt``: a model fitted to the user's own collection, without labels
(:func:`primkit.model.adaptation.adapt`)."""

from __future__ import annotations

from pathlib import Path

from ._common import add_command
from ._common import (add_align, add_axes, add_cache, add_force, add_model, add_output, add_quiet, add_refine, add_workers,
                      check_command_outputs, collect, err, input_paths, model_file, progress_of, report_errors,
                      settings_from_args)


def register(sub) -> None:
    p = add_command(sub, 
        "adapt", help="continue a model's training on your own shapes, without labels",
        description="Fit a model to your own collection without labels: its unsupervised stage-2 training goes on "
        "over the given shapes (found in the model's frame first), pulled toward the parent's answer so that part "
        "indices and names stay. The new model's metadata names its parent, the collection and the settings.",
        examples=["primkit adapt mine/ --model chair -o chair-mine.safetensors", "primkit adapt scans/ --model chair --steps 200 --seed 1 -o chair-scans.safetensors"])
    p.add_argument("inputs", nargs="+", help="shape files or folders (meshes, point clouds, voxel grids)")
    add_model(p)
    add_output(p, "the adapted model file (.safetensors)")
    p.add_argument("--steps", type=int, default=None, help="stage-2 steps (default: 40 draws a shape, 200 to 600)")
    p.add_argument("--seed", type=int, default=0, help="random seed of the batches and samples (default 0): "
                   "the same seed gives the same model")
    add_axes(p)
    add_align(p)
    add_refine(p)  # shared by every command with --model; adapting refines nothing
    add_cache(p)
    add_workers(p)
    add_quiet(p)
    add_force(p)
    p.set_defaults(func=run)


def run(args) -> int:
    from ..model.modelfile import claim_output

    with claim_output(args.output, args.force):  # a second run into the same -o is refused before any work
        return _run_claimed(args)


def _run_claimed(args) -> int:
    from dataclasses import replace

    from ..data import prepare_collection
    from ..model.abstraction import load_model
    from ..model.adaptation import AdaptConfig, adapt, save_adapted
    from ..model.orientation import resolve_align

    try:
        files = collect(args.inputs)
        output = Path(args.output)
        if output.suffix != ".safetensors":
            raise ValueError(f"{output}: the adapted model is written as '.safetensors'")
        check_command_outputs(args, [output], input_paths(files, model_file(args.model)))
        if args.steps is not None and args.steps < 1:
            raise ValueError(f"--steps must be at least 1, got {args.steps}")
        if args.refine:
            raise ValueError("--refine does not apply to adapt (it refines one shape's cuboids, not a model)")
        parent = load_model(args.model)
        settings = replace(settings_from_args(args, parent.settings), resolution=parent.resolution)
        align = resolve_align(args.align, args.up, args.front)
    except (ValueError, FileNotFoundError, FileExistsError, OSError) as exc:
        err(str(exc).splitlines()[0])
        return 2
    coll = prepare_collection(files, settings, cache_dir=args.cache, workers=args.workers, progress=progress_of(args))
    status = report_errors(coll.errors)
    if not len(coll):
        err("no usable shapes to adapt to")
        return 1
    child = adapt(parent, coll, AdaptConfig(steps=args.steps, seed=args.seed), align=align, parent_name=str(args.model),
                  progress=progress_of(args))
    save_adapted(child, output, overwrite=args.force)
    a = child.metadata["adaptation"]
    print(f"{output}: {a['parent']} adapted to {a['shapes']} shapes (digest {a['digest']}), {a['config']['steps']} steps, "
          f"{a['seconds']:.0f} s; {100 * a['index_agreement']:.1f}% of surface samples keep their part's index "
          f"({a['agreement_shapes']} shapes)")
    return status
