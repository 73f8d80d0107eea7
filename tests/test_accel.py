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


def test_the_packet_node_test_lane_by_lane_equals_its_vector_form():
    """``accel.packet_node`` runs a packet's 8 lanes as clang vectors on the CPU and lane by lane
    where that is not available (CUDA). Both branches, compiled here on the CPU, give the same
    entries bit for bit as a float32 numpy slab test over random boxes and rays: origins inside
    boxes, axis-aligned directions (1/d of a zero component as ``safe_inverse`` makes it),
    lanes whose nearest hit is before the box, and unused lanes (nearest hit < 0)."""
    import warp as wp

    rng = np.random.default_rng(7)
    n_nodes, n = 64, 4096
    lo = rng.uniform(-2, 1, (n_nodes, 2, 3)).astype(np.float32)
    hi = (lo + rng.uniform(0.01, 2, (n_nodes, 2, 3))).astype(np.float32)
    rec = np.zeros((n_nodes, 14), np.float32)
    rec[:, 0:3], rec[:, 3:6], rec[:, 6:9], rec[:, 9:12] = lo[:, 0], hi[:, 0], lo[:, 1], hi[:, 1]
    ref = rng.integers(0, n_nodes, n).astype(np.int32)
    o = rng.uniform(-3, 3, (n, 8, 3)).astype(np.float32)
    # most lanes aimed at a point of one of the node's boxes (a pixel's rays meet the same boxes)
    child = rng.integers(0, 2, (n, 8))
    aim = lo[ref[:, None], child] + rng.random((n, 8, 3)) * (hi[ref[:, None], child] - lo[ref[:, None], child])
    d = np.where(rng.random((n, 8, 1)) < 0.7, aim - o, rng.normal(size=(n, 8, 3)))
    axis = rng.random((n, 8)) < 0.1
    d[axis] = np.eye(3)[rng.integers(0, 3, axis.sum())] * rng.choice([-1, 1], (axis.sum(), 1))
    d = (d / np.linalg.norm(d, axis=-1, keepdims=True)).astype(np.float32)
    inv = np.float32(1.0) / np.where(d == 0, np.float32(1e-20), d)
    best = rng.uniform(0.5, 6, (n, 8)).astype(np.float32)
    best[rng.random((n, 8)) < 0.15] = -1.0  # unused lanes

    # the float32 reference: the scalar traversal's slab test and conditions, lane by lane
    b = rec[ref]  # (n, 14)
    want = np.empty((n, 2), np.float32)
    for c in range(2):
        lo_c, hi_c = b[:, None, 6 * c:6 * c + 3], b[:, None, 6 * c + 3:6 * c + 6]
        a_, b_ = (lo_c - o) * inv, (hi_c - o) * inv
        lesser, greater = np.where(a_ < b_, a_, b_), np.where(a_ > b_, a_, b_)
        t_in = np.where(lesser[..., 0] > lesser[..., 1], lesser[..., 0], lesser[..., 1])
        t_in = np.where(t_in > lesser[..., 2], t_in, lesser[..., 2])
        t_out = np.where(greater[..., 0] < greater[..., 1], greater[..., 0], greater[..., 1])
        t_out = np.where(t_out < greater[..., 2], t_out, greater[..., 2])
        hit = (t_in <= t_out) & (t_out >= 0) & (t_in <= best)
        want[:, c] = np.where(hit, t_in, np.float32(3.0e38)).min(axis=1)
    assert (want < 3.0e38).mean() > 0.3 and (want == np.float32(3.0e38)).any()

    lane_by_lane = wp.func_native(accel._PACKET_NODE.replace(
        "#if defined(__clang__) && !defined(__CUDA_ARCH__)", "#if 0"))(accel.packet_node.func)
    table = np.zeros(n_nodes, dtype=accel.BvhNode.numpy_dtype())
    for k, f in enumerate(("lo0", "hi0", "lo1", "hi1")):
        table[f] = rec[:, 3 * k:3 * k + 3]
    nodes = wp.array(table, dtype=accel.BvhNode, device="cpu")
    out = {}
    for name, fn in (("vectors", accel.packet_node), ("lanes", lane_by_lane)):
        @wp.kernel(enable_backward=False, module="unique")
        def k(nodes: wp.array(dtype=accel.BvhNode), refs: wp.array(dtype=int), o: wp.array(dtype=wp.vec3, ndim=2),
              inv: wp.array(dtype=wp.vec3, ndim=2), best: wp.array(dtype=float, ndim=2), out: wp.array(dtype=wp.vec2)):
            i = wp.tid()
            ox = accel.PacketF()
            oy = accel.PacketF()
            oz = accel.PacketF()
            ix = accel.PacketF()
            iy = accel.PacketF()
            iz = accel.PacketF()
            bb = accel.PacketF()
            for l in range(accel.PACKET):
                ox[l] = o[i, l][0]
                oy[l] = o[i, l][1]
                oz[l] = o[i, l][2]
                ix[l] = inv[i, l][0]
                iy[l] = inv[i, l][1]
                iz[l] = inv[i, l][2]
                bb[l] = best[i, l]
            out[i] = fn(nodes, refs[i], ox, oy, oz, ix, iy, iz, bb)

        res = wp.zeros(n, dtype=wp.vec2, device="cpu")
        wp.launch(k, dim=n, device="cpu", inputs=[
            nodes,
            wp.array(ref, dtype=int, device="cpu"), wp.array(o, dtype=wp.vec3, device="cpu"),
            wp.array(inv, dtype=wp.vec3, device="cpu"), wp.array(best, dtype=float, device="cpu"), res])
        out[name] = res.numpy()
    np.testing.assert_array_equal(out["vectors"], want)
    np.testing.assert_array_equal(out["lanes"], want)
