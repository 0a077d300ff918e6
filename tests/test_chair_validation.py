"""scripts/chair_validation.py: chairs grouped by structure from hand-made voxel label grids (no data
needed), and its per-group figures against counts done by hand."""

import importlib.util
import itertools
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
BACK, SEAT, LEGS, ARMS = 0, 1, 2, 3


@pytest.fixture(scope="module")
def cv():
    spec = importlib.util.spec_from_file_location("chair_validation", ROOT / "scripts" / "chair_validation.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules["chair_validation"] = module  # its dataclasses look their module up
    try:
        spec.loader.exec_module(module)
        yield module
    finally:
        sys.modules.pop("chair_validation", None)


def seat_and_back(labels, top=10, back=True, arms=False):
    """A 16 x 16 seat two cells thick at ``top`` (x, z 8-23), a back panel at x 8-9, arms at the sides."""
    labels[8:24, top:top + 2, 8:24] = SEAT
    if back:
        labels[8:10, top + 2:top + 18, 8:24] = BACK
    if arms:
        labels[10:22, top + 8, 8] = ARMS
        labels[10:22, top + 8, 23] = ARMS
    return labels


def grid():
    return np.full((32, 32, 32), -1)


def four_legs(**kw):
    labels = grid()
    for x, z in itertools.product((8, 22), (8, 22)):
        labels[x:x + 2, 0:10, z:z + 2] = LEGS
    return seat_and_back(labels, **kw)


def column(x=15, z=15, foot=True, star=False, **kw):
    """A 2 x 2 column from the floor to the seat at (x, z), on a round foot or a five-spoke star
    whose casters are the only cells on the floor."""
    labels = grid()
    labels[x:x + 2, 0:10, z:z + 2] = LEGS
    if foot:
        xx, zz = np.meshgrid(np.arange(32), np.arange(32), indexing="ij")
        labels[:, 0, :][(xx - 15.5) ** 2 + (zz - 15.5) ** 2 <= 7 ** 2] = LEGS
    if star:
        for k in range(5):
            a = 2 * np.pi * k / 5
            for r in np.linspace(0, 9, 30):
                labels[int(15.5 + r * np.cos(a)), 1, int(15.5 + r * np.sin(a))] = LEGS
            labels[int(15.5 + 9 * np.cos(a)), 0, int(15.5 + 9 * np.sin(a))] = LEGS  # the caster
    return seat_and_back(labels, **kw)


def test_four_separate_legs_are_legs(cv):
    s = cv.chair_structure(four_legs())
    assert (s.base, s.blobs, s.back, s.arms) == ("legs", 4, True, False)
    assert cv.groups_of(s) == ["all", "four-legged"]


def test_three_legs_and_a_stretcher_ring_are_still_legs(cv):
    labels = four_legs()
    labels[8:24, 5, 8:24][1:-1, 1:-1] = -1
    labels[8:24, 5, 8] = labels[8:24, 5, 23] = labels[8, 5, 8:24] = labels[23, 5, 8:24] = LEGS  # one layer joins them
    assert cv.base_kind(labels) == ("legs", 4)
    labels = four_legs()
    labels[22:24, 0:10, 22:24] = -1  # a leg taken away: three
    assert cv.base_kind(labels) == ("legs", 3)


def test_a_central_column_is_a_pedestal_on_a_foot_or_a_star(cv):
    assert cv.base_kind(column()) == ("pedestal", 1)
    assert cv.base_kind(column(foot=False, star=True)) == ("pedestal", 1)  # five casters on the floor
    s = cv.chair_structure(column(arms=True))
    assert cv.groups_of(s) == ["all", "armchairs", "pedestal"]


def test_a_column_at_the_seats_edge_or_two_runners_are_other(cv):
    assert cv.base_kind(column(x=22, foot=False)) == ("other", 1)  # a cantilever's front post
    labels = grid()
    labels[8:24, 0:10, 8:10] = LEGS
    labels[8:24, 0:10, 22:24] = LEGS  # two side panels
    seat_and_back(labels)
    assert cv.base_kind(labels) == ("other", 2)
    s = cv.chair_structure(seat_and_back(grid(), top=0))  # a seat on the floor: no base at all
    assert (s.base, s.blobs) == ("other", 0)
    assert cv.groups_of(s) == ["all", "other base"]


def test_no_back_label_is_a_stool_in_its_own_group(cv):
    s = cv.chair_structure(column(back=False))
    assert (s.back, s.base) == (False, "pedestal")
    assert cv.groups_of(s) == ["all", "no back"]
    assert cv.groups_of(cv.chair_structure(four_legs(back=False))) == ["all", "no back"]


def test_group_figures_against_hand_counts(cv):
    labels = ["back", "seat", "legs", "arms"]
    # chair 1: truth back back seat legs arm; chair 2: seat seat legs (no back, no arms)
    truths = [np.array([0, 0, 1, 2, 3]), np.array([1, 1, 2])]
    mapping = np.array([0, 1, 2, 3, -1])  # index 4 means no label
    assignments = [np.array([0, 1, 1, 2, 4]), np.array([1, 0, 2])]
    f = cv.group_figures(assignments, truths, mapping, np.array([5, 3]), labels)
    # chair 1: back 1/2, seat 1/2, legs 1, arms 0 (index 4 maps to nothing); chair 2: back 0 (a back
    # where there is none), seat 1/2, legs 1, arms 1 (absent from both)
    assert f["iou"] == {"back": 0.25, "seat": 0.5, "legs": 1.0, "arms": 0.5}
    assert f["mean_iou"] == pytest.approx((0.25 + 0.5 + 1.0) / 3, abs=1e-4)
    assert f["arms"] == {"with": 1, "true_positive": 0, "false_positive": 0, "missed": 1, "f1": 0.0}
    assert (f["without_back"], f["back_absent_kept_absent"], f["parts_mean"]) == (1, 0.0, 4.0)
    armless = cv.group_figures(assignments[1:], truths[1:], mapping, np.array([3]), labels)
    assert armless["arms"] == {"with": 0, "true_positive": 0, "false_positive": 0, "missed": 0, "f1": None}
    assert cv.group_figures([], [], mapping, np.array([], int), labels) == {"chairs": 0}
