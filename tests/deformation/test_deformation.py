"""Deformation transfer and part edits: closed forms on shapes made of boxes, seams, the CLI."""

import numpy as np
import pytest

from primkit import deformation as D
from primkit.primitives import Cuboids, matrix_to_quaternion


def box_mesh(lo, hi, n=4):
    """A closed box surface, each face an n x n grid of quads (two triangles each)."""
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    verts, faces = [], []
    g = np.linspace(0.0, 1.0, n + 1)
    for axis in range(3):
        for side in (0, 1):
            a, b = [i for i in range(3) if i != axis]
            base = len(verts)
            for u in g:
                for w in g:
                    p = np.empty(3)
                    p[axis] = (lo if side == 0 else hi)[axis]
                    p[a] = lo[a] + u * (hi[a] - lo[a])
                    p[b] = lo[b] + w * (hi[b] - lo[b])
                    verts.append(p)
            for i in range(n):
                for j in range(n):
                    c = base + i * (n + 1) + j
                    quad = [c, c + n + 1, c + n + 2, c + 1]
                    tri = [[quad[0], quad[1], quad[2]], [quad[0], quad[2], quad[3]]]
                    if side == 0:
                        tri = [t[::-1] for t in tri]
                    faces.extend(tri)
    return np.array(verts), np.array(faces)


def boxes_cuboids(boxes, rotations=None):
    lo = np.array([b[0] for b in boxes], float)
    hi = np.array([b[1] for b in boxes], float)
    rot = np.tile(np.eye(3), (len(boxes), 1, 1)) if rotations is None else np.asarray(rotations)
    return Cuboids((hi - lo) / 2, matrix_to_quaternion(rot), (hi + lo) / 2, np.ones(len(boxes), bool))


# a stool: a seat on one central leg, front +X, up +Y
LEG = ([-0.05, -0.5, -0.05], [0.05, 0.0, 0.05])
SEAT = ([-0.3, 0.0, -0.3], [0.3, 0.1, 0.3])


def stool():
    lv, lf = box_mesh(*LEG)
    sv, sf = box_mesh(*SEAT)
    return np.vstack([lv, sv]), np.vstack([lf, sf + len(lv)]), boxes_cuboids([LEG, SEAT])


def test_identity_edit_gives_the_source_back():
    v, f, cub = stool()
    for falloff in (None, 0.05, 0.3):
        d = D.edit(v, cub, falloff=falloff)
        assert np.allclose(d.vertices, v, atol=1e-15, rtol=0)
        same = D.deform(v, cub, cub, falloff=falloff)
        assert np.max(np.abs(same.vertices - v)) < 1e-12


def test_local_coordinates_scaled_by_half_extents():
    v, f, cub = stool()
    b = D.bind(v, cub)
    u = b.local_coordinates(1)
    assert np.allclose(u, (v - cub.translations[1]) / cub.half_extents[1])
    # every vertex of the seat box lies on the unit cube's surface in its scaled coordinates
    seat = b.labels == 1
    assert np.allclose(np.abs(u[seat]).max(axis=1), 1.0)


def test_known_affine_edit_on_boxes():
    """Scaling the leg (1, 1.5, 1) about its foot: the leg's vertices follow x -> pivot + S (x - pivot)
    and the seat, resting on it, rises by 0.5 * leg height = 0.25; away from the seam (beyond the
    falloff) both are exact."""
    v, f, cub = stool()
    falloff = 0.02
    d = D.edit(v, cub, scale={0: (1.0, 1.5, 1.0)}, falloff=falloff)
    assert d.edit.carried == {1: [0]}
    pivot = np.array([0.0, -0.5, 0.0])
    want = v.copy()
    leg = np.arange(len(v)) < len(box_mesh(*LEG)[0])
    want[leg] = pivot + (v[leg] - pivot) * [1.0, 1.5, 1.0]
    want[~leg] = v[~leg] + [0.0, 0.25, 0.0]
    sd = D.signed_distances(v, cub)
    far = np.abs(sd[:, 0] - sd[:, 1]) > falloff
    assert far.sum() > len(v) / 2
    assert np.allclose(d.vertices[far], want[far], atol=1e-12)
    # the new cuboids: leg 0.75 tall from the ground, seat on top of it
    c = d.edit.cuboids
    assert np.allclose(c.half_extents[0], [0.05, 0.375, 0.05]) and np.allclose(c.translations[0], [0, -0.125, 0])
    assert np.allclose(c.translations[1], cub.translations[1] + [0, 0.25, 0])


def test_rotation_tips_backwards_about_the_bottom_face():
    v, f, cub = stool()
    d = D.edit(v, cub, rotate={1: 90.0}, carry=False, falloff=0.01)
    # right-handed about +Z through the seat's bottom-face centre (0, 0, 0): (x, y) -> (-y, x)
    top_front = np.array([0.3, 0.1, 0.3])
    i = int(np.argmin(np.linalg.norm(v - top_front, axis=1)))
    assert np.allclose(d.vertices[i], [-0.1, 0.3, 0.3], atol=1e-12)


def test_transfer_maps_cuboid_onto_target_with_axis_matching():
    src = boxes_cuboids([LEG, SEAT])
    # the target seat is wider and given with its axes relabelled (turned 90 degrees about Y)
    turn = np.array([[0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [-1.0, 0.0, 0.0]])
    tgt_box = boxes_cuboids([LEG, ([-0.4, 0.0, -0.3], [0.4, 0.1, 0.3])])
    tgt = Cuboids(tgt_box.half_extents[:, [2, 1, 0]], matrix_to_quaternion(np.stack([np.eye(3), turn])),
                  tgt_box.translations, tgt_box.existence)
    m = D.cuboid_map(src, tgt, 1)
    assert np.allclose(m[:3, :3], np.diag([0.4 / 0.3, 1.0, 1.0]))  # no 90-degree spin
    corners = src.to_mesh()[0][8:]
    moved = corners @ m[:3, :3].T + m[:3, 3]
    assert np.allclose(np.sort(moved, axis=0), np.sort(tgt.to_mesh()[0][8:], axis=0))


def test_transfer_reports_parts_present_in_one_shape():
    a = boxes_cuboids([LEG, SEAT, ([-0.3, 0.1, -0.3], [-0.25, 0.6, 0.3])])
    b = a.with_existence([True, True, False])
    up = Cuboids(b.half_extents, b.quaternions, b.translations + [0, 0.2, 0], b.existence)
    t = D.transfer_transforms(a, up)
    assert t.paired == [0, 1] and t.target_only == []
    assert t.source_only == {2: 1}  # the back follows the seat it touches
    assert np.allclose(t.transforms[2], t.transforms[1])
    t2 = D.transfer_transforms(b, a)
    assert t2.target_only == [2] and t2.source_only == {}


def test_seam_moves_continuously():
    """A two-part column, the upper part moved sideways: vertices of the seam (the shared plane)
    move by half the offset (equal weights there), displacement changes continuously along the
    column (bounded by offset / falloff per unit height), and no triangle flips."""
    lo_box = ([-0.1, -0.5, -0.1], [0.1, 0.0, 0.1])
    hi_box = ([-0.1, 0.0, -0.1], [0.1, 0.5, 0.1])
    v, f = box_mesh([-0.1, -0.5, -0.1], [0.1, 0.5, 0.1], n=20)  # one connected surface across the seam
    cub = boxes_cuboids([lo_box, hi_box])
    tgt = Cuboids(cub.half_extents, cub.quaternions, cub.translations + [[0, 0, 0], [0.05, 0, 0]], cub.existence)
    falloff = 0.2
    d = D.deform(v, cub, tgt, falloff=falloff, faces=f)
    disp = d.vertices - v
    seam = np.abs(v[:, 1]) < 1e-12
    assert np.allclose(disp[seam], [0.025, 0, 0])
    # independent expectation: on the side walls the signed distances are -(depth to the nearest
    # face); for |y| >= falloff/2 away from the corners, only one part weighs
    side = (np.abs(v[:, 1]) > falloff) & (np.abs(np.abs(v[:, 0]) - 0.1) < 1e-12)
    assert np.allclose(disp[side & (v[:, 1] > 0)], [0.05, 0, 0]) and np.allclose(disp[side & (v[:, 1] < 0)], 0)
    # continuity: along every edge the displacement changes by at most |edge| * offset * 1.5 / falloff·2
    e = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    jump = np.linalg.norm(disp[e[:, 0]] - disp[e[:, 1]], axis=1)
    length = np.linalg.norm(v[e[:, 0]] - v[e[:, 1]], axis=1)
    assert np.all(jump <= length * 0.05 * 1.5 / (falloff / 2) + 1e-12)
    assert D.flipped_fraction(v, d.vertices, f) == 0.0
    # hard assignment (a tiny falloff) tears the seam: a jump of the whole offset across one edge row
    hard = D.deform(v, cub, tgt, falloff=1e-9, faces=f)
    assert np.max(np.linalg.norm((hard.vertices - v)[e[:, 0]] - (hard.vertices - v)[e[:, 1]], axis=1)) > 0.02


def test_harmonic_weights_are_a_partition_of_unity():
    v, f = box_mesh([-0.1, -0.5, -0.1], [0.1, 0.5, 0.1], n=10)
    cub = boxes_cuboids([([-0.1, -0.5, -0.1], [0.1, 0.0, 0.1]), ([-0.1, 0.0, -0.1], [0.1, 0.5, 0.1])])
    w = D.blend_weights(v, cub, 0.2, faces=f, method="harmonic")
    assert np.allclose(w.sum(axis=1), 1.0) and w.min() >= 0
    wd = D.blend_weights(v, cub, 0.2)
    fixed = wd.max(axis=1) == 1.0
    assert np.allclose(w[fixed], wd[fixed])


def test_quality_measures_against_hand_computations():
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]], float)
    f = np.array([[0, 1, 2], [1, 3, 2]])
    mirrored = v * [-1, 1, 1]
    assert D.flipped_fraction(v, mirrored, f) == 1.0
    moved = v.copy()
    moved[3] = [-1, -1, 0]  # only the second triangle turns over
    assert D.flipped_fraction(v, moved, f) == 0.5
    stretched = v * [2, 1, 1]
    dist = D.edge_distortion(v, stretched, f, np.zeros(4, int))
    # edges: 4 sides (2 of length 1 along x -> 2, 2 along y -> 1) and one diagonal sqrt2 -> sqrt5
    want = sorted([1.0, 1.0, 0.0, 0.0, np.sqrt(5) / np.sqrt(2) - 1])
    assert dist["all"].edges == 5 and np.isclose(dist["all"].max, 1.0)
    assert np.isclose(dist["all"].median, np.median(want))
    rel = D.edge_distortion(v, stretched, f, np.zeros(4, int), linear=np.diag([2.0, 1, 1])[None])
    assert rel["all"].max < 1e-12


def test_legs_edit_on_a_procedural_chair():
    """Lengthening the legs by 30% raises the chair by 30% of the leg cuboids' height, and the
    back keeps its shape (edge lengths within 1%)."""
    from primkit import synthetic

    s = next(c for c in synthetic.generate("chair", 6, seed=3) if "leg_front_left" in [c.part_names[i] for i in np.unique(c.face_labels)])
    names = list(s.part_names)
    lab = np.asarray(s.face_labels)
    v, f = np.asarray(s.vertices, float), np.asarray(s.faces)
    legs = [n for n in names if n.startswith("leg_")]
    order = legs + ["seat", "back"]
    boxes = []
    for n in order:  # a cuboid per labelled part: the bounding box of its vertices
        pv = v[np.unique(f[lab == names.index(n)])]
        boxes.append((pv.min(0), pv.max(0)))
    cub = boxes_cuboids(boxes)
    d = D.edit(v, cub, scale={k: (1.0, 1.3, 1.0) for k in range(len(legs))}, falloff=0.02)
    assert sorted(d.edit.carried) == [len(legs), len(legs) + 1]  # seat and back carried
    leg_height = 2 * cub.half_extents[0, 1]
    dh = np.ptp(d.vertices[:, 1]) - np.ptp(v[:, 1])
    assert abs(dh - 0.3 * leg_height) < 0.03 * 0.3 * leg_height
    back = d.binding.labels == len(legs) + 1
    dist = D.edge_distortion(v, d.vertices, f, np.where(back, 1, -1))
    assert dist[1].max < 0.01


def test_cli_bad_file_is_one_line(tmp_path, capsys):
    from primkit.cli import main

    bad = tmp_path / "broken.off"
    bad.write_text("OFF\n3 1 0\n0 0 0\n1 0 0\n")
    rc = main(["edit", str(bad), "--model", "chair", "--scale", "part16=1.2", "-o", str(tmp_path / "out.ply"),
               "--cache", str(tmp_path / "cache"), "--workers", "1"])
    errors = [line for line in capsys.readouterr().err.splitlines() if "broken.off" in line]
    assert rc == 1 and len(errors) == 1


def test_cli_edit_unknown_part_is_usage_error(tmp_path, capsys):
    from primkit import io, synthetic
    from primkit.cli import main

    s = synthetic.generate("chair", 1, seed=1)[0]
    path = io.write_mesh(tmp_path / "c.off", s.vertices, s.faces)
    rc = main(["edit", str(path), "--model", "chair", "--scale", "wings=2", "-o", str(tmp_path / "out.off"),
               "--cache", str(tmp_path / "cache"), "--workers", "1"])
    err = [line for line in capsys.readouterr().err.splitlines() if line.startswith("primkit:")]
    assert rc == 2 and len(err) == 1 and "unknown part 'wings'" in err[0]


def test_cli_deform_writes_source_topology(tmp_path):
    from primkit import io, synthetic
    from primkit.cli import main

    a, b = synthetic.generate("chair", 2, seed=5)
    pa = io.write_mesh(tmp_path / "a.off", a.vertices, a.faces)
    pb = io.write_mesh(tmp_path / "b.off", b.vertices, b.faces)
    out = tmp_path / "a_to_b.off"
    rc = main(["deform", str(pa), str(pb), "--model", "chair", "-o", str(out), "--cache", str(tmp_path / "cache"),
               "--workers", "1"])
    assert rc == 0
    m = io.read_mesh(out)
    assert np.array_equal(m.faces, np.asarray(a.faces)) and m.vertices.shape == np.asarray(a.vertices).shape
    import json

    q = json.loads(out.with_suffix(".json").read_text())["quality"]
    assert q["chamfer_result_target"] < q["chamfer_source_target"]
    assert main(["deform", str(pa), str(pb), "--model", "chair", "-o", str(out),
                 "--cache", str(tmp_path / "cache")]) == 2  # exists, no --force


def test_unfold_removes_flips_and_keeps_parts_away_from_them():
    """A two-part column whose upper part is pushed down by more than the blending width folds the
    seam; :func:`unfold` re-solves only neighbourhoods of the folds: afterwards no triangle is
    flipped, vertices it did not touch are exactly where the blend put them, the upper end still
    moves rigidly with its cuboid, and a fold-free blend is left alone (identity exact)."""
    lo_box = ([-0.1, -0.5, -0.1], [0.1, 0.0, 0.1])
    hi_box = ([-0.1, 0.0, -0.1], [0.1, 0.5, 0.1])
    v, f = box_mesh([-0.1, -0.5, -0.1], [0.1, 0.5, 0.1], n=20)
    cub = boxes_cuboids([lo_box, hi_box])
    tgt = Cuboids(cub.half_extents, cub.quaternions, cub.translations + [[0, 0, 0], [0, -0.3, 0]], cub.existence)
    plain = D.deform(v, cub, tgt, falloff=0.05, faces=f)
    assert plain.resolved is None and D.flipped_fraction(v, plain.vertices, f) > 0  # the blend folds
    fixed = D.deform(v, cub, tgt, falloff=0.05, faces=f, unfold=True)
    assert D.flipped_fraction(v, fixed.vertices, f) == 0.0
    keep = ~fixed.resolved
    assert keep.any() and np.array_equal(fixed.vertices[keep], plain.vertices[keep])
    top = v[:, 1] > 0.45
    assert np.allclose(fixed.vertices[top], v[top] + [0, -0.3, 0])
    same = D.deform(v, cub, cub, faces=f, unfold=True)
    assert not same.resolved.any() and np.allclose(same.vertices, v, atol=1e-15, rtol=0)


def test_lengthen_legs_below_the_seat_on_a_procedural_chair():
    """``lengthen`` legs by 30%: the chair grows by 0.3 x (seat underside - floor), computed from
    the generator's ``leg_length``, and the back's edges keep their lengths (within 1%), also
    when the rear-leg cuboids reach up past the seat into the back (as the model's do on real
    chairs)."""
    from primkit import synthetic

    s = synthetic.chair(seed=5, swivel=False, has_arms=False, leg_splay_deg=0.0)
    names = list(s.part_names)
    lab = np.asarray(s.face_labels)
    v, f = np.asarray(s.vertices, float), np.asarray(s.faces)
    legs = [n for n in names if n.startswith("leg_")]
    boxes = []
    for n in legs + ["seat", "back"]:  # a cuboid per labelled part: the bounding box of its vertices
        pv = v[np.unique(f[lab == names.index(n)])]
        boxes.append([pv.min(0), pv.max(0)])
    top = boxes[-1][1][1]
    for b in boxes[: len(legs)]:
        if b[0][0] < 0:  # rear legs (back at -X): cuboids running up into the back posts
            b[1][1] = 0.5 * (top + boxes[len(legs)][1][1])
    cub = boxes_cuboids(boxes)
    seat, back = len(legs), len(legs) + 1
    d = D.edit(v, cub, lengthen={k: 1.3 for k in range(len(legs))}, faces=f, unfold=True)
    L = d.edit.lengthening
    assert L.support == seat
    assert sorted(d.edit.carried) == [seat, back]
    # the generator normalises its metre-like units: the seat (no arms) is the widest part along Z
    unit = np.ptp(v[:, 2]) / s.attributes["seat_width"]
    expected = 0.3 * unit * s.attributes["leg_length"]  # leg_length: floor to seat underside
    dh = np.ptp(d.vertices[:, 1]) - np.ptp(v[:, 1])
    assert abs(dh - expected) < 0.02 * expected
    assert np.isclose(d.vertices[:, 1].min(), v[:, 1].min())  # the feet stay on the floor
    in_back = d.binding.labels == back
    dist = D.edge_distortion(v, d.vertices, f, np.where(in_back, 1, -1))
    assert dist[1].edges > 0 and dist[1].max < 0.01
    assert D.flipped_fraction(v, d.vertices, f) < 0.001
    # the legs really are 30% longer below the seat: a foot-to-underside vertical span
    leg = np.isin(d.binding.labels, range(len(legs))) & (v[:, 1] < L.cut - 0.05) & (v[:, 1] > L.floor + 0.05)
    ratio = (d.vertices[leg, 1] - L.floor) / (v[leg, 1] - L.floor)
    assert leg.any() and np.allclose(ratio, 1.3, atol=0.02)


def test_lengthen_is_checked():
    v, f, cub = stool()
    with pytest.raises(ValueError, match="cannot also be scaled"):
        D.edit_cuboids(cub, lengthen={0: 1.3}, scale={0: 2.0})
    with pytest.raises(ValueError, match="> 0"):
        D.edit_cuboids(cub, lengthen={0: -1.0})
    e = D.edit_cuboids(cub, lengthen={0: 1.5})  # the stool's seat is held up: cut at its bottom
    assert e.lengthening.support == 1 and np.isclose(e.lengthening.cut, 0.0)
    assert np.allclose(e.cuboids.half_extents[0], [0.05, 0.375, 0.05])
    assert np.allclose(e.transforms[1, :3, 3], [0.0, 0.25, 0.0])
