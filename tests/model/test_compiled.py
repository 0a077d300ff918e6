"""primkit.model._compiled.over_batch: the kernels split over the batch give the one-call answer bit for bit."""

import numpy as np
import pytest
import torch

from primkit.model._field_kernels import consistency_backward, consistency_forward
from primkit.model._union_kernels import union_backward, union_forward
from primkit.primitives.rotations import quaternion_to_matrix


@pytest.fixture
def threads():
    before = torch.get_num_threads()
    yield torch.set_num_threads
    torch.set_num_threads(before)


def _arrays(b=7, m=5, n=60, k=24, r=8, seed=0):
    rng = np.random.default_rng(seed)
    rot = quaternion_to_matrix(rng.normal(size=(b, m, 4))).astype(np.float32)
    z = rng.uniform(0.02, 0.3, (b, m, 3)).astype(np.float32)
    t = rng.uniform(-0.3, 0.3, (b, m, 3)).astype(np.float32)
    offset = np.ascontiguousarray(np.einsum("bmji,bmj->bmi", rot, t), np.float32)
    present = (rng.random((b, m)) < 0.6).astype(np.float32)
    points = rng.uniform(-0.5, 0.5, (b, n, 3)).astype(np.float32)
    uv = rng.uniform(-1, 1, (b, m, k, 2)).astype(np.float32)
    planar = rng.uniform(-0.5, 0.5, (b, 3, r**3)).astype(np.float32)
    return rot, z, t, offset, present, points, uv, planar, r


def _run(rot, z, t, offset, present, points, uv, planar, r):
    absent = (1 - present) * np.float32(100)
    u = union_forward(rot, offset, z, absent, present, points, True, 10.0)
    ub = union_backward(rot, offset, z, points, u[1], np.ones_like(u[0]))
    c = consistency_forward(rot, z, t, uv, planar, r)
    cb = consistency_backward(rot, z, t, uv, c[1], np.ones_like(c[0]))
    return [*u, *ub, *c, *cb]


def test_split_batch_is_bit_identical_to_one_call(threads):
    arrays = _arrays()
    threads(1)
    one = _run(*arrays)
    for n in (2, 3, 16):  # more runs than shapes too
        threads(n)
        split = _run(*arrays)
        for a, b in zip(one, split):
            assert a.dtype == b.dtype and np.array_equal(a, b)


def test_each_shape_is_its_own(threads):
    # shape i's answer alone equals its row in the batch's answer (what makes splitting exact)
    threads(2)
    rot, z, t, offset, present, points, uv, planar, r = _arrays(b=4)
    whole = _run(rot, z, t, offset, present, points, uv, planar, r)
    i = 2
    alone = _run(*(a[i:i + 1] for a in (rot, z, t, offset, present, points, uv, planar)), r)
    for w, a in zip(whole, alone):
        assert np.array_equal(w[i:i + 1], a)
