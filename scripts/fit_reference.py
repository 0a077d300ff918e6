"""Store a bundled model's fit reference: how well it fits held-out shapes of its own kind.

:func:`primkit.abstract_shapes` warns when a model fits the inputs far worse than it should (a
model of another category, a wrong frame or scale). It compares the inputs' median fit loss with
the model file's ``fit_reference`` (:func:`primkit.model.abstraction.fit_reference`: the median
and spread of the log fit loss over held-out shapes), by a test of the median, so that one or a
few shapes of the model's own kind do not set it off. Without a reference it compares with the
card's final training loss, which the bundled chair model's own held-out chairs exceed 2.5 times
about one time in three (``docs/faults.md``).

This script abstracts the shapes the model held out of its training (the split its file records:
its input folder, found under ``../shared/data/shapenetvox32``, and ``hold_out_every``;
``--shapes N`` of them, evenly spread over the sorted files) with default flags and writes a copy
of the model file with the reference added.
The weights and every other metadata key are copied unchanged (checked).

Usage (from the repository root)::

    python -m scripts.fit_reference chair -o chair-ref.safetensors
    cp chair-ref.safetensors primkit/model/bundled/chair.safetensors
"""

from __future__ import annotations

import argparse
import warnings
from pathlib import Path

import numpy as np

from primkit import data
from primkit.model.abstraction import CardMismatchWarning, abstract_shapes, fit_reference, load_model
from primkit.model.bundled import resolve_model
from primkit.model.modelfile import load_model_file, read_metadata, update_metadata

from scripts.build_labellers import SHARED

#: the bundled volume models (the image model abstracts pictures: no fit check)
MODELS = ("chair", "table", "airplane")


def reference_for(model: str, shapes: int = 400):
    """The fit reference of bundled ``model`` from ``shapes`` of the ShapeNetVox32 grids it held
    out (its recorded input folder's name under ``SHARED``, split by its ``hold_out_every``)."""
    abstractor = load_model(model)
    folders = [SHARED / "shapenetvox32" / Path(p).name for p in abstractor.metadata["training"]["data"]["inputs"]]
    _, held = data.split_files([f for d in folders for f in data.find_shape_files(d)], abstractor.hold_out_every)
    held = sorted(held, key=data.shape_name)
    files = [held[i] for i in np.unique(np.linspace(0, len(held) - 1, min(shapes, len(held))).astype(int))]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", CardMismatchWarning)  # the check being calibrated
        got = abstract_shapes([str(f) for f in files], abstractor, progress=True)
    if got.errors:
        raise SystemExit(f"{model}: {len(got.errors)} held-out files could not be abstracted: {got.errors[:3]}")
    return fit_reference(got.fit_losses, f"{len(got.fit_losses)} held-out ShapeNetVox32 {model} grids (every "
                                         f"{abstractor.hold_out_every}th file of the training split), fit losses at 1000 points")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("model", choices=MODELS)
    ap.add_argument("-o", "--output", type=Path, required=True)
    ap.add_argument("--shapes", type=int, default=400)
    ap.add_argument("--force", action="store_true")
    args = ap.parse_args(argv)
    source = resolve_model(args.model)
    reference = reference_for(args.model, args.shapes)
    update_metadata(source, args.output, {"fit_reference": reference.to_dict()}, overwrite=args.force)
    before, after = load_model_file(source), load_model_file(args.output)
    assert before[0].keys() == after[0].keys() and all((before[0][k] == after[0][k]).all() for k in before[0])
    assert {k: v for k, v in read_metadata(args.output).items() if k not in ("fit_reference", "created")} == \
        {k: v for k, v in before[1].items() if k not in ("fit_reference", "created")}
    print(f"wrote {args.output}: fit reference {reference}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
