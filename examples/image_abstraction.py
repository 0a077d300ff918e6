"""Cuboids from a single picture: distil the volume model into a small image network, then use it.

    python examples/image_abstraction.py OUTPUT_FOLDER

1. Renders pictures of procedural chairs from random viewpoints over random backgrounds
   (primkit.image.views), with the cameras.
2. Distils the bundled chair volume model into a tiny image network for a few seconds (the real
   recipe is ``primkit train-image``; this only shows the moving parts and the falling loss).
3. Abstracts a picture of a chair it never saw with the bundled ``chair-image`` model when it is
   installed (the tiny network otherwise) and draws the cuboids over the picture.

Writes views.png, tiny-image-model.safetensors, chair.png (the picture), chair.cuboids.json and
chair.overlay.png into OUTPUT_FOLDER.
"""

import json
import sys
from pathlib import Path

import numpy as np
from PIL import Image

from primkit import data, io, synthetic
from primkit import image as im
from primkit import image as views
from primkit.model.abstractor import Abstractor
from primkit.model.bundled import bundled_models

out = Path(sys.argv[1] if len(sys.argv) > 1 else "image-example")
out.mkdir(parents=True, exist_ok=True)
chairs = synthetic.generate("chair", 7, seed=7)
grids = [data.prepare(io.Mesh(c.vertices, c.faces), data.PrepareSettings(samples=500)).occupancy for c in chairs]
train_grids, new_grid = grids[:6], grids[6]

# 1. pictures with their cameras (deterministic under the seed)
settings = views.ViewSettings(size=32, supersample=2)
rendered = views.render_views(train_grids, 4, settings=settings, seed=0)
sheet = rendered.images[:16].reshape(2, 8, 32, 32, 3).transpose(0, 2, 1, 3, 4).reshape(64, 256, 3)
Image.fromarray(sheet).resize((1024, 256), Image.NEAREST).save(out / "views.png")

# 2. distillation: the teacher's cuboids for each chair, the student learns them from the pictures
teacher = Abstractor.load("chair")
targets = teacher.predict_canonical(np.stack(train_grids))
result = im.train_image_model(rendered.images, rendered.shape_index, rendered.cameras, targets,
                              im.ImageNetConfig(size=32, channels=(8, 16, 16, 32, 32), fc_width=64),
                              im.ImageTrainConfig(iterations=150, batch_size=16, learning_rate=3e-3, log_every=10),
                              progress=False)
print(f"distillation loss {result.history[0]['total']:.3f} -> {result.history[-1]['total']:.3f} "
      f"in {result.seconds:.1f} s")
tiny = im.ImageAbstractor(result.network, {})
tiny.save(out / "tiny-image-model.safetensors", {"teacher": "chair", "views": settings.to_dict()}, overwrite=True)

# 3. one picture of a chair neither model saw, abstracted and drawn over
bundled = bundled_models().get("chair-image")
model = im.ImageAbstractor.load(bundled) if bundled else im.ImageAbstractor.load(out / "tiny-image-model.safetensors")
vs = model.view_settings
picture = views.render_views([new_grid], 1, settings=vs, palette="unseen", seed=11)
Image.fromarray(picture.images[0]).save(out / "chair.png")
(r,), errors = model.predict_files([out / "chair.png"])
(out / "chair.cuboids.json").write_text(json.dumps(r.to_dict(), indent=1))
im.draw_over_image(r, out / "chair.overlay.png", distance=float(np.mean(vs.distance)), view_angle_deg=vs.view_angle_deg)
true = picture.camera(0)
print(f"{'chair-image' if bundled else 'tiny'} model: {int(r.cuboids.existence.sum())} parts; viewpoint "
      f"azimuth {r.azimuth_deg:.0f} deg (true {true.azimuth_deg:.0f}), elevation {r.elevation_deg:.0f} deg "
      f"(true {true.elevation_deg:.0f}) -> {out}")
