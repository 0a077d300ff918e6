"""Helpers of the labeller-format tests: a small labeller learned from random shapes, a labeller
file with its description changed, and one without a setting."""

from __future__ import annotations

import json

import numpy as np

from primkit import primitives
from primkit.segmentation.labeller import Labeller, frame_features


def small_labeller(settings):
    """``(labeller, cuboids, points)``: a labeller with ``settings`` learned in 10 rounds from 3
    random 5-cuboid shapes of 300 points (labels: above the middle, plus cuboid 1's points);
    the last shape's cuboids and points."""
    rng = np.random.default_rng(0)
    shapes = []
    for _ in range(3):
        c = primitives.Cuboids(rng.uniform(0.05, 0.3, (5, 3)), rng.normal(size=(5, 4)),
                               rng.uniform(-0.4, 0.4, (5, 3)), np.ones(5, bool))
        points = rng.uniform(-0.5, 0.5, (300, 3))
        y = (points[:, 1] > 0).astype(int) + (primitives.assign_points(points, c) == 1)
        shapes.append((frame_features(points, c, None, settings), y))
    return Labeller.fit(shapes, ["a", "b", "c"], 5, settings=settings, max_iter=10), c, points


def rewrite_description(path, out, change):
    """The labeller file ``path`` written to ``out`` with ``change`` (a function) applied to its
    labeller description (the JSON dict), the tensors unchanged."""
    from safetensors import safe_open
    from safetensors.numpy import load_file, save_file

    with safe_open(str(path), framework="numpy") as f:
        meta = json.loads(f.metadata()["primkit"])
    change(meta["labeller"])
    save_file(load_file(str(path)), str(out), metadata={"primkit": json.dumps(meta)})
    return out


def without_setting(path, out, setting: str):
    """The labeller file ``path`` without the ``setting`` key in its settings, written to ``out``."""
    return rewrite_description(path, out, lambda d: d["settings"].pop(setting))
