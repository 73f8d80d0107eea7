"""warprt's own BVH (``warprt.accel``): the tree the host builds, and rays through it.

The renders through it are checked against the loops over each table in test_features.py
(spheres, rectangles, disks, pieces of long bars) and test_worlds.py (one tree per world,
refitted as the worlds move); here: the tree's structure, its depth bound, and closest hits and
shadows through a tree of many shapes against an independent float64 brute force."""

from __future__ import annotations

import numpy as np
import pytest

import warprt
from warprt import accel


def _check_tree(lo, hi):
    order, c0, c1, boxes = accel.build_tree(lo, hi)
    n = lo.shape[0]
    assert sorted(order) == list(range(n))
    refs = np.concatenate([c0, c1])
    # every primitive is one leaf, every node but the root one child; children after parents
    assert sorted(-refs[refs < 0] - 1) == list(range(n))
    assert sorted(refs[refs >= 0]) == list(range(1, n - 1))
    for i in range(n - 1):
        for c, (blo, bhi) in ((c0[i], (boxes[i, 0], boxes[i, 1])), (c1[i], (boxes[i, 2], boxes[i, 3]))):
            assert c < 0 or c > i
            # the child's box is exactly the union of what it holds
            if c < 0:
                p = order[-c - 1]
                np.testing.assert_array_equal(blo, lo[p])
                np.testing.assert_array_equal(bhi, hi[p])
            else:
                np.testing.assert_array_equal(blo, np.minimum(boxes[c, 0], boxes[c, 2]))
                np.testing.assert_array_equal(bhi, np.maximum(boxes[c, 1], boxes[c, 3]))
    return order, c0, c1, boxes


@pytest.mark.parametrize("n", [2, 3, 17, 300, 5000])
def test_every_primitive_is_one_leaf_and_every_box_holds_its_children(n):
    rng = np.random.default_rng(n)
    c = rng.uniform(-10, 10, (n, 3)) * rng.uniform(0.01, 1, (n, 1)) ** 3  # clustered and spread
    r = rng.uniform(1e-3, 0.5, (n, 3))
    order, c0, c1, _ = _check_tree(c - r, c + r)
    # SAH may peel a cluster off a few at a time, but from MEDIAN_FROM_LEVEL on nodes halve: the
    # traversal stack (one entry per level) always suffices
    assert accel.tree_depth(c0, c1) <= min(accel.MEDIAN_FROM_LEVEL + np.ceil(np.log2(n)), accel.MAX_DEPTH)


def test_equal_boxes_split_at_the_median_and_the_depth_stays_bounded():
    n = 1000
    lo, hi = np.zeros((n, 3)), np.ones((n, 3))
    _, c0, c1, _ = _check_tree(lo, hi)
    assert accel.tree_depth(c0, c1) == int(np.ceil(np.log2(n)))
    # a chain that SAH would split one by one: sizes growing geometrically along x
    x = 2.0 ** np.arange(200, dtype=np.float64) * 1e-30
    lo = np.stack([x, np.zeros(200), np.zeros(200)], 1)
    _, c0, c1, _ = _check_tree(lo, lo + np.stack([x, x, x], 1))
    assert accel.tree_depth(c0, c1) <= accel.MAX_DEPTH


def test_fewer_than_two_boxes_is_refused():
    with pytest.raises(ValueError, match="two"):
        accel.build_tree(np.zeros((1, 3)), np.ones((1, 3)))


def _brute_force(spheres, o, d):
    """Nearest sphere hit along each ray in float64 (t > 0), -1 for none."""
    best = np.full(o.shape[0], np.inf)
    idx = np.full(o.shape[0], -1)
    for k, (c, r) in enumerate(spheres):
        oc = o - c
        b = np.einsum("ij,ij->i", oc, d)
        disc = b * b - (np.einsum("ij,ij->i", oc, oc) - r * r)
        s = np.sqrt(np.maximum(disc, 0.0))
        for t in (-b - s, -b + s):
            ok = (disc >= 0) & (t > 0.0) & (t < best)
            best[ok], idx[ok] = t[ok], k
    return np.where(np.isfinite(best), best, -1.0), idx


def test_closest_hits_through_the_tree_match_a_brute_force(device):
    """2000 small spheres: the hit shape and t of 4096 rays from inside and outside the cloud,
    in all directions (axis-aligned ones among them), as a float64 brute force finds them."""
    rng = np.random.default_rng(11)
    c = rng.uniform(-5, 5, (2000, 3))
    r = rng.uniform(0.02, 0.3, 2000)
    spheres = list(zip(c, r))
    scene = warprt.Scene(camera=warprt.Camera(width=8, height=8),
                         shapes=tuple(warprt.Sphere(center=tuple(p), radius=float(q)) for p, q in spheres),
                         lights=(warprt.PointLight(),))
    renderer = warprt.Renderer(scene, device=device)
    assert renderer.built.analytic_bvh is not None
    o = rng.uniform(-7, 7, (4096, 3))
    d = rng.normal(size=(4096, 3))
    d[:300] = np.eye(3)[rng.integers(0, 3, 300)] * rng.choice([-1, 1], (300, 1))  # axis-aligned rays
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    o, d = o.astype(np.float32).astype(np.float64), d.astype(np.float32).astype(np.float64)  # as the device sees them
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    hits = warprt.trace_rays(renderer, o, d)
    t_ref, k_ref = _brute_force(spheres, o, d)
    # rays that graze a sphere within float32 rounding may go either way: leave them out
    margin = np.zeros(len(o), dtype=bool)
    for p, q in spheres:
        oc = o - p
        b = np.einsum("ij,ij->i", oc, d)
        dist = np.sqrt(np.maximum(np.einsum("ij,ij->i", oc, oc) - b * b, 0.0))
        margin |= np.abs(dist - q) < 1e-4 * max(q, 1.0) + 1e-5 * np.abs(b)
    sure = ~margin
    assert sure.mean() > 0.97
    got = hits["shape"][sure]
    np.testing.assert_array_equal(np.where(got >= 0, got, -1), k_ref[sure])
    hit = sure & (k_ref >= 0)
    assert hit.sum() > 500
    np.testing.assert_allclose(hits["t"][hit], t_ref[hit], rtol=2e-6, atol=2e-6)
