"""Rendered views (determinism, camera projection) and the image abstractor (distillation loss,
a short real training run, the command line on pictures)."""

import json

import numpy as np
import pytest
import torch

from primkit import data, io, primitives, synthetic
from primkit import image as im
from primkit import image as views
from primkit.image.backgrounds import _hsv_to_rgb
from primkit.image.distill import _geometric_loss
from primkit.primitives import matrix_to_quaternion


@pytest.fixture(scope="module")
def chairs():
    shapes = synthetic.generate("chair", 3, seed=5)
    return [data.prepare(io.Mesh(s.vertices, s.faces), data.PrepareSettings(samples=500)) for s in shapes]


@pytest.fixture(scope="module")
def grids(chairs):
    return [c.occupancy for c in chairs]


SMALL = views.ViewSettings(size=32, supersample=1)


def test_same_seed_same_pixels_other_seed_other_pixels(grids):
    a = views.render_views(grids[:2], 2, settings=SMALL, seed=3)
    b = views.render_views(grids[:2], 2, settings=SMALL, seed=3)
    c = views.render_views(grids[:2], 2, settings=SMALL, seed=4)
    assert a.images.shape == (4, 32, 32, 3) and a.images.dtype == np.uint8
    assert np.array_equal(a.images, b.images) and np.array_equal(a.cameras, b.cameras)
    assert not np.array_equal(a.images, c.images)
    # a view does not depend on the views rendered before it (rendering in chunks gives the same pixels)
    d = views.render_views(grids[1:2], 2, settings=SMALL, seed=3, first_index=1)
    assert np.array_equal(d.images, a.images[2:])


def test_views_round_trip_through_npz(grids, tmp_path):
    a = views.render_views(grids[:1], 2, settings=SMALL, seed=0, names=["c0"], palette="unseen")
    a.save(tmp_path / "v.npz")
    b = views.load_views(tmp_path / "v.npz")
    assert np.array_equal(a.images, b.images) and b.names == ["c0"] and b.settings == SMALL and b.palette == "unseen"


def test_kept_foregrounds_rebuild_the_pictures(grids, tmp_path):
    """``images = foreground + background (1 - alpha)``: where the shape covers a pixel fully the
    picture is the foreground, where it is absent the foreground is black; and laying the views
    over other backgrounds changes only the uncovered pixels."""
    a = views.render_views(grids[:2], 2, settings=SMALL, seed=3, keep_foreground=True)
    b = views.render_views(grids[:2], 2, settings=SMALL, seed=3)
    assert np.array_equal(a.images, b.images) and b.foreground is None  # same pixels either way
    full, empty = a.alpha == 255, a.alpha == 0
    assert full.any() and empty.any()
    assert np.abs(a.images[full].astype(int) - a.foreground[full]).max() <= 1
    assert a.foreground[empty].max() == 0
    white = a.composite(np.ones(a.images.shape, float))
    assert (white[empty] == 255).all() and np.abs(white[full].astype(int) - a.images[full]).max() <= 1
    a.save(tmp_path / "v.npz")
    c = views.load_views(tmp_path / "v.npz")
    assert np.array_equal(c.foreground, a.foreground) and np.array_equal(c.alpha, a.alpha)
    with pytest.raises(ValueError, match="keep_foreground"):
        b.composite(np.ones(b.images.shape, float))


def test_training_backgrounds_are_seeded_and_in_range():
    g1, g2 = torch.Generator().manual_seed(0), torch.Generator().manual_seed(0)
    a, b = im.training_backgrounds(40, 24, g1), im.training_backgrounds(40, 24, g2)
    assert a.shape == (40, 3, 24, 24) and torch.equal(a, b)
    assert a.min() >= 0 and a.max() <= 1
    assert not torch.equal(a, im.training_backgrounds(40, 24, g1))  # the next draw differs
    import colorsys

    # solid backgrounds (one colour) keep to the training palette's hues
    flat = [x for x in a if float((x.amax(dim=(1, 2)) - x.amin(dim=(1, 2))).max()) < 1e-6]
    assert flat
    for x in flat:
        h, s, _ = colorsys.rgb_to_hsv(*x[:, 0, 0].tolist())
        if s > 0.05:
            assert views.PALETTE_HUES["seen"][0] - 1e-6 <= h <= views.PALETTE_HUES["seen"][1] + 1e-6


def test_hsv_to_rgb_matches_colorsys():
    import colorsys

    hsv = torch.rand(200, 3, generator=torch.Generator().manual_seed(1))
    ours = _hsv_to_rgb(hsv[:, 0], hsv[:, 1], hsv[:, 2]).numpy()
    ref = np.array([colorsys.hsv_to_rgb(*row) for row in hsv.tolist()])
    assert np.abs(ours - ref).max() < 1e-6


def test_projection_matches_the_rendered_silhouette(grids):
    """The silhouette's bounding box (renderer) against the projected surface's (our camera maths)."""
    settings = views.ViewSettings(size=64, supersample=1)
    v, f = views.shape_surface(grids[0])
    with views.ViewRenderer(settings) as r:
        for az, el in ((0, 10), (70, 30), (200, 0)):
            cam = views.OrbitCamera(az, el, 2.0, 35.0)
            _, alpha = r.render(v, f, cam, np.random.default_rng(0))
            rows, cols = np.nonzero(alpha > 0.5)
            uv = views.project(v, cam, 64)
            assert abs(cols.min() - uv[:, 0].min()) <= 1.5 and abs(cols.max() + 1 - uv[:, 0].max()) <= 1.5
            assert abs(rows.min() - uv[:, 1].min()) <= 1.5 and abs(rows.max() + 1 - uv[:, 1].max()) <= 1.5


def test_backgrounds_palettes_use_disjoint_hues():
    import colorsys

    for palette, lo, hi in (("seen", 0.0, 0.5), ("unseen", 0.5, 1.0)):
        for seed in range(20):
            bg = views.random_background(16, np.random.default_rng(seed), palette)
            r, g, b = bg[0, 0]
            h, s, _ = colorsys.rgb_to_hsv(r, g, b)
            if s > 0.05:  # the hue of a grey is undefined
                assert lo - 0.02 <= h <= hi + 0.02


def _quat(axis, angle):
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    return np.r_[np.cos(angle / 2), np.sin(angle / 2) * axis]


def test_rotation_distance_sign_and_closed_form():
    rng = np.random.default_rng(0)
    q = rng.normal(size=(5, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    q_ref = rng.normal(size=(5, 4))
    q_ref /= np.linalg.norm(q_ref, axis=1, keepdims=True)
    qt, rt = torch.tensor(q), torch.tensor(q_ref)
    assert torch.allclose(im.rotation_distance(qt, rt), im.rotation_distance(-qt, rt))
    assert torch.allclose(im.rotation_distance(qt, rt), im.rotation_distance(qt, -rt))
    assert torch.allclose(im.rotation_distance(qt, qt), torch.zeros(5, dtype=torch.float64), atol=1e-12)
    # two rotations theta apart: 1 - cos(theta / 2), whatever the axes (the relative rotation is built
    # from a matrix product, independently of the quaternion algebra)
    for theta in (0.3, 1.0, 2.5):
        base = _quat([1, 2, 3], 0.7)
        from primkit.primitives import quaternion_to_matrix

        rel = quaternion_to_matrix(_quat([0, 1, -1], theta)[None])[0]
        other = matrix_to_quaternion((quaternion_to_matrix(base[None])[0] @ rel)[None])[0]
        d = float(im.rotation_distance(torch.tensor(base), torch.tensor(other)))
        assert d == pytest.approx(1 - np.cos(theta / 2), abs=1e-9)


def test_distillation_loss_does_not_see_the_quaternion_sign():
    rng = np.random.default_rng(1)
    b, m = 3, 4
    q = torch.nn.functional.normalize(torch.tensor(rng.normal(size=(b, m, 4))), dim=-1)
    from dataclasses import replace

    from primkit.model.abstractor import RawCuboids

    teacher = RawCuboids(half_extents=torch.rand(b, m, 3, dtype=torch.float64) * 0.3, quaternions=q,
                         translations=torch.rand(b, m, 3, dtype=torch.float64) - 0.5,
                         existence=torch.rand(b, m, dtype=torch.float64))
    same_as_teacher = im.ImagePrediction(teacher.half_extents, teacher.quaternions, teacher.translations,
                                         teacher.existence, torch.logit(teacher.existence), torch.zeros(b, 3))
    pred = replace(same_as_teacher, quaternions=torch.nn.functional.normalize(
        q + 0.3 * torch.tensor(rng.normal(size=(b, m, 4))), dim=-1))
    flipped = replace(pred, quaternions=-pred.quaternions)
    a, c = im.distillation_loss(pred, teacher), im.distillation_loss(flipped, teacher)
    assert float(a.terms["rotation"]) > 0.01
    assert float(a.total) == pytest.approx(float(c.total), abs=1e-12)
    # the teacher's own output costs nothing but the entropy of its soft existence
    same = im.distillation_loss(same_as_teacher, teacher)
    assert float(same.terms["rotation"]) == pytest.approx(0, abs=1e-12) and float(same.terms["translations"]) == 0


# the fast loop keeps the plain run, in 30 iterations (the loss falls to 0.32 of its start; 0.15 in 60);
# the background swap and the geometric term cost 25 and 20 s of CPU in 60
@pytest.mark.parametrize("swap, geometric, iterations", [(0.0, 0.0, 30),
                                                         pytest.param(0.75, 0.0, 60, marks=pytest.mark.integration),
                                                         pytest.param(0.0, 5.0, 60, marks=pytest.mark.integration)])
def test_short_training_run_lowers_the_loss(chairs, swap, geometric, iterations):
    settings = views.ViewSettings(size=32, supersample=1)
    v = views.render_views([c.occupancy for c in chairs], 4, settings=settings, seed=0, keep_foreground=swap > 0)
    from primkit.model.abstractor import Abstractor

    teacher = Abstractor.load("chair").predict_canonical(np.stack([c.occupancy for c in chairs]))
    config = im.ImageTrainConfig(iterations=iterations, batch_size=12, learning_rate=3e-3, log_every=1, shift_pixels=1,
                                 swap_backgrounds=swap, geometric=geometric, geometric_points=200, geometric_samples=30)
    res = im.train_image_model(v.images, v.shape_index, v.cameras, teacher,
                               im.ImageNetConfig(size=32, channels=(8, 16, 16, 32, 32), fc_width=64), config,
                               progress=False, foreground=v.foreground, alpha=v.alpha,
                               surface_points=np.stack([c.points for c in chairs]),
                               closest=np.stack([c.closest for c in chairs]))
    for term in ("total", "geometric") if geometric else ("total",):
        first = np.mean([h[term] for h in res.history[:5]])
        last = np.mean([h[term] for h in res.history[-5:]])
        assert last < 0.7 * first, term


def _box_shape():
    """A 1 x 0.6 x 0.4 box, prepared (canonical frame: centred, longest side 1, so half-extents 0.5, 0.3, 0.2)."""
    import trimesh

    box = trimesh.creation.box(extents=(2.0, 1.2, 0.8))
    return data.prepare(io.Mesh(np.asarray(box.vertices), np.asarray(box.faces)), data.PrepareSettings(samples=600))


def _pred(z, t):
    z, t = torch.tensor(np.array(z), dtype=torch.float32)[None], torch.tensor(np.array(t), dtype=torch.float32)[None]
    q = torch.zeros(1, len(z[0]), 4)
    q[..., 0] = 1.0
    return im.ImagePrediction(z, q, t, None, None, None)  # what the geometric loss reads


def test_geometric_loss_against_brute_force_on_a_box():
    shape = _box_shape()
    pts = torch.from_numpy(shape.points)[None]
    closest = torch.from_numpy(shape.closest)[None]
    box = np.array([0.5, 0.3, 0.2])
    gen = torch.Generator().manual_seed(0)
    far = (np.array([0.05, 0.05, 0.05]), np.array([2.0, 2.0, 2.0]))  # far outside the shape's grid
    exact = _pred([box, far[0]], [np.zeros(3), far[1]])
    used_one = torch.tensor([[True, False]])
    # the box explains itself: no coverage error, and its surface lies on the shape's (up to the
    # closest-point grid's resolution: a lookup is off by a fraction of a 1/32 cell along the face)
    assert float(_geometric_loss(exact, used_one, pts, closest, 150, gen)) < 0.25 * (1 / 32) ** 2
    # a part the teacher does not use costs nothing; used, the far cube's consistency counts
    assert float(_geometric_loss(exact, torch.tensor([[True, True]]), pts, closest, 150, gen)) > 1.0
    # a shrunken box, brute force: coverage is the mean squared excess of the shape's points over the
    # smaller box; consistency the area-weighted mean squared distance of the smaller box's surface
    # (dense samples) to the box's, which from inside is min over axes of (extent - |x|). The loss
    # reads distances off a 32^3 closest-point grid: measured 8% long in distance here, hence rel=0.15.
    small = 0.9 * box
    excess = np.clip(np.abs(shape.points) - small, 0, None)
    coverage = float((excess ** 2).sum(1).mean())
    inner = primitives.Cuboids(small[None], np.array([[1.0, 0, 0, 0]]), np.zeros((1, 3)), np.array([True]))
    dense = primitives.sample_cuboid_surfaces(inner, 6000, seed=1)
    d = (box - np.abs(dense.points.reshape(-1, 3))).min(1)
    consistency = float((dense.weights.reshape(-1) * d ** 2).sum() / dense.weights.sum())
    got = float(_geometric_loss(_pred([small, far[0]], [np.zeros(3), far[1]]), used_one, pts, closest, 150, gen))
    assert got == pytest.approx(coverage + consistency, rel=0.15)


def test_geometric_training_needs_the_shapes(grids):
    v = views.render_views(grids[:1], 2, settings=SMALL, seed=0)
    from primkit.model.abstractor import RawCuboids

    teacher = RawCuboids(half_extents=np.full((1, 2, 3), 0.1), quaternions=np.tile([1.0, 0, 0, 0], (1, 2, 1)),
                         translations=np.zeros((1, 2, 3)), existence=np.ones((1, 2)))
    config = im.ImageTrainConfig(iterations=1, batch_size=2, geometric=1.0)
    with pytest.raises(ValueError, match="surface_points"):
        im.train_image_model(v.images, v.shape_index, v.cameras, teacher, im.ImageNetConfig(size=32, parts=2), config,
                             progress=False)


@pytest.fixture(scope="module")
def tiny_model(tmp_path_factory):
    net = im.ImageNet(im.ImageNetConfig(size=32, channels=(8, 8, 8, 8, 8), fc_width=16))
    path = tmp_path_factory.mktemp("m") / "tiny.safetensors"
    im.ImageAbstractor(net, {}).save(path, {"views": views.ViewSettings(size=32).to_dict()})
    return path


def test_run_abstract_images_writes_outputs_and_reports_bad_files(tiny_model, tmp_path, grids):
    from types import SimpleNamespace

    from PIL import Image

    from primkit.cli.image import run_abstract_images

    v = views.render_views(grids[:1], 1, settings=SMALL, seed=0)
    Image.fromarray(v.images[0]).resize((80, 50)).save(tmp_path / "chair.png")
    (tmp_path / "broken.png").write_bytes(b"not an image")
    out = tmp_path / "out"
    args = SimpleNamespace(inputs=[str(tmp_path / "chair.png"), str(tmp_path / "broken.png")], model=str(tiny_model),
                           output=str(out), force=False, png=str(out / "chair.png"))
    assert run_abstract_images(args) == 1
    d = json.loads((out / "chair.cuboids.json").read_text())
    assert len(d["parts"]) == 20 and "viewpoint" in d
    from primkit.primitives import Cuboids

    assert Cuboids.from_dict(d).count == 20
    assert (out / "chair.cuboids.ply").is_file()
    assert Image.open(out / "chair.png").size == (2 * 32 * 4 + 8, 32 * 4)
    from pictures import read_picture

    drawn = read_picture(out / "chair.png")  # the picture, and the cuboids drawn over it
    assert drawn.crop(0, 128).foreground_fraction > 0.02 and drawn.crop(136, 264).foreground_fraction > 0.02
    args.inputs = [str(tmp_path / "chair.png")]
    with pytest.raises(FileExistsError, match="--force"):  # outputs exist and no --force: refused before any work
        run_abstract_images(args)
    args.force = True
    assert run_abstract_images(args) == 0


def test_a_volume_model_is_refused_as_an_image_model():
    with pytest.raises(ValueError, match="not an image model"):
        im.ImageAbstractor.load("chair")


def test_train_image_command_writes_a_model_the_abstract_side_reads(tmp_path):
    from types import SimpleNamespace

    from PIL import Image

    from primkit.cli import main
    from primkit.cli.image import run_abstract_images

    synthetic.write_collection(tmp_path / "chairs", "chair", 3, seed=2)
    model = tmp_path / "img.safetensors"
    argv = [str(tmp_path / "chairs"), "-o", str(model), "--teacher", "chair", "--views", "2", "--size", "32",
            "--iterations", "3", "--batch-size", "4", "--hold-out", "0", "--workers", "1", "--samples", "500",
            "--cache", str(tmp_path / "cache"), "--geometric", "2"]
    assert main(["train-image", *argv]) == 0
    assert main(["train-image", *argv]) == 2  # exists, no --force
    meta = im.ImageAbstractor.load(model).metadata
    assert meta["kind"] == "image-abstractor" and meta["training"]["views"] == 6 and meta["views"]["size"] == 32
    assert meta["training"]["config"]["geometric"] == 2 and meta["training"]["final"]["geometric"] > 0
    Image.fromarray(np.full((40, 40, 3), 200, np.uint8)).save(tmp_path / "grey.png")
    args = SimpleNamespace(inputs=[str(tmp_path / "grey.png")], model=str(model), output=str(tmp_path / "out"),
                           force=False, png=None)
    assert run_abstract_images(args) == 0
    assert (tmp_path / "out" / "grey.cuboids.json").is_file() and not (tmp_path / "out" / "grey.png").exists()
