"""Co-segment a small collection of procedural chairs with the bundled chair model, and score the
parsing against the chairs' own part labels.

    python examples/segment_chairs.py OUTPUT_FOLDER

No labels are used to segment: each face simply goes to its nearest cuboid, and because one network
explains every chair, cuboid ``k`` is the same part on all of them (its seat, its back, ...).
"""

import sys
from pathlib import Path

from primkit import segmentation, synthetic

out = Path(sys.argv[1] if len(sys.argv) > 1 else "segment-example")
shapes = synthetic.write_collection(out / "chairs", "chair", 6, seed=3, overwrite=True)

segmenter = segmentation.Segmenter("chair", refine=50)  # the bundled model; ShapeNet axes (+y up, +x front)
segs, errors = segmenter.segment_files(shapes, cache_dir=out / "cache", progress=False)

names, truths = [], []
for seg in segs:
    seg.save(out / "segmented", semantic=True, overwrite=True)  # <name>.seg (name codes) + coloured .ply
    # the .json beside each procedural chair says what its labels mean (seat, back, legs, arms, base)
    truths.append(segmentation.read_ground_truth(Path(seg.source).with_suffix(".seg"), len(seg.faces), None, names))
segmentation.write_summary(segs, out / "summary.csv", overwrite=True)

report = segmentation.evaluate(segs, truths, part_names=segmenter.part_names)
for protocol, entry in report.protocols.items():
    print(f"{protocol:20s} accuracy {entry.mean_area:.1%} of the surface, mean IoU {entry.mean_iou:.2f}")
print("part names:", {k: n for k, n in enumerate(segmenter.part_names) if not n.startswith("part")})
print(f"wrote {out}/segmented/ and {out}/summary.csv")
