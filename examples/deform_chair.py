"""Deform one procedural chair into another's part configuration, and lengthen its legs.

    python examples/deform_chair.py OUTPUT_FOLDER

Uses the bundled chair model: abstracts two procedural chairs, moves the first one's cuboids onto
the second's (primitive k onto primitive k), then raises the first chair by lengthening its legs
30% (the seat and back rest on them and are carried up). Writes the meshes, a picture and the
quality measures into OUTPUT_FOLDER.
"""

import json
import sys
from pathlib import Path

import numpy as np

from primkit import data, deformation, io, synthetic
from primkit.viz import render
from primkit.viz.camera import CANONICAL_RADIUS
from primkit.model.abstractor import Abstractor

out = Path(sys.argv[1] if len(sys.argv) > 1 else "deform-example")
out.mkdir(parents=True, exist_ok=True)
a, b = synthetic.generate("chair", 2, seed=5)
model = Abstractor.load("chair")
shapes = [data.prepare(io.Mesh(s.vertices, s.faces), name=n) for s, n in ((a, "source"), (b, "target"))]
src, tgt = model.predict(shapes)
v = src.frame.to_canonical(a.vertices)  # work in the canonical frame (+Y up, longest side 1)

# 1. deformation transfer: the source takes the target's configuration
d = deformation.deform(v, src.canonical, tgt.canonical, faces=a.faces, unfold=True)  # unfold: re-solve flipped spots
q = d.quality(a.faces, target_points=shapes[1].points, source_points=shapes[0].points).to_dict()
print(f"Chamfer-L1 to the target: source {q['chamfer_source_target']:.4f} -> result {q['chamfer_result_target']:.4f}; "
      f"flipped triangles {100 * q['flipped']:.2f}%")
io.write_mesh(out / "deformed.off", src.frame.from_canonical(d.vertices), a.faces, overwrite=True)

# 2. part edit: slots 3, 5, 9 and 10 are the bundled chair model's legs (16 the seat, 18 the back)
c = src.canonical
legs = [k for k in (3, 5, 9, 10) if c.existence[k]]
e = deformation.edit(v, c, scale={k: (1.0, 1.3, 1.0) for k in legs}, faces=a.faces, unfold=True)
h0, h1 = np.ptp(v[:, 1]), np.ptp(e.vertices[:, 1])
print(f"legs {legs} 30% longer: height {h0:.3f} -> {h1:.3f}; carried along: {sorted(e.edit.carried)}")
io.write_mesh(out / "longer_legs.off", src.frame.from_canonical(e.vertices), a.faces, overwrite=True)

tiles = [render.Tile("source", [render.mesh_layer(v, a.faces), render.cuboid_layer(c, opacity=0.3)]),
         render.Tile("target", [render.mesh_layer(shapes[1].frame.to_canonical(b.vertices), b.faces),
                                render.cuboid_layer(tgt.canonical, opacity=0.3)]),
         render.Tile("deformed", [render.mesh_layer(d.vertices, a.faces)]),
         render.Tile("legs +30%", [render.mesh_layer(e.vertices, a.faces), render.cuboid_layer(e.edit.cuboids, opacity=0.3)])]
render.write_png(out / "deform.png", tiles, overwrite=True, columns=4, radius=CANONICAL_RADIUS)
(out / "quality.json").write_text(json.dumps({"deform": {k: q[k] for k in ("chamfer_source_target", "chamfer_result_target",
                                                                         "flipped")}, "height": [h0, h1]}, indent=1))
print(f"wrote {out}/deformed.off, longer_legs.off, deform.png, quality.json")
