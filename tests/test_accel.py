"""warprt's own BVH (``warprt.accel``): the tree the host builds, and rays through it.

The renders through it are checked against the loops over each table in test_features.py
(spheres, rectangles, disks, pieces of long bars) and test_worlds.py (one tree per world,
refitted as the worlds move); here: the tree's structure, its depth bound, and closest hits and
shadows through a tree of many shapes against an independent float64 brute force."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import warp as wp

import warprt
from warprt import accel
from warprt._warp import MODULE_OPTIONS
from warprt.build import DeviceScene
from warprt.records import InstRec, SceneData
from warprt.trace import mesh_first_hit


@wp.func
def _lanes(v: wp.array(dtype=wp.vec3, ndim=2), i: int, c: int) -> accel.PacketF:
    """Coordinate c of row i's 8 vectors, as a packet's lanes."""
    p = accel.PacketF()
    for l in range(accel.PACKET):
        p[l] = v[i, l][c]
    return p


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


def test_the_packet_node_test_lane_by_lane_equals_its_vector_form(device):
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
    nodes = wp.array(table, dtype=accel.BvhNode, device=device)
    out = {}
    for name, fn in (("vectors", accel.packet_node), ("lanes", lane_by_lane)):
        @wp.kernel(enable_backward=False, module="unique", module_options=MODULE_OPTIONS)
        def k(nodes: wp.array(dtype=accel.BvhNode), refs: wp.array(dtype=int), o: wp.array(dtype=wp.vec3, ndim=2),
              inv: wp.array(dtype=wp.vec3, ndim=2), best: wp.array(dtype=float, ndim=2), out: wp.array(dtype=wp.vec2)):
            i = wp.tid()
            bb = accel.PacketF()
            for l in range(accel.PACKET):
                bb[l] = best[i, l]
            out[i] = fn(nodes, refs[i], _lanes(o, i, 0), _lanes(o, i, 1), _lanes(o, i, 2), _lanes(inv, i, 0),
                        _lanes(inv, i, 1), _lanes(inv, i, 2), bb)

        res = wp.zeros(n, dtype=wp.vec2, device=device)
        wp.launch(k, dim=n, device=device, inputs=[
            nodes,
            wp.array(ref, dtype=int, device=device), wp.array(o, dtype=wp.vec3, device=device),
            wp.array(inv, dtype=wp.vec3, device=device), wp.array(best, dtype=float, device=device), res])
        out[name] = res.numpy()
    np.testing.assert_array_equal(out["vectors"], want)
    np.testing.assert_array_equal(out["lanes"], want)


def _bumpy_sphere():
    """A closed, non-convex mesh (an icosphere with bumps, 1280 faces) in float32: faces see and
    shadow each other."""
    import trimesh

    ico = trimesh.creation.icosphere(subdivisions=3)
    v = np.asarray(ico.vertices, np.float64)
    lat, lon = np.arcsin(np.clip(v[:, 1], -1, 1)), np.arctan2(v[:, 2], v[:, 0])
    v = v * (1.0 + 0.15 * np.sin(5 * lon) * np.cos(4 * lat))[:, None]
    return v.astype(np.float32), np.asarray(ico.faces, np.int32)


def _any_hit_f64(tri, o, d, t_max, margin, skip):
    """Whether a triangle other than the ray's ``skip`` (its starting face, or -1) blocks each
    segment (o, o + t_max d) in float64 (Möller-Trumbore), and whether the answer is sure: no
    triangle met within ``margin`` of an edge, of t = 0 or of t_max."""
    e1, e2 = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    blocked = np.zeros(len(o), bool)
    unsure = np.zeros(len(o), bool)
    for lo in range(0, len(o), 256):
        oo, dd, tm = o[lo:lo + 256, None], d[lo:lo + 256, None], t_max[lo:lo + 256, None]
        p = np.cross(dd, e2)
        det = np.einsum("rtk,tk->rt", p, e1)
        with np.errstate(divide="ignore", invalid="ignore"):
            inv = 1.0 / det
            s = oo - tri[:, 0]
            u = np.einsum("rtk,rtk->rt", s, p) * inv
            q = np.cross(s, e1)
            v = np.einsum("rtk,rtk->rt", np.broadcast_to(dd, q.shape), q) * inv
            t = np.einsum("rtk,tk->rt", q, e2) * inv
        own = np.arange(len(tri))[None, :] == skip[lo:lo + 256, None]
        inside = (u >= 0) & (v >= 0) & (u + v <= 1) & (np.abs(det) > 1e-12) & ~own
        near_edge = (np.minimum(np.minimum(np.abs(u), np.abs(v)), np.abs(1 - u - v)) < margin) | (np.abs(det) <= 1e-12)
        near_t = (np.abs(t) < margin) | (np.abs(t - tm) < margin)
        blocked[lo:lo + 256] = (inside & (t > 0) & (t < tm)).any(axis=1)
        unsure[lo:lo + 256] = ((near_edge | near_t) & (t > -margin) & (t < tm + margin) & ~own).any(axis=1)
    return blocked, ~unsure


def test_mesh_shadow_rays_stop_at_the_first_occluder_with_the_nearest_hit_loops_answer():
    """``accel.mesh_tree_occluded`` (the CPU's any-hit traversal for shadow rays through opaque
    meshes) answers every segment as ``trace.mesh_first_hit`` does (the nearest hit in
    (0, t_max) on a face the ray does not leave), bit for bit, and as a float64 brute force does
    where that is sure: segments from points exactly on the faces of a bumpy closed mesh (rays
    leaving a face, rays entering the mesh), the same points moved off by the renderer's spawn
    offset, segments between random points, and rays aimed at vertices, stopping just before or
    just past them."""
    import warp as wp

    v, f = _bumpy_sphere()
    tri = v[f].astype(np.float64)
    rng = np.random.default_rng(5)
    n = 3000
    face = rng.integers(0, len(f), n)
    bary = rng.dirichlet([2, 2, 2], n)
    on = np.einsum("nk,nkj->nj", bary, tri[face]).astype(np.float32)
    fn = np.cross(tri[face, 1] - tri[face, 0], tri[face, 2] - tri[face, 0])
    fn /= np.linalg.norm(fn, axis=1, keepdims=True)
    d_rand = rng.normal(size=(n, 3))
    d_rand /= np.linalg.norm(d_rand, axis=1, keepdims=True)
    d_out = np.where((np.sum(d_rand * fn, 1) > 0)[:, None], d_rand, -d_rand)  # leaving the face's front
    mag = np.maximum(np.abs(tri[face]).max(axis=1), np.abs(on)) + np.abs(on)
    off = (np.sum(np.abs(fn) * mag, 1) * 2.0 ** -17)[:, None] * fn
    pts = rng.uniform(-1.4, 1.4, (2 * n, 3))
    aim = v[rng.integers(0, len(v), n)].astype(np.float64)
    o_aim = rng.uniform(-3, 3, (n, 3))
    d_aim = aim - o_aim
    dist = np.linalg.norm(d_aim, axis=1)
    # origins, directions, t_max, and the face the ray starts on where the float64 brute force can
    # judge it (None: from exactly on a face, whose own plane the ray meets at t ~ 0 on either side
    # by rounding, or through a vertex, where every ray is on edges: only the nearest-hit loop's
    # answer is the reference)
    cases = {
        "from on the face, leaving it": (on, d_out, rng.uniform(0.01, 3, n), None),
        "from on the face, entering": (on, -d_out, rng.uniform(0.01, 3, n), None),
        "spawned off the face": ((on + off).astype(np.float32), d_out, rng.uniform(0.01, 3, n), face),
        "random segments": (pts[:n], pts[n:] - pts[:n], np.ones(n), np.full(n, -1)),
        "aimed at vertices": (o_aim, d_aim / dist[:, None], dist * np.where(rng.random(n) < 0.5, 1 - 1e-4, 1 + 1e-4),
                              None),
    }
    mesh = wp.Mesh(points=wp.array(v, dtype=wp.vec3, device="cpu"),
                   indices=wp.array(f.reshape(-1), dtype=wp.int32, device="cpu"), bvh_leaf_size=1)
    tree = accel.MeshTree(mesh, len(f))
    assert tree.usable
    inst = InstRec()
    inst.mesh = mesh.id
    for k, val in tree.record().items():
        setattr(inst, k, val)

    @wp.kernel(enable_backward=False, module="unique", module_options=MODULE_OPTIONS)
    def k(inst: InstRec, o: wp.array(dtype=wp.vec3), d: wp.array(dtype=wp.vec3), t_max: wp.array(dtype=float),
          out: wp.array(dtype=wp.vec2i)):
        i = wp.tid()
        occ = accel.mesh_tree_occluded(inst.tree_nodes, inst.tree_kids, inst.tree_tris, inst.tree_root, inst.cones,
                                       o[i], d[i], t_max[i])
        out[i] = wp.vec2i(occ, wp.where(mesh_first_hit(inst, o[i], d[i], t_max[i]).index >= 0, 1, 0))

    blocked_somewhere = 0
    for name, (o, d, t_max, skip) in cases.items():
        o, d, t_max = (np.asarray(x, np.float32) for x in (o, d, t_max))
        res = wp.zeros(len(o), dtype=wp.vec2i, device="cpu")
        wp.launch(k, dim=len(o), device="cpu", inputs=[
            inst, wp.array(o, dtype=wp.vec3, device="cpu"), wp.array(d, dtype=wp.vec3, device="cpu"),
            wp.array(t_max, dtype=float, device="cpu"), res])
        got, loop = res.numpy().T
        assert (got >= 0).all(), f"{name}: the traversal gave up on {int((got < 0).sum())} rays"
        np.testing.assert_array_equal(got, loop, err_msg=name)
        if skip is not None:
            want, sure = _any_hit_f64(tri, o.astype(np.float64), d.astype(np.float64), t_max.astype(np.float64),
                                      1e-5, skip)
            assert sure.mean() > 0.9, name
            np.testing.assert_array_equal(got[sure], want[sure], err_msg=name)
        blocked_somewhere += int(got.sum())
        assert 0 < got.mean() < 1, f"{name}: every answer the same ({got.mean():.2f})"
    assert blocked_somewhere > 1000


def _lane_by_lane(native, src):
    """A packet function's CUDA branch (its lanes one by one), compiled for the CPU."""
    import warp as wp

    return wp.func_native(src.replace("#if defined(__clang__) && !defined(__CUDA_ARCH__)", "#if 0"))(native.func)


def test_a_packets_shadow_tests_equal_the_scalar_tests_lane_by_lane(device):
    """The shadow tests and set-ups a packet runs for its 8 lanes at once (``geometry``:
    ``sphere_hits_packet``, ``plane_hits_packet``, ``rect_hits_packet``, ``box_hits_packet``,
    ``shadow_rays_packet``; ``lights.point_light_packet``, ``lobe_packet``), as clang vectors and lane by lane (their
    CUDA branch, compiled here on the CPU), answer each lane exactly as the scalar functions do
    (``sphere_roots``, ``intersect_plane``, ``intersect_rect``, ``ray_box``, ``shadow``,
    ``point_lights_direct``'s and ``blinn_phong``'s arithmetic): random rays aimed at the shapes, lengths ending near
    the hits, axis-aligned directions, origins on the surfaces, moving spheres, points behind
    their normals and lights on the surface."""
    import warp as wp

    from warprt import geometry as g
    from warprt import lights as lt
    from warprt.shading import FLT_MAX  # noqa: F401  (the module the kernels' functions live in)

    rng = np.random.default_rng(9)
    n = 4096
    c0 = rng.uniform(-1, 1, (n, 3)).astype(np.float32)
    dc = np.where(rng.random((n, 1)) < 0.5, rng.normal(0, 0.3, (n, 3)), 0.0).astype(np.float32)
    r = rng.uniform(0.05, 0.8, n).astype(np.float32)
    o = rng.uniform(-3, 3, (n, 8, 3)).astype(np.float32)
    aim = c0[:, None] + rng.normal(0, 0.6, (n, 8, 3))
    d = np.where(rng.random((n, 8, 1)) < 0.8, aim - o, rng.normal(size=(n, 8, 3)))
    axis = rng.random((n, 8)) < 0.08
    d[axis] = np.eye(3)[rng.integers(0, 3, axis.sum())] * rng.choice([-1, 1], (axis.sum(), 1))
    d = (d / np.linalg.norm(d, axis=-1, keepdims=True)).astype(np.float32)
    dist = np.linalg.norm(c0[:, None] - o, axis=-1)
    t_max = (dist * rng.uniform(0.3, 1.7, (n, 8))).astype(np.float32)
    time = rng.random((n, 8)).astype(np.float32)
    e1 = rng.normal(0, 0.7, (n, 3)).astype(np.float32)
    e2 = rng.normal(0, 0.7, (n, 3)).astype(np.float32)
    lo = (c0 - rng.uniform(0.05, 1, (n, 3))).astype(np.float32)
    hi = (c0 + rng.uniform(0.05, 1, (n, 3))).astype(np.float32)
    nrm = rng.normal(size=(n, 3))
    nrm = (nrm / np.linalg.norm(nrm, axis=1, keepdims=True)).astype(np.float32)
    on = rng.random((n, 8)) < 0.1  # origins on the plane through c0
    o[on] = (o[on] - np.einsum("ij,ij->i", o[on] - np.repeat(c0[:, None], 8, 1)[on],
                               np.repeat(nrm[:, None], 8, 1)[on])[:, None] * np.repeat(nrm[:, None], 8, 1)[on])
    # shading points with normals (g, n), viewer directions and lights (some on the point)
    gn = rng.normal(size=(n, 8, 3))
    gn = (gn / np.linalg.norm(gn, axis=-1, keepdims=True)).astype(np.float32)
    sn = gn + rng.normal(0, 0.2, (n, 8, 3))
    sn = (sn / np.linalg.norm(sn, axis=-1, keepdims=True)).astype(np.float32)
    vv = rng.normal(size=(n, 8, 3))
    vv = (vv / np.linalg.norm(vv, axis=-1, keepdims=True)).astype(np.float32)
    pos = np.where(rng.random((n, 1)) < 0.05, o[:, 0], rng.uniform(-3, 3, (n, 3))).astype(np.float32)
    stop = rng.uniform(0, 0.3, n).astype(np.float32)
    directional = (rng.random(n) < 0.2).astype(np.int32)
    lanes = rng.integers(1, 256, n).astype(np.int32)

    P = accel.PacketF

    def kernel_for(sph, pln, rct, box, shd, pl, lob):
        @wp.func
        def pkf(a: wp.array(dtype=float, ndim=2), i: int) -> accel.PacketF:
            v = accel.PacketF()
            for k in range(accel.PACKET):
                v[k] = a[i, k]
            return v

        @wp.kernel(enable_backward=False, module="unique", module_options=MODULE_OPTIONS)
        def k(o: wp.array(dtype=wp.vec3, ndim=2), d: wp.array(dtype=wp.vec3, ndim=2),
              tm: wp.array(dtype=float, ndim=2), tt: wp.array(dtype=float, ndim=2), c0: wp.array(dtype=wp.vec3),
              dc: wp.array(dtype=wp.vec3), r: wp.array(dtype=float), e1: wp.array(dtype=wp.vec3),
              e2: wp.array(dtype=wp.vec3), nrm: wp.array(dtype=wp.vec3), lo: wp.array(dtype=wp.vec3),
              hi: wp.array(dtype=wp.vec3), gn: wp.array(dtype=wp.vec3, ndim=2), sn: wp.array(dtype=wp.vec3, ndim=2),
              vv: wp.array(dtype=wp.vec3, ndim=2), pos: wp.array(dtype=wp.vec3), stop: wp.array(dtype=float),
              directional: wp.array(dtype=int), lanes: wp.array(dtype=int), out: wp.array(dtype=int, ndim=2)):
            i = wp.tid()
            ox, oy, oz = _lanes(o, i, 0), _lanes(o, i, 1), _lanes(o, i, 2)
            dx, dy, dz = _lanes(d, i, 0), _lanes(d, i, 1), _lanes(d, i, 2)
            t_max = pkf(tm, i)
            time = pkf(tt, i)
            m = lanes[i]
            out[i, 0] = sph(c0[i], dc[i], 1, r[i], m, ox, oy, oz, dx, dy, dz, t_max, time)
            out[i, 1] = pln(c0[i], nrm[i], m, ox, oy, oz, dx, dy, dz, t_max)
            out[i, 2] = rct(c0[i], e1[i], e2[i], m, ox, oy, oz, dx, dy, dz, t_max)
            out[i, 3] = box(lo[i], hi[i], m, ox, oy, oz, dx, dy, dz, 0.05, t_max)
            sx, sy, sz, st = accel.PacketF(), accel.PacketF(), accel.PacketF(), accel.PacketF()
            # shadow rays from o to the sphere's centre
            yx = accel.PacketF(c0[i][0], c0[i][0], c0[i][0], c0[i][0], c0[i][0], c0[i][0], c0[i][0], c0[i][0])
            yy = accel.PacketF(c0[i][1], c0[i][1], c0[i][1], c0[i][1], c0[i][1], c0[i][1], c0[i][1], c0[i][1])
            yz = accel.PacketF(c0[i][2], c0[i][2], c0[i][2], c0[i][2], c0[i][2], c0[i][2], c0[i][2], c0[i][2])
            out[i, 4] = shd(m, ox, oy, oz, yx, yy, yz, stop[i], sx, sy, sz, st)
            # the point light at pos seen from p = o (its shadow rays from o + 0.01 g)
            gx, gy, gz = _lanes(gn, i, 0), _lanes(gn, i, 1), _lanes(gn, i, 2)
            nx, ny, nz = _lanes(sn, i, 0), _lanes(sn, i, 1), _lanes(sn, i, 2)
            vx, vy, vz = _lanes(vv, i, 0), _lanes(vv, i, 1), _lanes(vv, i, 2)
            qx, qy, qz = ox + gx * 0.01, oy + gy * 0.01, oz + gz * 0.01
            ld, lnl, lhl, lnh, lx, ly, lz, lt_ = (accel.PacketF(), accel.PacketF(), accel.PacketF(), accel.PacketF(),
                                                 accel.PacketF(), accel.PacketF(), accel.PacketF(), accel.PacketF())
            out[i, 5] = pl(pos[i], directional[i], stop[i], m, ox, oy, oz, qx, qy, qz, gx, gy, gz, nx, ny, nz, vx, vy,
                           vz, ld, lnl, lhl, lnh, lx, ly, lz, lt_)
            # an area light's samples in the directions d (lights.lobe_packet)
            bn, bh, bnh = accel.PacketF(), accel.PacketF(), accel.PacketF()
            out[i, 13] = lob(m, dx, dy, dz, gx, gy, gz, nx, ny, nz, vx, vy, vz, bn, bh, bnh)
            # the scalar answers, lane by lane; bit 8 + k of out[i, 6..]: a value that differs
            want = wp.vec4i(0, 0, 0, 0)
            want2 = int(0)
            want3 = int(0)
            bad = int(0)
            want4 = int(0)
            for k in range(accel.PACKET):
                if (m >> k) & 1 == 0:
                    continue
                ok = wp.vec3(ox[k], oy[k], oz[k])
                dk = wp.vec3(dx[k], dy[k], dz[k])
                c = c0[i] + dc[i] * time[k]
                roots = g.sphere_roots(ok, dk, c, r[i])
                if (roots[0] > 0.0 and roots[0] < t_max[k]) or (roots[1] > 0.0 and roots[1] < t_max[k]):
                    want[0] = want[0] | (1 << k)
                if g.intersect_plane(ok, dk, c0[i], nrm[i], 0.0, t_max[k]) >= 0.0:
                    want[1] = want[1] | (1 << k)
                if g.intersect_rect(ok, dk, c0[i], e1[i], e2[i], 0.0, t_max[k]) >= 0.0:
                    want[2] = want[2] | (1 << k)
                if g.ray_box(ok, wp.cw_div(wp.vec3(1.0, 1.0, 1.0), dk), lo[i], hi[i], 0.05, t_max[k]):
                    want[3] = want[3] | (1 << k)
                to_t = c0[i] - ok
                dist = wp.length(to_t)
                if not (dist <= stop[i]):
                    want2 = want2 | (1 << k)
                    s = to_t / dist
                    if s[0] != sx[k] or s[1] != sy[k] or s[2] != sz[k] or dist - stop[i] != st[k]:
                        bad = bad | (1 << k)
                # blinn_phong's tests and values towards d (as area_lights_packet takes them)
                g_d = wp.vec3(gx[k], gy[k], gz[k])
                n_d = wp.vec3(nx[k], ny[k], nz[k])
                if wp.dot(g_d, dk) > 0.0 and wp.dot(n_d, dk) > 0.0:
                    want4 = want4 | (1 << k)
                    h_d = dk + wp.vec3(vx[k], vy[k], vz[k])
                    hl_d = wp.length(h_d)
                    if wp.dot(n_d, dk) != bn[k] or hl_d != bh[k] or wp.dot(n_d, h_d / hl_d) != bnh[k]:
                        bad = bad | (1 << (24 + k))
                # point_lights_direct's tests and values
                l = pos[i]
                dl = float(0.0)
                if directional[i] == 0:
                    to_light = pos[i] - ok
                    dl = wp.length(to_light)
                    if dl <= 0.0:
                        continue
                    l = to_light / dl
                g_k = wp.vec3(gx[k], gy[k], gz[k])
                n_k = wp.vec3(nx[k], ny[k], nz[k])
                if wp.dot(g_k, l) <= 0.0 or wp.dot(n_k, l) <= 0.0:
                    continue
                want3 = want3 | (1 << k)
                h = l + wp.vec3(vx[k], vy[k], vz[k])
                hl = wp.length(h)
                if dl != ld[k] or wp.dot(n_k, l) != lnl[k] or hl != lhl[k] or wp.dot(n_k, h / hl) != lnh[k]:
                    bad = bad | (1 << (8 + k))
                q = wp.vec3(qx[k], qy[k], qz[k])
                if directional[i] == 0:
                    to_t2 = pos[i] - q
                    dq = wp.length(to_t2)
                    if not (dq <= stop[i]):
                        want3 = want3 | (1 << (16 + k))
                        s2 = to_t2 / dq
                        if s2[0] != lx[k] or s2[1] != ly[k] or s2[2] != lz[k] or dq - stop[i] != lt_[k]:
                            bad = bad | (1 << (16 + k))
                else:
                    want3 = want3 | (1 << (16 + k))
                    if l[0] != lx[k] or l[1] != ly[k] or l[2] != lz[k] or lt_[k] != 3.0e38:
                        bad = bad | (1 << (16 + k))
            for j in range(4):
                out[i, 6 + j] = want[j]
            out[i, 10] = want2
            out[i, 11] = want3
            out[i, 12] = bad
            out[i, 14] = want4
        return k

    natives = [(g.sphere_hits_packet, g._SPHERE_HITS_PACKET), (g.plane_hits_packet, g._PLANE_HITS_PACKET),
               (g.rect_hits_packet, g._RECT_HITS_PACKET), (g.box_hits_packet, g._BOX_HITS_PACKET),
               (g.shadow_rays_packet, g._SHADOW_RAYS_PACKET), (lt.point_light_packet, lt._POINT_LIGHT_PACKET),
               (lt.lobe_packet, lt._LOBE_PACKET)]
    arrays = dict(o=(o, wp.vec3), d=(d, wp.vec3), tm=(t_max, float), tt=(time, float), c0=(c0, wp.vec3),
                  dc=(dc, wp.vec3), r=(r, float), e1=(e1, wp.vec3), e2=(e2, wp.vec3), nrm=(nrm, wp.vec3),
                  lo=(lo, wp.vec3), hi=(hi, wp.vec3), gn=(gn, wp.vec3), sn=(sn, wp.vec3), vv=(vv, wp.vec3),
                  pos=(pos, wp.vec3), stop=(stop, float), directional=(directional, int), lanes=(lanes, int))
    inputs = [wp.array(a, dtype=t, device=device) for a, t in arrays.values()]
    for variant in ("vectors", "lanes"):
        fns = [f if variant == "vectors" else _lane_by_lane(f, src) for f, src in natives]
        out = wp.zeros((n, 15), dtype=int, device=device)
        wp.launch(kernel_for(*fns), dim=n, device=device, inputs=inputs + [out])
        res = out.numpy()
        for j, name in enumerate(("sphere", "plane", "rectangle", "box", "shadow rays", "point light")):
            np.testing.assert_array_equal(res[:, j], res[:, 6 + j], err_msg=f"{variant}: {name}")
        np.testing.assert_array_equal(res[:, 13], res[:, 14], err_msg=f"{variant}: lobe")
        assert (res[:, 12] == 0).all(), variant
        # the cases are there: hits and misses of every test, lanes cut by the stop, no light
        hits = [np.unpackbits(res[:, 6 + j].astype(np.uint8)[:, None], axis=1).sum() for j in range(4)]
        asked = np.unpackbits(lanes.astype(np.uint8)[:, None], axis=1).sum()
        assert all(0.02 * asked < h < 0.9 * asked for h in hits), (hits, asked)
        lit = np.unpackbits(res[:, 11].astype(np.uint8)[:, None], axis=1).sum()
        assert 0.05 * asked < lit < 0.5 * asked


def test_a_packets_samples_equal_the_film_functions_lane_by_lane(device):
    """``film.packet_samples`` (a shaded packet's 8 samples as the film adds them: the lit lanes'
    mul_sat(1, local + area), every lane sanitised, its luminance squared), as clang vectors and
    lane by lane (its CUDA branch, compiled here on the CPU), gives each lane exactly what
    ``shading.mul_sat``, ``film.sanitize`` and ``film.luminance`` give it: ordinary colours,
    zeros of both signs, negatives, NaN and Inf in any channel, sums past FLT_MAX, clamps of
    1, 100 and Inf, every lit mask."""
    import warp as wp

    from warprt import film as fm
    from warprt.accel import PacketF
    from warprt.shading import mul_sat

    rng = np.random.default_rng(17)
    n = 4096
    special = np.array([0.0, -0.0, -1.0, np.nan, np.inf, -np.inf, 3.0e38, 1.0e-45, 2.5], np.float32)

    def colours():
        c = (rng.random((n, 3, 8)) * 10.0 ** rng.uniform(-3, 3, (n, 3, 8))).astype(np.float32)
        pick = rng.random((n, 3, 8)) < 0.25
        c[pick] = rng.choice(special, int(pick.sum()))
        return c

    local, area = colours(), colours()
    lit = rng.integers(0, 256, n).astype(np.int32)
    clamp = rng.choice(np.array([1.0, 100.0, np.inf], np.float32), n)

    def kernel_for(fn):
        @wp.kernel(module="unique", enable_backward=False, module_options=MODULE_OPTIONS)
        def k(local: wp.array3d(dtype=float), area: wp.array3d(dtype=float), lit: wp.array(dtype=int),
              clamp: wp.array(dtype=float), out: wp.array3d(dtype=float), want: wp.array3d(dtype=float)):
            i = wp.tid()
            r = PacketF()
            g = PacketF()
            b = PacketF()
            ar = PacketF()
            ag = PacketF()
            ab = PacketF()
            for j in range(8):
                r[j] = local[i, 0, j]
                g[j] = local[i, 1, j]
                b[j] = local[i, 2, j]
                ar[j] = area[i, 0, j]
                ag[j] = area[i, 1, j]
                ab[j] = area[i, 2, j]
            fr = PacketF()
            fg = PacketF()
            fb = PacketF()
            fy = PacketF()
            fn(r, g, b, ar, ag, ab, lit[i], clamp[i], fr, fg, fb, fy)
            for j in range(8):
                out[i, 0, j] = fr[j]
                out[i, 1, j] = fg[j]
                out[i, 2, j] = fb[j]
                out[i, 3, j] = fy[j]
                L = wp.vec3(r[j], g[j], b[j])
                if (lit[i] >> j) & 1 != 0:
                    L = wp.vec3(0.0, 0.0, 0.0) + mul_sat(wp.vec3(1.0, 1.0, 1.0), L + wp.vec3(ar[j], ag[j], ab[j]))
                L = fm.sanitize(L, clamp[i])
                y = fm.luminance(L)
                want[i, 0, j] = L[0]
                want[i, 1, j] = L[1]
                want[i, 2, j] = L[2]
                want[i, 3, j] = y * y
        return k

    for variant, fn in (("vectors", fm.packet_samples), ("lanes", _lane_by_lane(fm.packet_samples, fm._PACKET_SAMPLES))):
        out = wp.zeros((n, 4, 8), dtype=float, device=device)
        want = wp.zeros((n, 4, 8), dtype=float, device=device)
        wp.launch(kernel_for(fn), dim=n, device=device,
                  inputs=[wp.array(local, dtype=float, device=device), wp.array(area, dtype=float, device=device),
                          wp.array(lit, dtype=int, device=device), wp.array(clamp, dtype=float, device=device), out,
                          want])
        got, ref = out.numpy(), want.numpy()
        np.testing.assert_array_equal(got.view(np.uint32), ref.view(np.uint32), err_msg=variant)
        # the cases are there: clamped, zeroed NaNs, saturated sums and plain values
        assert (ref[:, :3] == 1.0).sum() > 100 and (ref[:, :3] == 0.0).sum() > 1000
        assert ((ref[:, :3] > 0) & (ref[:, :3] < 1)).sum() > 1000 and (ref[:, :3] == 3.4028235e38).sum() > 10


def test_a_packets_point_light_sums_equal_the_lane_loop(device):
    """``lights.point_sums`` (a point light's mul_sat(1, mul_sat(I, f)) added to a packet's lit
    lanes, I over dist² for an inverse-square light), as clang vectors and lane by lane (its CUDA
    branch, compiled here on the CPU), gives each lane exactly what ``point_lights_packet``'s loop
    over the lanes gave: colours and intensities of every size, zeros, Inf, products past
    FLT_MAX, tiny and huge distances, both falloffs, every lit mask; unlit lanes untouched."""
    import warp as wp

    from warprt import lights as lt
    from warprt.accel import PacketF
    from warprt.shading import mul_sat

    rng = np.random.default_rng(23)
    n = 4096
    f = (rng.random((n, 3, 8)) * 10.0 ** rng.uniform(-3, 3, (n, 3, 8))).astype(np.float32)
    f[rng.random((n, 3, 8)) < 0.1] = 0.0
    f[rng.random((n, 3, 8)) < 0.03] = 3.0e38
    inten = (rng.random((n, 3)) * 10.0 ** rng.uniform(-2, 6, (n, 3))).astype(np.float32)
    inten[rng.random((n, 3)) < 0.1] = 0.0
    inten[rng.random((n, 3)) < 0.02] = np.inf
    dist = (10.0 ** rng.uniform(-20, 20, (n, 8))).astype(np.float32)
    acc = (rng.random((n, 3, 8)) * 4).astype(np.float32)
    lit = rng.integers(0, 256, n).astype(np.int32)
    inv_sq = rng.integers(0, 2, n).astype(np.int32)

    def kernel_for(fn):
        @wp.kernel(module="unique", enable_backward=False, module_options=MODULE_OPTIONS)
        def k(f: wp.array3d(dtype=float), inten: wp.array(dtype=wp.vec3), dist: wp.array2d(dtype=float),
              acc: wp.array3d(dtype=float), lit: wp.array(dtype=int), inv_sq: wp.array(dtype=int),
              out: wp.array3d(dtype=float), want: wp.array3d(dtype=float)):
            i = wp.tid()
            fr = PacketF()
            fg = PacketF()
            fb = PacketF()
            d = PacketF()
            r = PacketF()
            g = PacketF()
            b = PacketF()
            for j in range(8):
                fr[j] = f[i, 0, j]
                fg[j] = f[i, 1, j]
                fb[j] = f[i, 2, j]
                d[j] = dist[i, j]
                r[j] = acc[i, 0, j]
                g[j] = acc[i, 1, j]
                b[j] = acc[i, 2, j]
            fn(lit[i], inten[i], inv_sq[i], d, fr, fg, fb, r, g, b)
            for j in range(8):
                out[i, 0, j] = r[j]
                out[i, 1, j] = g[j]
                out[i, 2, j] = b[j]
                c = wp.vec3(acc[i, 0, j], acc[i, 1, j], acc[i, 2, j])
                if (lit[i] >> j) & 1 != 0:
                    I = inten[i]
                    if inv_sq[i] == 1:
                        I = I / (d[j] * d[j])
                    L = mul_sat(wp.vec3(1.0, 1.0, 1.0), mul_sat(I, wp.vec3(fr[j], fg[j], fb[j])))
                    c = wp.vec3(c[0] + L[0], c[1] + L[1], c[2] + L[2])
                want[i, 0, j] = c[0]
                want[i, 1, j] = c[1]
                want[i, 2, j] = c[2]
        return k

    for variant, fn in (("vectors", lt.point_sums), ("lanes", _lane_by_lane(lt.point_sums, lt._POINT_SUMS))):
        out = wp.zeros((n, 3, 8), dtype=float, device=device)
        want = wp.zeros((n, 3, 8), dtype=float, device=device)
        wp.launch(kernel_for(fn), dim=n, device=device,
                  inputs=[wp.array(f, dtype=float, device=device), wp.array(inten, dtype=wp.vec3, device=device),
                          wp.array(dist, dtype=float, device=device), wp.array(acc, dtype=float, device=device),
                          wp.array(lit, dtype=int, device=device), wp.array(inv_sq, dtype=int, device=device), out,
                          want])
        got, ref = out.numpy(), want.numpy()
        np.testing.assert_array_equal(got.view(np.uint32), ref.view(np.uint32), err_msg=variant)
        added = ref != acc
        assert added.mean() > 0.2 and (ref == 3.4028235e38).sum() > 10 and (ref == acc).mean() > 0.4


def test_a_packets_bvh_leaf_updates_equal_the_lane_loop(device):
    """A sphere, rectangle or plane against a camera packet's first n lanes (a leaf of the analytic
    BVH, or the loops' shapes: ``geometry.sphere_leaf_packet``, ``rect_leaf_packet``,
    ``plane_leaf_packet``), as clang vectors and lane by lane
    (the CUDA branch, compiled here on the CPU), updates each lane's nearest hit, kind and row
    and returns the farthest nearest hit exactly as ``trace_packet``'s loop over the lanes does
    with ``intersect_sphere`` / ``intersect_rect`` / ``intersect_plane``: hits nearer and farther than each lane's
    bound, exact ties that the tie rule gives to the lower kind or row (and not to a higher
    one), lanes without a hit yet (kind -1), moving spheres, unused lanes past n."""
    from warprt import geometry as g

    rng = np.random.default_rng(13)
    n = 4096
    c = rng.uniform(-1, 1, (n, 3)).astype(np.float32)
    dc = np.where(rng.random((n, 1)) < 0.5, rng.normal(0, 0.3, (n, 3)), 0.0).astype(np.float32)
    r = rng.uniform(0.05, 0.8, n).astype(np.float32)
    e1 = rng.normal(0, 0.8, (n, 3)).astype(np.float32)
    e2 = rng.normal(0, 0.8, (n, 3)).astype(np.float32)
    o = rng.uniform(-3, 3, (n, 8, 3)).astype(np.float32)
    d = c[:, None] + rng.normal(0, 0.6, (n, 8, 3)) - o
    d = (d / np.linalg.norm(d, axis=-1, keepdims=True)).astype(np.float32)
    time = rng.random((n, 8)).astype(np.float32)
    dist = np.linalg.norm(c[:, None] - o, axis=-1)
    best = np.repeat((dist * rng.uniform(0.5, 1.5, (n, 8))).astype(np.float32)[:, None], 3, 1)
    kind = rng.choice([-1, 0, 1, 2, 3], (n, 3, 8)).astype(np.int32)
    index = rng.integers(0, 6, (n, 3, 8)).astype(np.int32)
    ii = rng.integers(0, 6, n).astype(np.int32)
    nl = rng.integers(1, 9, n).astype(np.int32)
    t_min = np.float32(1e-4)

    def kernel_for(sph, rct, pln, exact):
        @wp.kernel(enable_backward=False, module="unique", module_options=MODULE_OPTIONS)
        def k(o: wp.array(dtype=wp.vec3, ndim=2), d: wp.array(dtype=wp.vec3, ndim=2),
              tt: wp.array(dtype=float, ndim=2), c: wp.array(dtype=wp.vec3), dc: wp.array(dtype=wp.vec3),
              r: wp.array(dtype=float), e1: wp.array(dtype=wp.vec3), e2: wp.array(dtype=wp.vec3),
              best: wp.array(dtype=float, ndim=3), kind: wp.array(dtype=int, ndim=3),
              index: wp.array(dtype=int, ndim=3), ii: wp.array(dtype=int), nl: wp.array(dtype=int), t_min: float,
              out_t: wp.array(dtype=float, ndim=3), out_k: wp.array(dtype=int, ndim=3),
              out_i: wp.array(dtype=int, ndim=3), far: wp.array(dtype=float, ndim=2)):
            i = wp.tid()
            ox, oy, oz = accel.PacketF(), accel.PacketF(), accel.PacketF()
            dx, dy, dz = accel.PacketF(), accel.PacketF(), accel.PacketF()
            tm = accel.PacketF()
            for l in range(accel.PACKET):
                ox[l] = o[i, l][0]
                oy[l] = o[i, l][1]
                oz[l] = o[i, l][2]
                dx[l] = d[i, l][0]
                dy[l] = d[i, l][1]
                dz[l] = d[i, l][2]
                tm[l] = tt[i, l]
            for shape in range(3):
                kk = 2 * shape - 3 * (shape // 2)  # KIND_SPHERE, KIND_RECT, KIND_PLANE
                b = accel.PacketF()
                kd = accel.PacketI()
                ix = accel.PacketI()
                for l in range(accel.PACKET):
                    b[l] = best[i, shape, l]
                    kd[l] = kind[i, shape, l]
                    ix[l] = index[i, shape, l]
                f = float(0.0)
                if exact == 0:
                    if shape == 0:
                        f = sph(c[i], dc[i], 1, r[i], kk, ii[i], nl[i], t_min, ox, oy, oz, dx, dy, dz, tm, b, kd, ix)
                    elif shape == 1:
                        f = rct(c[i], e1[i], e2[i], kk, ii[i], nl[i], t_min, ox, oy, oz, dx, dy, dz, b, kd, ix)
                    else:
                        f = pln(c[i], wp.normalize(e1[i]), kk, ii[i], nl[i], t_min, ox, oy, oz, dx, dy, dz, b, kd, ix)
                else:
                    # trace_packet's loop over the lanes
                    for l in range(nl[i]):
                        lane_best = b[l]
                        first = kd[l] != -1 and (kk < kd[l] or (kk == kd[l] and ii[i] < ix[l]))
                        t_hi = lane_best
                        if first:
                            t_hi = lane_best * 1.0000002 + 1.0e-38
                        ol = wp.vec3(ox[l], oy[l], oz[l])
                        dl = wp.vec3(dx[l], dy[l], dz[l])
                        t = float(-1.0)
                        if shape == 0:
                            t = g.intersect_sphere(ol, dl, c[i] + dc[i] * tm[l], r[i], t_min, t_hi)
                        elif shape == 1:
                            t = g.intersect_rect(ol, dl, c[i], e1[i], e2[i], t_min, t_hi)
                        else:
                            t = g.intersect_plane(ol, dl, c[i], wp.normalize(e1[i]), t_min, t_hi)
                        if t >= 0.0 and (t < lane_best or (first and t == lane_best)):
                            b[l] = t
                            kd[l] = kk
                            ix[l] = ii[i]
                        f = wp.max(f, b[l])
                for l in range(accel.PACKET):
                    out_t[i, shape, l] = b[l]
                    out_k[i, shape, l] = kd[l]
                    out_i[i, shape, l] = ix[l]
                far[i, shape] = f
        return k

    def run(best, kind, index):
        arrays = [(o, wp.vec3), (d, wp.vec3), (time, float), (c, wp.vec3), (dc, wp.vec3), (r, float), (e1, wp.vec3),
                  (e2, wp.vec3), (best, float), (kind, int), (index, int), (ii, int), (nl, int)]
        results = {}
        for name, (sph, rct, pln, exact) in {
                "loop": (g.sphere_leaf_packet, g.rect_leaf_packet, g.plane_leaf_packet, 1),
                "vectors": (g.sphere_leaf_packet, g.rect_leaf_packet, g.plane_leaf_packet, 0),
                "lanes": (_lane_by_lane(g.sphere_leaf_packet, g._SPHERE_LEAF_PACKET),
                          _lane_by_lane(g.rect_leaf_packet, g._RECT_LEAF_PACKET),
                          _lane_by_lane(g.plane_leaf_packet, g._PLANE_LEAF_PACKET), 0)}.items():
            outs = [wp.zeros((n, 3, 8), dtype=float, device=device), wp.zeros((n, 3, 8), dtype=int, device=device),
                    wp.zeros((n, 3, 8), dtype=int, device=device), wp.zeros((n, 3), dtype=float, device=device)]
            wp.launch(kernels[name] if name in kernels else kernels.setdefault(name, kernel_for(sph, rct, pln, exact)),
                      dim=n, device=device, inputs=[wp.array(a, dtype=t, device=device) for a, t in arrays] + [t_min] + outs)
            results[name] = [x.numpy() for x in outs]
        for name in ("vectors", "lanes"):
            for got, want in zip(results[name], results["loop"]):
                assert got.tobytes() == want.tobytes(), name
        return results["loop"]

    kernels = {}
    used = np.arange(8)[None, None, :] < nl[:, None, None]
    got = run(best, kind, index)
    took = (got[1] != kind) & used
    assert 0.1 < took.sum() / used.sum() < 0.6, took.sum() / used.sum()
    # exact ties: each lane's bound set to the shape's own hit, held by a shape of the same kind
    # whose row is one lower (the tie stays) or one higher (the tie rule hands it over)
    alone = run(np.full_like(best, 1e30), np.full_like(kind, -1), index)
    hit = (alone[1] >= 0) & used
    lower = rng.random((n, 3, 8)) < 0.5
    kind2 = np.where(hit, alone[1], kind)
    index2 = np.where(hit, ii[:, None, None] + np.where(lower, -1, 1), index).astype(np.int32)
    tied = run(np.where(hit, alone[0], best).astype(np.float32), kind2.astype(np.int32), index2)
    handed = hit & (tied[2] == ii[:, None, None])
    assert hit.sum() > 1000 and handed.sum() > 0.3 * hit.sum() and (hit & ~handed).sum() > 0.3 * hit.sum()
    np.testing.assert_array_equal(handed, hit & ~lower)


# --- interior balls (accel.interior_balls): shadow rays through a ball inside a closed mesh ----


def _winding_f64(tri, p):
    """The generalised winding number of points p (m, 3) with respect to triangles (F, 3, 3),
    float64 (van Oosterom and Strackee's solid angles): 1 inside a closed outward mesh, 0 outside."""
    a, b, c = (tri[None, :, k] - p[:, None] for k in range(3))
    la, lb, lc = (np.linalg.norm(x, axis=-1) for x in (a, b, c))
    det = np.einsum("mfi,mfi->mf", a, np.cross(b, c))
    den = (la * lb * lc + np.einsum("mfi,mfi->mf", a, b) * lc + np.einsum("mfi,mfi->mf", b, c) * la
           + np.einsum("mfi,mfi->mf", c, a) * lb)
    return 2.0 * np.arctan2(det, den).sum(axis=1) / (4.0 * np.pi)


def _surface_distance_f64(tri, p):
    """The distance from points p (m, 3) to the nearest of the triangles (F, 3, 3), float64."""
    a, b, c = (tri[None, :, k] for k in range(3))
    q = p[:, None]
    n = np.cross(b - a, c - a)
    n = n / np.linalg.norm(n, axis=-1, keepdims=True)
    h = np.einsum("mfi,mfi->mf", q - a, n)
    foot = q - h[..., None] * n
    inside = np.ones(h.shape, dtype=bool)
    for u, v in ((a, b), (b, c), (c, a)):
        inside &= np.einsum("mfi,mfi->mf", np.cross(v - u, foot - u), n) >= 0.0

    def to_edge(u, v):
        e = v - u
        t = np.clip(np.einsum("mfi,mfi->mf", q - u, e) / np.einsum("mfi,mfi->mf", e, e), 0.0, 1.0)
        return np.linalg.norm(q - (u + t[..., None] * e), axis=-1)

    edge = np.minimum(np.minimum(to_edge(a, b), to_edge(b, c)), to_edge(c, a))
    return np.where(inside, np.abs(h), edge).min(axis=1)


def _ball_meshes():
    from benchmarks.peers import bumpy_torus

    v, f = bumpy_torus(64, 24, major=0.9, minor=0.35, bumps=0.08)
    return {"bumpy sphere": _bumpy_sphere(), "bumpy torus": (v.astype(np.float32), f.astype(np.int32))}


@pytest.mark.parametrize("name", ["bumpy sphere", "bumpy torus"])
def test_interior_balls_lie_inside_the_mesh_and_block_only_what_the_traversal_blocks(name):
    """A closed mesh's interior balls (``accel.interior_balls``) lie wholly inside the solid (their
    centres' winding number 1 and their radii below the centres' distance to every triangle, both
    in float64), and a shadow segment from a point outside the solid that ``accel.mesh_balls_hit``
    calls blocked is one ``accel.mesh_tree_occluded`` blocks: segments between random points
    around the mesh, segments aimed at the balls' centres that stop short of the surface, reach
    into the solid or go past it, and segments pointing away from it. The balls answer most of
    the blocked segments (which is what they are for)."""
    v, f = _ball_meshes()[name]
    tri = v[f].astype(np.float64)
    mesh = wp.Mesh(points=wp.array(v, dtype=wp.vec3, device="cpu"),
                   indices=wp.array(f.reshape(-1), dtype=wp.int32, device="cpu"), bvh_leaf_size=1)
    tree = accel.MeshTree(mesh, len(f))
    tree.find_balls(v, f)
    assert tree.balls is not None
    blocks = tree.balls.numpy().reshape(-1, 4, 8)
    centres = blocks[:, :3].transpose(0, 2, 1).reshape(-1, 3).astype(np.float64)
    r2 = blocks[:, 3].reshape(-1).astype(np.float64)
    real = r2 > 0
    centres, radii = centres[real], np.sqrt(r2[real])
    assert 8 <= len(radii) <= accel.BALLS_MAX
    np.testing.assert_allclose(_winding_f64(tri, centres), 1.0, atol=1e-6)
    assert np.all(radii < _surface_distance_f64(tri, centres))

    rng = np.random.default_rng(11)
    lo, hi = v.min(axis=0) - 0.5, v.max(axis=0) + 0.5
    n = 6000
    o = rng.uniform(lo, hi, (n, 3))
    o = o[np.abs(_winding_f64(tri, o)) < 1e-6][:4000]  # outside the solid
    m = len(o)
    k = rng.integers(0, len(radii), m)
    to_c = centres[k] - o
    dist = np.linalg.norm(to_c, axis=1)
    away = rng.normal(size=(m, 3))
    away = np.where((np.sum(away * to_c, 1) < 0)[:, None], away, -away)
    segments = {
        "random segments": (o, rng.uniform(lo, hi, (m, 3)) - o, np.ones(m)),
        "aimed at a ball's centre": (o, to_c / dist[:, None], dist * rng.uniform(0.2, 1.5, m)),
        "pointing away from a ball": (o, away / np.linalg.norm(away, axis=1, keepdims=True), dist * 2.0),
    }
    inst = InstRec()
    inst.mesh = mesh.id
    for key, val in {**tree.record(), **tree.ball_fields()}.items():
        setattr(inst, key, val)

    @wp.kernel(enable_backward=False, module="unique", module_options=MODULE_OPTIONS)
    def k_balls(inst: InstRec, o: wp.array(dtype=wp.vec3), d: wp.array(dtype=wp.vec3), t_max: wp.array(dtype=float),
                out: wp.array(dtype=wp.vec2i)):
        i = wp.tid()
        out[i] = wp.vec2i(accel.mesh_balls_hit(inst.balls, inst.n_balls, o[i], d[i], t_max[i]),
                          accel.mesh_tree_occluded(inst.tree_nodes, inst.tree_kids, inst.tree_tris, inst.tree_root,
                                                   inst.cones, o[i], d[i], t_max[i]))

    caught, blocked = 0, 0
    for what, (oo, dd, tm) in segments.items():
        res = wp.zeros(m, dtype=wp.vec2i, device="cpu")
        wp.launch(k_balls, dim=m, device="cpu", inputs=[
            inst, wp.array(oo.astype(np.float32), dtype=wp.vec3, device="cpu"),
            wp.array(dd.astype(np.float32), dtype=wp.vec3, device="cpu"),
            wp.array(tm.astype(np.float32), dtype=float, device="cpu"), res])
        ball, occ = res.numpy().T
        assert (occ >= 0).all()
        assert np.all(occ[ball == 1] == 1), f"{what}: {int(((ball == 1) & (occ != 1)).sum())} segments a ball blocks"
        if what == "pointing away from a ball":
            assert 0 < occ.sum() and ball.sum() < occ.sum()
        else:
            assert 0 < ball.sum() < occ.sum() < m, what
        caught += int(ball.sum())
        blocked += int(occ.sum())
    assert caught > 0.7 * blocked  # (0.80 and 0.87 of them on these meshes)


def test_interior_balls_need_a_closed_mesh_of_enough_triangles():
    """An open mesh (one triangle taken out), one with an edge shared by three triangles and a
    closed mesh below ``BALLS_MIN_TRIANGLES`` get no balls."""
    v, f = _bumpy_sphere()
    assert accel.closed_surface(f)
    assert not accel.closed_surface(f[1:])
    third = np.array([[f[0, 0], f[0, 1], f[5, 2]]])  # a third triangle on face 0's first edge
    assert not accel.closed_surface(np.concatenate([f, third]))
    mesh = wp.Mesh(points=wp.array(v, dtype=wp.vec3, device="cpu"),
                   indices=wp.array(f[1:].reshape(-1), dtype=wp.int32, device="cpu"), bvh_leaf_size=1)
    assert accel.interior_balls(mesh, v, f[1:]) is None
    import trimesh

    small = trimesh.creation.icosphere(subdivisions=2)  # 320 triangles
    sv, sf = np.asarray(small.vertices, np.float32), np.asarray(small.faces, np.int32)
    assert accel.closed_surface(sf) and len(sf) < accel.BALLS_MIN_TRIANGLES
    mesh = wp.Mesh(points=wp.array(sv, dtype=wp.vec3, device="cpu"),
                   indices=wp.array(sf.reshape(-1), dtype=wp.int32, device="cpu"), bvh_leaf_size=1)
    assert accel.interior_balls(mesh, sv, sf) is None


def _balls_scene(camera_eye=(0.0, 1.6, 3.2), light=None):
    v, f = _bumpy_sphere()
    return warprt.Scene(
        camera=warprt.Camera(eye=camera_eye, look_at=(0.0, 0.4, 0.0), fov=50.0, width=48, height=36),
        shapes=(warprt.Plane(point=(0.0, -1.2, 0.0), normal=(0.0, 1.0, 0.0), material="ground"),
                warprt.Mesh(vertices=v, faces=f, material="ball")),
        materials={"ground": warprt.Material(kd=0.6, ka=0.0), "ball": warprt.Material(kd=0.7, ka=0.0)},
        lights=(light or warprt.RectLight(corner=(-1.0, 2.5, -1.0), edge1=(2.0, 0.0, 0.0), edge2=(0.0, 0.0, 2.0),
                                          radiance=3.0),))


def _n_balls(renderer):
    return int(renderer.built.data.insts.numpy()["n_balls"][0])


def _cones(renderer):
    return int(renderer.built.data.insts.numpy()["cones"][0])


def _with_and_without(renderer, field, spp):
    """The renderer's image, then the same with every instance record's ``field`` zeroed."""
    first = renderer.render(spp=spp, seed=3, progress=False).image
    rows = renderer.built.data.insts.numpy()
    rows[field] = 0
    renderer.built.data.insts.assign(rows)
    return first, renderer.render(spp=spp, seed=3, progress=False).image


def test_shadow_packets_render_what_each_lane_renders_alone(monkeypatch):
    """A mesh of ``accel.SHADOW_PACKET_TRIANGLES`` or more triangles has its record's
    ``shadow_packets`` set, and a camera packet's shadow rays then go through its tree together
    (``trace.mesh_lanes_occluded``); the images are the same bit for bit as with each lane alone:
    with the interior balls and normal cones, without either, with one and four light samples."""
    scene = _balls_scene()
    monkeypatch.setattr(accel, "SHADOW_PACKET_TRIANGLES", 4096)
    small = warprt.Renderer(scene, device="cpu")
    assert int(small.built.data.insts.numpy()["shadow_packets"][0]) == 0  # (1280 triangles: below that size)
    monkeypatch.setattr(accel, "SHADOW_PACKET_TRIANGLES", 1280)
    for samples in (1, 4):
        light = dataclasses.replace(scene.lights[0], samples=samples)
        r = warprt.Renderer(scene.replace(lights=(light,)), device="cpu")
        assert int(r.built.data.insts.numpy()["shadow_packets"][0]) == 1
        assert _n_balls(r) > 0 and _cones(r) != 0
        packets, alone = _with_and_without(r, "shadow_packets", 8)
        assert packets.tobytes() == alone.tobytes()
        assert float(alone[..., 0].std()) > 0.01  # (a lit, shadowed image)
        rows = r.built.data.insts.numpy()
        rows["shadow_packets"] = 1
        rows["n_balls"] = 0
        rows["cones"] = 0
        r.built.data.insts.assign(rows)
        packets_bare, alone_bare = _with_and_without(r, "shadow_packets", 8)
        assert packets_bare.tobytes() == alone_bare.tobytes() == alone.tobytes()


def test_shadow_rays_use_interior_balls_only_where_no_shading_point_is_inside_the_solid():
    """The renderer gives a mesh instance its balls and normal cones while the camera (eye and
    lens, at both ends of its motion) and every light stay outside the instance's box, and its
    images are then the same bit for bit as without them; a camera or a point light inside the
    box, camera rays that start past the eye (``t_min``), points moved by ``set_mesh_points``
    and a batch's worlds take none."""
    scene = _balls_scene()
    r = warprt.Renderer(scene, device="cpu")
    assert _n_balls(r) > 0 and _cones(r) != 0
    with_balls, without = _with_and_without(r, "n_balls", 4)
    assert without.tobytes() == with_balls.tobytes()
    with_cones, without = _with_and_without(r, "cones", 4)  # (neither balls nor cones now)
    assert without.tobytes() == with_cones.tobytes() == with_balls.tobytes()
    r.built.refresh_balls()
    assert _n_balls(r) > 0 and _cones(r) != 0
    # the same through the all-features kernel, whose shadow rays take ``transmittance``
    full = warprt.Renderer(scene, device="cpu", features=warprt.Features.full())
    assert _n_balls(full) > 0 and _cones(full) != 0
    with_balls, without = _with_and_without(full, "n_balls", 2)
    assert without.tobytes() == with_balls.tobytes()
    with_cones, without = _with_and_without(full, "cones", 2)
    assert without.tobytes() == with_cones.tobytes() == with_balls.tobytes()

    r.set_camera(dataclasses.replace(scene.camera, eye=(0.0, 0.2, 0.3)))  # inside the mesh's box
    assert _n_balls(r) == 0 and _cones(r) == 0
    r.set_camera(dataclasses.replace(scene.camera, eye=(0.0, 0.2, 3.0), aperture=1.9))  # the lens reaches into it
    assert _n_balls(r) == 0 and _cones(r) == 0
    r.set_camera(dataclasses.replace(scene.camera, eye_end=(0.0, 0.2, 0.5)))  # moving into it over the shutter
    assert _n_balls(r) == 0 and _cones(r) == 0
    r.set_camera(scene.camera)
    assert _n_balls(r) > 0 and _cones(r) != 0

    cut = warprt.Renderer(scene.with_settings(t_min=1.0), device="cpu")  # camera rays may start inside
    assert _n_balls(cut) == 0 and _cones(cut) == 0
    lit_inside = _balls_scene(light=warprt.PointLight(position=(0.0, 0.0, 0.0), intensity=5.0))
    r_inside = warprt.Renderer(lit_inside, device="cpu")
    assert _n_balls(r_inside) == 0 and _cones(r_inside) == 0
    lit_outside = _balls_scene(light=warprt.PointLight(position=(0.0, 3.0, 0.0), intensity=5.0))
    r_outside = warprt.Renderer(lit_outside, device="cpu")
    assert _n_balls(r_outside) > 0 and _cones(r_outside) != 0

    v = np.asarray(scene.shapes[1].vertices)
    r.set_mesh_points(1, v * 1.01)
    assert _n_balls(r) == 0 and _cones(r) == 0
    r.update(scene)  # the moved asset is reused: still none
    assert _n_balls(r) == 0 and _cones(r) == 0

    worlds = warprt.BatchRenderer(scene, worlds=2, device="cpu").tables.insts.numpy()
    assert int(worlds["n_balls"].max()) == 0 and int(worlds["cones"].max()) == 0


# --- escaping faces (accel.escape_sides): shadow rays leaving a face with the mesh behind it ------


def _escape_meshes():
    import trimesh

    from benchmarks.peers import bumpy_torus

    ico = trimesh.creation.icosphere(subdivisions=3, radius=0.45)
    iv, fi = np.asarray(ico.vertices, np.float32), np.asarray(ico.faces, np.int32)
    tv, tf = bumpy_torus(48, 24, major=0.55, minor=0.2)
    half = trimesh.creation.uv_sphere(radius=0.5, count=[24, 24])
    hv = np.asarray(half.vertices, np.float64)
    hf = np.asarray(half.faces)
    hf = hf[(hv[hf][:, :, 1] <= 1e-9).all(axis=1)]  # the lower half: an open bowl
    return {"icosphere": (iv, fi), "icosphere wound inwards": (iv, fi[:, ::-1].copy()),
            "torus": (tv.astype(np.float32), tf.astype(np.int32)), "bumpy sphere": _bumpy_sphere(),
            "bowl": (hv.astype(np.float32), hf.astype(np.int32))}


def test_escaping_faces_are_those_with_the_whole_mesh_behind_them():
    """``accel.escape_sides``: a convex mesh's faces all escape on their outer side (the front, or
    the back when wound inwards), a torus's outer half and no inner face, a bowl's outside and
    not its inside, and a bumpy sphere's and a box's (its top with one vertex raised) faces only
    where no vertex rises above their plane (float64 brute force)."""
    m = _escape_meshes()
    assert np.all(accel.escape_sides(*m["icosphere"]) == 1)
    assert np.all(accel.escape_sides(*m["icosphere wound inwards"]) == 2)
    assert np.all(accel.escape_sides(*m["bowl"]) == 1)
    v, f = m["torus"]
    side = accel.escape_sides(v, f)
    centre = v[f].astype(np.float64).mean(axis=1)
    outer = np.hypot(centre[:, 0], centre[:, 2]) > 0.55
    assert np.all(side[~outer] == 0) and outer.mean() > 0.4 and side[outer].mean() > 0.9
    import trimesh

    # a box's flat top, finely cut, with one inner vertex raised by 1e-3: the faces of the top
    # have it in front of them, and it is the extreme vertex only in a narrow cone of directions
    box = trimesh.creation.box(extents=(1.0, 0.5, 1.0))
    bv, bf = trimesh.remesh.subdivide(*trimesh.remesh.subdivide(box.vertices, box.faces))
    bv = np.asarray(bv, np.float64)
    raised = np.flatnonzero((np.abs(bv[:, 1] - 0.25) < 1e-9) & (np.abs(bv[:, 0]) < 0.4) & (np.abs(bv[:, 2]) < 0.4))[0]
    bv[raised, 1] += 1e-3
    for v, f in (m["bumpy sphere"], (bv.astype(np.float32), np.asarray(bf, np.int32))):
        side = accel.escape_sides(v, f)
        t = v[f].astype(np.float64)
        n = np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])
        length = np.linalg.norm(n, axis=1, keepdims=True)
        n = n / np.where(length > 0, length, 1.0)
        h = n @ v.T.astype(np.float64) - np.einsum("fj,fj->f", n, t[:, 0])[:, None]
        tol = accel.ESCAPE_TOL * float(np.abs(v).max())
        np.testing.assert_array_equal(side == 1, (h.max(axis=1) <= tol) & (length[:, 0] > 0))
        assert 0 < (side == 1).mean() < 1 and not (side == 2).any()


@pytest.mark.parametrize("name", ["icosphere", "icosphere wound inwards", "torus", "bumpy sphere", "bowl"])
def test_shadow_rays_leaving_an_escaping_face_meet_no_triangle_of_its_mesh(name):
    """A ray from a point of an escaping face, spawned off it to its escaping side as the renderer
    spawns shadow rays, in any direction into that side (grazing ones too) and of any length,
    meets no triangle of the mesh (``accel.mesh_tree_occluded``, the renderer's own test); the
    same rays from the faces that do not escape on that side are blocked now and then."""
    v, f = _escape_meshes()[name]
    from warprt.geometry import SPAWN_ABS, SPAWN_REL

    side = accel.escape_sides(v, f)
    side = np.zeros(len(f), np.uint8) if side is None else side
    tri = v[f].astype(np.float64)
    rng = np.random.default_rng(13)
    n_rays = 4000
    face = rng.integers(0, len(f), n_rays)
    bary = rng.dirichlet([1.5, 1.5, 1.5], n_rays)
    p = np.einsum("nk,nkj->nj", bary, tri[face])
    ng = np.cross(tri[face, 1] - tri[face, 0], tri[face, 2] - tri[face, 0])
    ng /= np.linalg.norm(ng, axis=1, keepdims=True)
    # the side the ray leaves into, either: into the escaping side, it must meet nothing
    s = rng.choice([-1.0, 1.0], n_rays)
    escaping = ((s > 0) & (side[face] & 1 != 0)) | ((s < 0) & (side[face] & 2 != 0))
    g = ng * s[:, None]
    mag = np.maximum(np.abs(tri[face]).max(axis=1), np.abs(p))
    o = p + g * (np.sum(np.abs(g) * mag, axis=1) * SPAWN_REL + SPAWN_ABS)[:, None]
    d = rng.normal(size=(n_rays, 3))
    d -= np.sum(d * g, axis=1)[:, None] * g  # in the plane, then tilted up: grazing to steep
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    up = rng.choice([1e-4, 1e-2, 0.3, 1.0, 10.0], n_rays)
    d = d + g * up[:, None]
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    t_max = rng.choice([0.05, 0.5, 5.0], n_rays)
    mesh = wp.Mesh(points=wp.array(v, dtype=wp.vec3, device="cpu"),
                   indices=wp.array(f.reshape(-1), dtype=wp.int32, device="cpu"), bvh_leaf_size=1)
    tree = accel.MeshTree(mesh, len(f))

    @wp.kernel(enable_backward=False, module="unique", module_options=MODULE_OPTIONS)
    def k_occ(nodes: wp.uint64, kids: wp.uint64, tris: wp.uint64, root: int, o: wp.array(dtype=wp.vec3),
              d: wp.array(dtype=wp.vec3), t_max: wp.array(dtype=float), out: wp.array(dtype=int)):
        i = wp.tid()
        out[i] = accel.mesh_tree_occluded(nodes, kids, tris, root, wp.uint64(0), o[i], d[i], t_max[i])

    out = wp.zeros(n_rays, dtype=int, device="cpu")
    wp.launch(k_occ, dim=n_rays, device="cpu", inputs=[
        tree.nodes.ptr, tree.kids.ptr, tree.tris.ptr, tree.root, wp.array(o.astype(np.float32), dtype=wp.vec3,
                                                                             device="cpu"),
        wp.array(d.astype(np.float32), dtype=wp.vec3, device="cpu"), wp.array(t_max.astype(np.float32), dtype=float,
                                                                              device="cpu"), out])
    blocked = out.numpy()
    assert (blocked >= 0).all()
    assert blocked[escaping].sum() == 0, f"{int(blocked[escaping].sum())} rays from escaping faces blocked"
    assert blocked[~escaping].sum() > 20  # (the same construction finds the mesh on the other sides)
    assert escaping.mean() > (0.02 if name == "bumpy sphere" else 0.2)  # (0.03 there: 6% of its faces)


# --- escape horizons (accel.escape_horizons): shadow rays above a face's horizon ---------------


def _rays_off_faces(tri, rng, n_rays, side=None):
    """Rays from random points of random triangles ``tri`` (F, 3, 3), spawned off them as the
    renderer spawns shadow rays, towards ``side`` (+1: along the winding normal, -1: against it;
    None: each ray's drawn at random), from grazing to steep and of any length: the faces, the
    sides, the origins, the directions and t_max."""
    from warprt.geometry import SPAWN_ABS, SPAWN_REL

    face = rng.integers(0, len(tri), n_rays)
    p = np.einsum("nk,nkj->nj", rng.dirichlet([1.5, 1.5, 1.5], n_rays), tri[face])
    ng = np.cross(tri[face, 1] - tri[face, 0], tri[face, 2] - tri[face, 0])
    ng /= np.linalg.norm(ng, axis=1, keepdims=True)
    s = rng.choice([-1.0, 1.0], n_rays) if side is None else np.full(n_rays, float(side))
    g = ng * s[:, None]
    mag = np.maximum(np.abs(tri[face]).max(axis=1), np.abs(p))
    o = p + g * (np.sum(np.abs(g) * mag, axis=1) * SPAWN_REL + SPAWN_ABS)[:, None]
    d = rng.normal(size=(n_rays, 3))
    d -= np.sum(d * g, axis=1)[:, None] * g
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    d = d + g * rng.choice([1e-3, 0.1, 0.4, 1.0, 3.0, 30.0], n_rays)[:, None]
    d *= rng.choice([0.5, 1.0, 2.0], n_rays)[:, None] / np.linalg.norm(d, axis=1, keepdims=True)  # any length
    t_max = rng.choice([0.05, 0.5, 5.0], n_rays) / np.linalg.norm(d, axis=1)
    return face, s, o, d, t_max


def _horizon_meshes():
    import trimesh

    from benchmarks.peers import bumpy_torus

    m = _escape_meshes()
    bt, bf = bumpy_torus(64, 32, major=0.55, minor=0.2, bumps=0.12)  # saddles and hollows
    box = trimesh.creation.box(extents=(1.0, 0.5, 1.0))
    xv, xf = trimesh.remesh.subdivide(*trimesh.remesh.subdivide(box.vertices, box.faces))
    xv = np.asarray(xv, np.float64)
    raised = np.flatnonzero((np.abs(xv[:, 1] - 0.25) < 1e-9) & (np.abs(xv[:, 0]) < 0.4) & (np.abs(xv[:, 2]) < 0.4))[0]
    xv[raised, 1] += 1e-3
    return {"torus": m["torus"], "bumpy torus": (bt.astype(np.float32), bf.astype(np.int32)),
            "bumpy sphere": m["bumpy sphere"], "bowl": m["bowl"],
            "box with a raised vertex": (xv.astype(np.float32), np.asarray(xf, np.int32)),
            "icosphere wound inwards": m["icosphere wound inwards"]}


# the least share of the unblocked rays that pass their face's horizon, per mesh: measured (this
# draw) torus 0.595, bumpy torus 0.227, bumpy sphere 0.429, bowl 0.763, box 0.654, inward
# icosphere 0.683, each less 0.04 (about 5 standard deviations of a share over ~3000 rays)
_HORIZON_SHARE = {"torus": 0.555, "bumpy torus": 0.187, "bumpy sphere": 0.389, "bowl": 0.723,
                  "box with a raised vertex": 0.614, "icosphere wound inwards": 0.643}


def _horizon_reference(h, code, d):
    """``accel.horizon_escapes`` for rays along d (float32) from face and side ``code``, with
    numpy's float32 operations in the order the C++ took before its frames were stored: the
    face's normal A (negated for side 1), then t across A and the axis of A's least component,
    b = A x t, and the sector of (d.t, d.b) found by the branches of its octants."""
    f32 = np.float32
    a = h[code // 2, :3].copy().view(np.float32) * np.where(code % 2 == 1, f32(-1.0), f32(1.0))[:, None]
    dx, dy, dz = d[:, 0], d[:, 1], d[:, 2]
    da = dx * a[:, 0] + dy * a[:, 1] + dz * a[:, 2]
    m = np.abs(a)
    ax = np.where(m[:, 0] <= m[:, 1], np.where(m[:, 0] <= m[:, 2], 0, 2), np.where(m[:, 1] <= m[:, 2], 1, 2))
    zero = np.zeros(len(a), f32)
    t = np.where((ax == 0)[:, None], np.stack([zero, a[:, 2], -a[:, 1]], 1),
                 np.where((ax == 1)[:, None], np.stack([-a[:, 2], zero, a[:, 0]], 1), np.stack([a[:, 1], -a[:, 0], zero], 1)))
    with np.errstate(divide="ignore", invalid="ignore"):
        t = t * (f32(1.0) / np.sqrt(t[:, 0] * t[:, 0] + t[:, 1] * t[:, 1] + t[:, 2] * t[:, 2]))[:, None]
    b = np.stack([a[:, 1] * t[:, 2] - a[:, 2] * t[:, 1], a[:, 2] * t[:, 0] - a[:, 0] * t[:, 2],
                  a[:, 0] * t[:, 1] - a[:, 1] * t[:, 0]], 1)
    x = dx * t[:, 0] + dy * t[:, 1] + dz * t[:, 2]
    y = dx * b[:, 0] + dy * b[:, 1] + dz * b[:, 2]
    sector = np.where(y >= 0, np.where(x > 0, np.where(y < x, 0, 1), np.where(y > -x, 2, 3)),
                      np.where(x < 0, np.where(-y < -x, 4, 5), np.where(x < -y, 6, 7)))
    q = h[code // 2, 4:8].copy().view(np.uint8).reshape(-1, 2, 8)[np.arange(len(code)), code % 2, sector]
    hq = q.astype(f32) * (f32(1.0) / f32(255.0))
    return ((da > 0) & (q != 255) & (da * da > hq * hq * (dx * dx + dy * dy + dz * dz))).astype(int)


@pytest.mark.parametrize("name", list(_HORIZON_SHARE))
def test_shadow_rays_above_a_faces_escape_horizon_meet_no_triangle_of_its_mesh(name):
    """``accel.escape_horizons`` and ``horizon_escapes``: rays from points of the faces, spawned
    off them as the renderer spawns shadow rays, in directions from grazing to steep and of any
    length, towards either side: none that passes its face's horizon meets a triangle of the
    mesh (``accel.mesh_tree_occluded``, the renderer's own test), while a fair share of the
    unblocked ones pass (the bounds are not all closed); faces that escape outright
    (``escape_sides``) have every sector at zero; a closed mesh's inner side stays closed."""
    v, f = _horizon_meshes()[name]
    mesh = wp.Mesh(points=wp.array(v, dtype=wp.vec3, device="cpu"),
                   indices=wp.array(f.reshape(-1), dtype=wp.int32, device="cpu"), bvh_leaf_size=1)
    tree = accel.MeshTree(mesh, len(f))
    h = accel.escape_horizons(tree, v, f)
    assert h is not None and h.shape == (len(f), accel.ESCAPE_WORDS)
    sectors = h[:, 4:8].copy().view(np.uint8).reshape(len(f), 2, 8)
    known = accel.escape_sides(v, f)
    if known is not None:
        for side in (0, 1):
            assert np.all(sectors[known >> side & 1 != 0, side] == 0)
    if accel.closed_surface(f):
        inner = 1 if name != "icosphere wound inwards" else 0  # (the side not computed)
        assert np.all(sectors[:, inner] == 255) and np.all(h[:, 3] >> inner & 1 == 0)
    tri = v[f].astype(np.float64)
    face, s, o, d, t_max = _rays_off_faces(tri, np.random.default_rng(29), 6000)
    n_rays = len(face)
    code = 2 * face + (s < 0)
    hz = wp.array(h.reshape(-1), dtype=wp.uint32, device="cpu")
    frames = wp.array(accel.escape_frames(h[:, :3].copy().view(np.float32)).reshape(-1), dtype=wp.float32, device="cpu")

    @wp.kernel(enable_backward=False, module="unique", module_options=MODULE_OPTIONS)
    def k_hz(nodes: wp.uint64, kids: wp.uint64, tris: wp.uint64, root: int, esc: wp.uint64, fr: wp.uint64,
             code: wp.array(dtype=int), o: wp.array(dtype=wp.vec3), d: wp.array(dtype=wp.vec3),
             t_max: wp.array(dtype=float), out: wp.array(dtype=wp.vec3i)):
        i = wp.tid()
        out[i] = wp.vec3i(accel.mesh_tree_occluded(nodes, kids, tris, root, wp.uint64(0), o[i], d[i], t_max[i]),
                          accel.horizon_escapes(esc, fr, code[i], d[i]),
                          accel.horizon_open(esc, code[i] // 2, code[i] % 2))

    out = wp.zeros(n_rays, dtype=wp.vec3i, device="cpu")
    wp.launch(k_hz, dim=n_rays, device="cpu", inputs=[
        tree.nodes.ptr, tree.kids.ptr, tree.tris.ptr, tree.root, hz.ptr, frames.ptr,
        wp.array(code.astype(np.int32), dtype=int),
        wp.array(o.astype(np.float32), dtype=wp.vec3, device="cpu"),
        wp.array(d.astype(np.float32), dtype=wp.vec3, device="cpu"),
        wp.array(t_max.astype(np.float32), dtype=float, device="cpu"), out])
    blocked, passes, is_open = out.numpy().T
    assert (blocked >= 0).all()
    # the stored frames and the sectors found without branches decide as the per-ray frame does
    np.testing.assert_array_equal(passes, _horizon_reference(h, code, d.astype(np.float32)))
    assert blocked[passes == 1].sum() == 0, f"{int(blocked[passes == 1].sum())} rays above their horizon blocked"
    assert np.all(passes[is_open == 0] == 0)
    assert blocked.sum() > 50  # (the rays find the mesh where they may)
    share = passes[blocked == 0].mean()
    assert share > _HORIZON_SHARE[name], f"{share:.3f} of the unblocked rays pass their horizon"


def test_escape_horizons_against_closed_forms():
    """A floor triangle and a wall beyond one of its edges (an open mesh of two faces): the highest
    direction from the floor to the wall leaves the middle of that edge for the wall's top
    corner, sin e = 0.3 / sqrt(0.34), higher than any corner-to-corner direction (0.39): the
    floor's horizon (the wall too near for a cap, and upright, so the exact cone's bound) is that
    sine plus HORIZON_MARGIN, rounded up to 1/255, in every sector. A wide roof over the floor
    instead closes its horizon (straight up meets it, though every edge of the cone of
    directions to it lies low)."""
    floor = [(0.0, 0.0, 0.0), (1.0, 0.0, 0.0), (0.5, 0.0, -1.0)]  # normal +y
    wall = [(-1.0, 0.0, 0.5), (2.0, 0.0, 0.5), (0.5, 0.3, 0.5)]
    roof = [(-2.0, 0.2, -3.0), (0.5, 0.2, 3.0), (3.0, 0.2, -3.0)]  # (overhanging: no steep edge to see)
    for top, expected in ((wall, None), (roof, 255)):
        v = np.array(floor + list(top), np.float32)
        f = np.array([[0, 1, 2], [3, 4, 5]], np.int32)
        mesh = wp.Mesh(points=wp.array(v, dtype=wp.vec3, device="cpu"),
                       indices=wp.array(f.reshape(-1), dtype=wp.int32, device="cpu"), bvh_leaf_size=1)
        h = accel.escape_horizons(accel.MeshTree(mesh, 2), v, f)
        if expected is None:  # the wall
            expected = int(np.ceil((0.3 / np.sqrt(0.34) + accel.HORIZON_MARGIN) * 255.0))
            assert h is not None and h[0, 3] & 1 == 1
        sectors = np.zeros(8, np.uint8) + 255 if h is None else h[0, 4:6].copy().view(np.uint8)
        assert np.all(sectors == expected), sectors


def test_escape_horizons_of_large_meshes_are_their_escaping_faces(monkeypatch):
    """Past HORIZON_MAX_TRIANGLES the horizons are the escaping faces alone: zero on the side a
    face escapes on (``escape_sides``), every other sector closed, the axis the face's float32
    unit normal; none where no face escapes."""
    monkeypatch.setattr(accel, "HORIZON_MAX_TRIANGLES", 1000)
    m = _escape_meshes()
    for name, side in (("icosphere", 0), ("icosphere wound inwards", 1)):
        v, f = m[name]
        assert len(f) > accel.HORIZON_MAX_TRIANGLES
        mesh = wp.Mesh(points=wp.array(v, dtype=wp.vec3, device="cpu"),
                       indices=wp.array(f.reshape(-1), dtype=wp.int32, device="cpu"), bvh_leaf_size=1)
        h = accel.escape_horizons(accel.MeshTree(mesh, len(f)), v, f)
        sectors = h[:, 4:8].copy().view(np.uint8).reshape(len(f), 2, 8)
        assert np.all(h[:, 3] == 1 << side) and np.all(sectors[:, side] == 0) and np.all(sectors[:, 1 - side] == 255)
        t = v[f].astype(np.float64)
        n = np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])
        np.testing.assert_array_equal(h[:, :3].copy().view(np.float32),
                                      (n / np.linalg.norm(n, axis=1, keepdims=True)).astype(np.float32))
    v, f = _horizon_meshes()["bumpy torus"]  # (no face escapes)
    mesh = wp.Mesh(points=wp.array(v, dtype=wp.vec3, device="cpu"),
                   indices=wp.array(f.reshape(-1), dtype=wp.int32, device="cpu"), bvh_leaf_size=1)
    assert accel.escape_sides(v, f) is None
    assert accel.escape_horizons(accel.MeshTree(mesh, len(f)), v, f) is None


def test_shadow_rays_skip_the_mesh_whose_escaping_face_they_leave_and_the_image_stays_the_same():
    """A scene whose meshes have escaping faces and escape horizons (an icosphere, a torus stood
    up, squashed and turned, whose inner faces see each other across the hole, and a bowl seen
    from inside, where its rim shadows its floor; a small ball between the light and the torus)
    renders the same bit for bit with them as without them (records' ``escape`` zeroed), lit by
    a rectangle light and a point light; moving a mesh's points drops them."""
    m = _escape_meshes()
    iv, fi = m["icosphere"]
    tv, tf = m["torus"]
    tf = tf[np.random.default_rng(5).permutation(len(tf))]  # (a face's index says nothing of its place)
    bv, bf = m["bowl"]
    scene = warprt.Scene(
        camera=warprt.Camera(eye=(0.2, 2.4, 2.6), look_at=(0.0, 0.2, 0.0), fov=55.0, width=64, height=48),
        shapes=(warprt.Plane(point=(0.0, -0.5, 0.0), normal=(0.0, 1.0, 0.0), material="ground"),
                warprt.Mesh(vertices=iv, faces=fi, material="a", transform=warprt.Transform(translate=(0.9, 0.0, 0.2))),
                warprt.Mesh(vertices=tv, faces=tf, material="a",  # (stood up, squashed: its hole to the light)
                            transform=warprt.Transform(translate=(-0.7, -0.1, 0.0), rotate=(55.0, 0.0, 20.0),
                                                       scale=(1.0, 1.3, 0.8))),
                warprt.Mesh(vertices=bv, faces=bf, material="a", transform=warprt.Transform(translate=(0.1, 0.0, -0.9))),
                warprt.Mesh(vertices=iv * 0.3, faces=fi, material="a",
                            transform=warprt.Transform(translate=(-0.6, 0.5, 0.1)))),
        materials={"ground": warprt.Material(kd=0.6, ka=0.0), "a": warprt.Material(kd=0.7, ks=0.2, p=20.0, ka=0.0)},
        lights=(warprt.RectLight(corner=(-1.0, 2.0, -0.8), edge1=(1.6, 0.0, 0.0), edge2=(0.0, 0.3, 1.2), radiance=3.0),
                warprt.PointLight(position=(1.5, 2.5, -1.5), intensity=2.0)))
    r = warprt.Renderer(scene, device="cpu")
    rows = r.built.data.insts.numpy()
    assert np.count_nonzero(rows["escape"]) == 4
    assert np.count_nonzero(rows["frames"]) == 4  # (their sectors' frames: horizons found on all four)
    assert np.count_nonzero(rows["cones"]) == 3  # (the bowl is open)
    with_faces, without = _with_and_without(r, "escape", 4)
    assert without.tobytes() == with_faces.tobytes()
    with_cones, without_cones = _with_and_without(r, "cones", 4)  # (neither horizons nor cones now)
    assert without_cones.tobytes() == with_cones.tobytes() == without.tobytes()
    assert float(without[..., 0].std()) > 0.01  # (a lit, shadowed image)
    r2 = warprt.Renderer(scene, device="cpu")
    r2.set_mesh_points(2, tv * 1.01)
    assert r2.built.data.insts.numpy()["escape"][1] == 0 and r2.built.data.insts.numpy()["frames"][1] == 0
    r2.update(scene)  # the moved asset is reused: still none
    assert r2.built.data.insts.numpy()["escape"][1] == 0


# --- normal cones (accel.normal_cones): shadow rays skip the subtrees they can only leave ---------

# the least share of a tree's inner children whose cone is open (s < 1), per mesh: measured torus
# 0.983, bumpy torus 0.910, bumpy sphere 0.956, box 0.842, inward icosphere 0.995, each less 0.02
_CONE_SHARE = {"torus": 0.963, "bumpy torus": 0.89, "bumpy sphere": 0.936, "box with a raised vertex": 0.822,
               "icosphere wound inwards": 0.975}


@pytest.mark.parametrize("name", list(_CONE_SHARE))
def test_normal_cones_hold_their_subtrees_normals_and_shadow_rays_keep_their_answer(name):
    """``accel.normal_cones`` of a closed, consistently wound mesh: each child's cone (axis a, s)
    holds the outward unit normal (float64) of every triangle of its subtree within arcsin(s -
    CONE_MARGIN) of a, a leaf's is its triangle's normal, and most are open; shadow segments
    whose ends lie outside the solid (between random points around it, and from points of the
    faces spawned off their outer side as the renderer spawns shadow rays, grazing to steep, of
    any length) get the same answer from ``mesh_tree_occluded`` with the cones as without them."""
    v, f = _horizon_meshes()[name]
    mesh = wp.Mesh(points=wp.array(v, dtype=wp.vec3, device="cpu"),
                   indices=wp.array(f.reshape(-1), dtype=wp.int32, device="cpu"), bvh_leaf_size=1)
    tree = accel.MeshTree(mesh, len(f))
    cones = accel.normal_cones(tree, v, f)
    assert cones is not None
    tri = v[f].astype(np.float64)
    outward = 1.0 if name != "icosphere wound inwards" else -1.0
    # the outward unit normals in leaf order, and each node's range of leaves (a subtree holds a
    # run of the leaf order)
    leaf_tri = tree.tris.numpy().astype(np.float64).reshape(-1, 3, 3)
    ln = np.cross(leaf_tri[:, 1] - leaf_tri[:, 0], leaf_tri[:, 2] - leaf_tri[:, 0])
    ln = outward * ln / np.linalg.norm(ln, axis=1, keepdims=True)
    kids = tree.kids.numpy().reshape(-1, 2)
    span = {}

    def leaves(k):
        if k < 0:
            return -k - 1, -k - 1
        if k not in span:
            a, b = leaves(int(kids[k, 0])), leaves(int(kids[k, 1]))
            span[k] = (min(a[0], b[0]), max(a[1], b[1]))
        return span[k]

    leaves(tree.root)  # (these trees are a few dozen levels deep)
    n_open = n_inner = 0
    for node in span:
        for c in range(2):
            k = int(kids[node, c])
            a, s = cones[node, c, :3].astype(np.float64), float(cones[node, c, 3])
            if k < 0:
                np.testing.assert_array_equal(cones[node, c, :3], ln[-k - 1].astype(np.float32))
                assert s == np.float32(accel.CONE_MARGIN)
                continue
            n_inner += 1
            if s >= 1.0:
                continue
            n_open += 1
            lo, hi = span[k]
            # a shadow ray u with u.a >= s (float32) leaves every triangle there: each normal lies
            # within arcsin(s / |a|) of a, less a float32 rounding's worth
            unit = a / np.linalg.norm(a)
            nn = ln[lo:hi + 1]
            angle = np.arctan2(np.linalg.norm(np.cross(nn, unit), axis=1), nn @ unit)
            assert np.all(angle <= np.arcsin(s / np.linalg.norm(a)) - 1e-6), (node, c)
    assert n_open / n_inner > _CONE_SHARE[name], n_open / n_inner

    o_all, d_all, t_all, n1 = _outside_segments(v, tri, outward)
    cn = wp.array(cones.reshape(-1), dtype=wp.float32, device="cpu")

    @wp.kernel(enable_backward=False, module="unique", module_options=MODULE_OPTIONS)
    def k_cones(nodes: wp.uint64, kids: wp.uint64, tris: wp.uint64, root: int, cones: wp.uint64,
                o: wp.array(dtype=wp.vec3), d: wp.array(dtype=wp.vec3), t_max: wp.array(dtype=float),
                out: wp.array(dtype=wp.vec2i)):
        i = wp.tid()
        out[i] = wp.vec2i(accel.mesh_tree_occluded(nodes, kids, tris, root, cones, o[i], d[i], t_max[i]),
                          accel.mesh_tree_occluded(nodes, kids, tris, root, wp.uint64(0), o[i], d[i], t_max[i]))

    out = wp.zeros(len(o_all), dtype=wp.vec2i, device="cpu")
    wp.launch(k_cones, dim=len(o_all), device="cpu", inputs=[
        tree.nodes.ptr, tree.kids.ptr, tree.tris.ptr, tree.root, cn.ptr,
        wp.array(o_all.astype(np.float32), dtype=wp.vec3, device="cpu"),
        wp.array(d_all.astype(np.float32), dtype=wp.vec3, device="cpu"),
        wp.array(t_all.astype(np.float32), dtype=float, device="cpu"), out])
    with_cones, without = out.numpy().T
    assert (without >= 0).all() and (with_cones >= 0).all()
    differ = np.flatnonzero(with_cones != without)
    assert differ.size == 0, f"{differ.size} of {len(o_all)} segments answered otherwise with the cones"
    assert 100 < without[:n1].sum() < n1 - 100
    # (from the faces: 485, 1535, 710 and 31 blocked of 6000; none from the convex icosphere)
    assert without[n1:].sum() > (20 if name != "icosphere wound inwards" else -1)


def _outside_segments(v, tri, outward):
    """Shadow segments whose ends lie outside a closed mesh's solid: between random points around
    it (float64 winding numbers 0 at both ends), then from points of the faces spawned off their
    outer side, grazing to steep, of any length (``_rays_off_faces``): origins, directions,
    lengths (in units of the direction) and how many of the first kind."""
    rng = np.random.default_rng(31)
    lo, hi = v.min(axis=0) - 0.5, v.max(axis=0) + 0.5
    o = rng.uniform(lo, hi, (5000, 3))
    q = rng.uniform(lo, hi, (5000, 3))
    keep = (np.abs(_winding_f64(tri, o)) < 1e-6) & (np.abs(_winding_f64(tri, q)) < 1e-6)
    o1, d1 = o[keep], (q - o)[keep]
    _, _, o2, d2, t2 = _rays_off_faces(tri, rng, 6000, outward)
    return (np.concatenate([o1, o2]), np.concatenate([d1, d2]), np.concatenate([np.ones(len(o1)), t2]), len(o1))


@pytest.mark.parametrize("name", list(_CONE_SHARE))
def test_shadow_packets_give_each_lane_its_own_answer(name):
    """``accel.mesh_tree_occluded_packet`` (up to 8 shadow rays through the tree copy's wide form
    together, a lane retired at its first occluder) answers every lane as ``mesh_tree_occluded`` answers it
    alone, with the normal cones and without, for full packets and random lane masks (lanes
    outside the mask answer 0), on the cone test's segments: between outside points, and from
    spawned face points in packets of neighbouring faces' rays (as a camera packet's shading
    points send theirs) and of random ones."""
    v, f = _horizon_meshes()[name]
    mesh = wp.Mesh(points=wp.array(v, dtype=wp.vec3, device="cpu"),
                   indices=wp.array(f.reshape(-1), dtype=wp.int32, device="cpu"), bvh_leaf_size=1)
    tree = accel.MeshTree(mesh, len(f))
    cones = accel.normal_cones(tree, v, f)
    tri = v[f].astype(np.float64)
    outward = 1.0 if name != "icosphere wound inwards" else -1.0
    o_all, d_all, t_all, n1 = _outside_segments(v, tri, outward)
    rng = np.random.default_rng(32)
    shuffled = np.concatenate([np.arange(len(o_all)), rng.permutation(len(o_all))])  # in order, then mixed
    m = len(shuffled) // 8 * 8
    idx = shuffled[:m]
    masks = rng.integers(1, 256, m // 8)
    masks[::3] = 255
    cn = wp.array(tree.wide_rows(cones.reshape(-1, 4)).reshape(-1), dtype=wp.float32, device="cpu")

    @wp.kernel(enable_backward=False, module="unique", module_options=MODULE_OPTIONS)
    def k_lanes(wide: wp.uint64, tris: wp.uint64, cones: wp.uint64,
                o: wp.array(dtype=wp.vec3), d: wp.array(dtype=wp.vec3), t_max: wp.array(dtype=float),
                masks: wp.array(dtype=int), out: wp.array(dtype=wp.vec2i)):
        i = wp.tid()
        ox = accel.PacketF()
        oy = accel.PacketF()
        oz = accel.PacketF()
        dx = accel.PacketF()
        dy = accel.PacketF()
        dz = accel.PacketF()
        tm = accel.PacketF()
        for k in range(8):
            ox[k] = o[8 * i + k][0]
            oy[k] = o[8 * i + k][1]
            oz[k] = o[8 * i + k][2]
            dx[k] = d[8 * i + k][0]
            dy[k] = d[8 * i + k][1]
            dz[k] = d[8 * i + k][2]
            tm[k] = t_max[8 * i + k]
        a = accel.mesh_tree_occluded_packet(wide, tris, cones, ox, oy, oz, dx, dy, dz, tm, masks[i])
        b = accel.mesh_tree_occluded_packet(wide, tris, wp.uint64(0), ox, oy, oz, dx, dy, dz, tm, masks[i])
        for k in range(8):
            out[8 * i + k] = wp.vec2i((a >> k) & 1, (b >> k) & 1)
            if a < 0 or b < 0:
                out[8 * i + k] = wp.vec2i(-1, -1)

    @wp.kernel(enable_backward=False, module="unique", module_options=MODULE_OPTIONS)
    def k_alone(nodes: wp.uint64, kids: wp.uint64, tris: wp.uint64, root: int,
                o: wp.array(dtype=wp.vec3), d: wp.array(dtype=wp.vec3), t_max: wp.array(dtype=float),
                out: wp.array(dtype=int)):
        i = wp.tid()
        out[i] = accel.mesh_tree_occluded(nodes, kids, tris, root, wp.uint64(0), o[i], d[i], t_max[i])

    arrays = [wp.array(o_all[idx].astype(np.float32), dtype=wp.vec3, device="cpu"),
              wp.array(d_all[idx].astype(np.float32), dtype=wp.vec3, device="cpu"),
              wp.array(t_all[idx].astype(np.float32), dtype=float, device="cpu")]
    args = [tree.nodes.ptr, tree.kids.ptr, tree.tris.ptr, tree.root]
    lanes = wp.zeros(m, dtype=wp.vec2i, device="cpu")
    alone = wp.zeros(m, dtype=int, device="cpu")
    wp.launch(k_lanes, dim=m // 8, device="cpu", inputs=[tree.wide.ptr, tree.tris.ptr, cn.ptr] + arrays
              + [wp.array(masks.astype(np.int32), dtype=int, device="cpu"), lanes])
    wp.launch(k_alone, dim=m, device="cpu", inputs=args + arrays + [alone])
    with_cones, without = lanes.numpy().T
    want = alone.numpy()
    assert (want >= 0).all() and (with_cones >= 0).all()
    in_mask = ((masks[:, None] >> np.arange(8)) & 1).reshape(-1).astype(bool)
    np.testing.assert_array_equal(with_cones, np.where(in_mask, want, 0))
    np.testing.assert_array_equal(without, np.where(in_mask, want, 0))
    assert 0.02 < want[in_mask].mean() < 0.98  # (lit and blocked lanes both)


def test_normal_cones_need_a_closed_consistently_wound_mesh():
    """An open mesh, a closed one with one triangle wound the other way and a tree the copy cannot
    take get no cones; a mesh wound inwards gets them, its normals turned outwards."""
    m = _horizon_meshes()
    for name, expect in (("bowl", False), ("torus", True), ("icosphere wound inwards", True)):
        v, f = m[name]
        mesh = wp.Mesh(points=wp.array(v, dtype=wp.vec3, device="cpu"),
                       indices=wp.array(f.reshape(-1), dtype=wp.int32, device="cpu"), bvh_leaf_size=1)
        tree = accel.MeshTree(mesh, len(f))
        assert (accel.normal_cones(tree, v, f) is not None) == expect, name
        if name == "torus":
            flipped = f.copy()
            flipped[7] = flipped[7, ::-1]
            assert accel.closed_surface(flipped)
            assert accel.normal_cones(tree, v, flipped) is None
            tree.usable = False
            assert accel.normal_cones(tree, v, f) is None


def _wide_tree_checks(tree, n_faces):
    """The wide tree (``accel.widen``) of ``tree`` is a tree over the same leaves: node 0 the root,
    every other node and every leaf a child exactly once, each child's box holding its subtree's
    triangles, 2 to 4 children a node and fewer than 4 only where all are leaves."""
    w = tree.wide.numpy().reshape(-1, 32)
    kids = np.ascontiguousarray(w[:, 24:28]).view(np.int32)
    lo = w[:, :12].reshape(-1, 3, 4).transpose(0, 2, 1)
    hi = w[:, 12:24].reshape(-1, 3, 4).transpose(0, 2, 1)
    full = kids != accel.WIDE_EMPTY
    inner = full & (kids >= 0)
    assert (full.sum(1) >= 2).all()
    assert (full.all(1) | ~inner.any(1)).all()  # a node with an empty slot has only leaves
    np.testing.assert_array_equal(np.sort(kids[inner]), np.arange(1, len(w)))
    np.testing.assert_array_equal(np.sort(-kids[full & (kids < 0)] - 1), np.arange(n_faces))
    assert (kids[inner] > np.nonzero(inner)[0]).all()  # (level by level: children come after)
    corners = tree.tris.numpy().reshape(-1, 3, 3)
    sub_lo, sub_hi = np.zeros((len(w), 3), np.float32), np.zeros((len(w), 3), np.float32)
    for n in range(len(w) - 1, -1, -1):  # children first
        k = kids[n][full[n]]
        c_lo = np.where((k < 0)[:, None], corners[np.where(k < 0, -k - 1, 0)].min(1), sub_lo[np.maximum(k, 0)])
        c_hi = np.where((k < 0)[:, None], corners[np.where(k < 0, -k - 1, 0)].max(1), sub_hi[np.maximum(k, 0)])
        assert (lo[n][full[n]] <= c_lo).all() and (c_hi <= hi[n][full[n]]).all()
        sub_lo[n], sub_hi[n] = c_lo.min(0), c_hi.max(0)


def test_wide_tree_holds_the_binary_trees_leaves_four_to_a_node():
    """``accel.MeshTree``'s wide form, which the packets traverse (``mesh_tree_packet``,
    ``mesh_tree_occluded_packet``), on a triangle soup: a valid tree four to a node wherever there
    are inner nodes to open; after the points move and the tree is refitted (``refresh``), its
    boxes hold the moved triangles."""
    rng = np.random.default_rng(41)
    n = 3000
    centres = rng.random((n, 1, 3)) * [4.0, 1.0, 2.0]
    v = (centres + 0.05 * rng.standard_normal((n, 3, 3))).reshape(-1, 3).astype(np.float32)
    f = np.arange(3 * n, dtype=np.int32).reshape(n, 3)
    mesh = wp.Mesh(points=wp.array(v, dtype=wp.vec3, device="cpu"),
                   indices=wp.array(f.reshape(-1), dtype=wp.int32, device="cpu"), bvh_leaf_size=1)
    tree = accel.MeshTree(mesh, n)
    assert tree.usable
    _wide_tree_checks(tree, n)
    mesh.points.assign(v * [1.0, 3.0, 1.0] + rng.standard_normal(v.shape).astype(np.float32) * 0.02)
    mesh.refit()
    tree.refresh()
    _wide_tree_checks(tree, n)


def _bins_mesh():
    v, f = _bumpy_sphere()
    mesh = wp.Mesh(points=wp.array(v, dtype=wp.vec3, device="cpu"),
                   indices=wp.array(f.reshape(-1), dtype=wp.int32, device="cpu"), bvh_leaf_size=1)
    tree = accel.MeshTree(mesh, len(f))
    assert tree.usable
    return v, f, mesh, tree


def _bins_against_tree(mesh, tree, rec, o, d, reach):
    """Each lane's (t, u, v, face) through the bins (``accel.mesh_bins_packet``) and through the
    tree (``mesh_tree_packet``), packets of 8 rays, and whether the bins served each packet; each
    lane's ray alone through ``mesh_bins_ray`` is checked against them (``rays_served``: how many
    it served)."""

    @wp.kernel(enable_backward=False, module="unique", module_options=MODULE_OPTIONS)
    def k(mid: wp.uint64, bins: wp.uint64, wide: wp.uint64, tris: wp.uint64, o: wp.array(dtype=wp.vec3, ndim=2),
          d: wp.array(dtype=wp.vec3, ndim=2), reach: wp.array(dtype=float, ndim=2),
          via_bins: wp.array(dtype=wp.vec4, ndim=2), via_tree: wp.array(dtype=wp.vec4, ndim=2),
          served: wp.array(dtype=int), ray_bad: wp.array(dtype=int), ray_served: wp.array(dtype=int)):
        i = wp.tid()
        ox, oy, oz = _lanes(o, i, 0), _lanes(o, i, 1), _lanes(o, i, 2)
        dx, dy, dz = _lanes(d, i, 0), _lanes(d, i, 1), _lanes(d, i, 2)
        tm = accel.PacketF()
        for l in range(accel.PACKET):
            tm[l] = reach[i, l]
        bt = accel.PacketF()
        bu = accel.PacketF()
        bv = accel.PacketF()
        bf = accel.PacketI()
        served[i] = accel.mesh_bins_packet(mid, bins, tris, 1, ox, oy, oz, dx, dy, dz, tm, bt, bu, bv, bf)
        tt = accel.PacketF()
        tu = accel.PacketF()
        tv = accel.PacketF()
        tf = accel.PacketI()
        done = accel.mesh_tree_packet(mid, wide, tris, 1, ox, oy, oz, dx, dy, dz, tm, tt, tu, tv, tf)
        for l in range(accel.PACKET):
            if tm[l] >= 0.0:
                via_bins[i, l] = wp.vec4(bt[l], bu[l], bv[l], float(bf[l]))
                via_tree[i, l] = wp.vec4(tt[l], tu[l], tv[l], float(tf[l] + (1 - done) * 100000))
                # the one-ray walk (``mesh_bins_ray``): a served packet's lane bit for bit; in another
                # packet, not served (t -2) or the tree's t, give or take a tie's rounding
                q = accel.mesh_bins_ray(mid, bins, tris, wp.vec3(ox[l], oy[l], oz[l]), wp.vec3(dx[l], dy[l], dz[l]),
                                        tm[l])
                if served[i] != 0:
                    if q[0] != bt[l] or (q[0] >= 0.0 and (q[1] != bu[l] or q[2] != bv[l]
                                                          or int(q[3]) * 4096 + int(q[4]) != bf[l])):
                        ray_bad[i] = ray_bad[i] + 1
                    ray_served[i] = ray_served[i] + 1
                elif q[0] != -2.0:
                    if wp.abs(q[0] - tt[l]) > 4.0e-7 * wp.abs(tt[l]):
                        ray_bad[i] = ray_bad[i] + 1
                    ray_served[i] = ray_served[i] + 1

    n = len(o)
    arrays = [wp.array(x, dtype=dt, device="cpu") for x, dt in ((o, wp.vec3), (d, wp.vec3), (reach, float))]
    via_bins, via_tree = wp.zeros((n, 8), dtype=wp.vec4, device="cpu"), wp.zeros((n, 8), dtype=wp.vec4, device="cpu")
    served, ray_bad, ray_served = (wp.zeros(n, dtype=int, device="cpu") for _ in range(3))
    bins = wp.array(rec, dtype=wp.float32, device="cpu") if rec is not None else None
    wp.launch(k, dim=n, device="cpu", inputs=[mesh.id, 0 if bins is None else bins.ptr, tree.wide.ptr, tree.tris.ptr,
                                              *arrays, via_bins, via_tree, served, ray_bad, ray_served])
    assert not ray_bad.numpy().any()
    _bins_against_tree.rays_served = int(ray_served.numpy().sum())
    return via_bins.numpy(), via_tree.numpy(), served.numpy().astype(bool)


@pytest.mark.parametrize("eye", [(0.4, 0.9, 3.4), (-0.3, 0.2, 1.9)])
def test_camera_bins_give_each_lane_the_trees_hit_bit_for_bit(eye):
    """``accel.camera_bins``: camera rays from the bins' origin through the cells' lists of
    triangles get the nearest hit of the packets' traversal bit for bit (t, u, v, face): rays
    aimed exactly at every vertex, edge midpoint and centroid (where the projected boxes and
    the triangles' edges meet cells' borders, and neighbouring triangles tie), at jittered points
    of the view, with open and bounded reaches. Rays from elsewhere or outside the grid are left
    to the tree (0); a near eye sees the mesh overflow the view."""
    v, f, mesh, tree = _bins_mesh()
    o = np.asarray(eye, np.float32)
    fwd = -o.astype(np.float64) + [0.0, 0.05, 0.0]
    tan_y = np.tan(np.radians(50.0) / 2.0)
    tan_x = tan_y * 64 / 48
    rec = accel.camera_bins(tree.tris, o, fwd, (0.0, 1.0, 0.0), tan_x, tan_y, 2.0 * tan_y / 48 / accel.BINS_PER_PIXEL,
                            (v.min(0), v.max(0)))
    assert rec is not None
    tri = v[f]
    rng = np.random.default_rng(5)
    targets = np.concatenate([v, (tri + np.roll(tri, 1, axis=1)).reshape(-1, 3) * np.float32(0.5), tri.mean(1)])
    rng.shuffle(targets)
    w = fwd / np.linalg.norm(fwd)
    u = np.cross(w, [0.0, 1.0, 0.0])
    u /= np.linalg.norm(u)
    up = np.cross(u, w)
    ab = rng.uniform(-1.0, 1.0, (4096, 2)) * [tan_x, tan_y]
    view = w + ab[:, :1] * u + ab[:, 1:] * up
    d = np.concatenate([(targets - o).astype(np.float32), view.astype(np.float32)])
    d = d[:len(d) // 8 * 8]
    reach = np.full(len(d), 3.0e38, np.float32)
    reach[1::3] = np.linalg.norm(d[1::3], axis=1) * 0.97  # (short of the targets: what lies before them)
    reach[2::7] = -1.0  # lanes that take no part
    o_all = np.broadcast_to(o, d.shape).copy()
    n = len(d) // 8
    via_bins, via_tree, served = _bins_against_tree(mesh, tree, rec, o_all.reshape(n, 8, 3), d.reshape(n, 8, 3),
                                                    reach.reshape(n, 8))
    aimed = len(targets) // 8  # (the packets aimed at the mesh: all in view from afar)
    # (the view's rays: the grid is the view cut to the mesh's projected box, or the whole view
    # where the mesh overflows it; of the aimed rays, those in view)
    if eye[2] > 3:
        assert served[:aimed].all() and 0.05 < served[aimed:].mean() < 0.95
    else:
        assert 0.2 < served[:aimed].mean() < 0.9 and served[aimed:].all()
    assert not (via_tree[..., 3] >= 100000).any()  # (the tree took every packet)
    part = served[:, None] & (reach.reshape(n, 8) >= 0)
    got, want = via_bins[part], via_tree[part]
    assert (want[:, 3] >= 0).mean() > 0.5 and (want[:, 3] < 0).any()
    # the same hit, but where two triangles meet the ray at the same t, or within rounding of it
    # (a ray through a vertex or an edge), and rounding put a box's entry past that t: the tree's
    # walk then skipped the nearer one, or the one at the lower leaf that the tie rule prefers
    leaf = {r.tobytes(): k for k, r in enumerate(tree.tris.numpy().reshape(-1, 9))}
    leaf_of = np.array([leaf[r.tobytes()] for r in tri.reshape(-1, 9)] + [-1])
    other = np.any(got.view(np.uint32) != want.view(np.uint32), axis=1)
    assert other.mean() < 0.01
    gt, wt = got[other, 0], want[other, 0]
    assert ((gt < wt) | (gt == wt) & (leaf_of[got[other, 3].astype(int)] < leaf_of[want[other, 3].astype(int)])).all()
    assert (wt - gt <= 4e-7 * wt).all()
    assert not other[np.nonzero(part)[0] >= aimed].any()  # (none among the jittered rays)
    # a packet with a lane from another point, or heading out of the grid, is the tree's
    moved = o_all.reshape(n, 8, 3).copy()
    moved[:, 5, 0] = np.nextafter(moved[:, 5, 0], np.float32(9.0))
    moved_reach = reach.reshape(n, 8).copy()
    moved_reach[:, 5] = 3.0e38
    _, _, served_moved = _bins_against_tree(mesh, tree, rec, moved, d.reshape(n, 8, 3), moved_reach)
    assert not served_moved.any()
    assert _bins_against_tree.rays_served > 0  # (alone, the lanes still at the origin are served)
    moved[:] = np.nextafter(o, np.float32(9.0))
    _bins_against_tree(mesh, tree, rec, moved, d.reshape(n, 8, 3), reach.reshape(n, 8))
    assert _bins_against_tree.rays_served == 0
    away = d.reshape(n, 8, 3).copy()
    away[:, 2] = (-w - 3.0 * u).astype(np.float32)
    away_reach = reach.reshape(n, 8).copy()
    away_reach[:, 2] = 1.0
    _, _, served_away = _bins_against_tree(mesh, tree, rec, o_all.reshape(n, 8, 3), away, away_reach)
    assert not served_away.any()


def test_camera_bins_are_refused_for_triangles_behind_the_eye():
    """An origin inside the mesh's hull (triangles behind or beside it) gets no bins."""
    v, f, mesh, tree = _bins_mesh()
    assert accel.camera_bins(tree.tris, np.zeros(3, np.float32), (0.0, 0.0, -1.0), (0.0, 1.0, 0.0), 0.5, 0.5, 0.01,
                             (v.min(0), v.max(0))) is None


def _bins(renderer):
    return int(renderer.built.data.insts.numpy()["bins"][0])


def test_renders_through_camera_bins_are_the_trees_and_follow_the_view(monkeypatch):
    """A renderer gives a large mesh (``accel.BINS_TRIANGLES``) the camera's bins with the scene
    (``build.DeviceScene.refresh_bins``), and the image is the one the tree gives, bit for bit, for
    a translated instance too. A new camera drops them until its view has been rendered
    ``BINS_AFTER_RENDERS`` times; moved points drop them (their lists would hold the old
    triangles), and the image stays the tree's. A camera with a lens or in motion, an instance that
    moves, turns or scales, or camera rays that start past the eye get none."""
    monkeypatch.setattr(accel, "BINS_TRIANGLES", 1024)
    scene = _balls_scene()
    mesh = dataclasses.replace(scene.shapes[1], transform=warprt.Transform(translate=(0.3, -0.1, -0.2)))
    # one shadow ray per sample, stated: with samples = "auto" a renderer keeps the split its pilot
    # chose through set_mesh_points, where a fresh renderer of the moved points runs its own
    scene = scene.replace(shapes=(scene.shapes[0], mesh), lights=(dataclasses.replace(scene.lights[0], samples=1),))
    r = warprt.Renderer(scene, device="cpu")
    assert _bins(r) != 0
    names = ["depth", "normal", "object_id"]  # (the AOVs' camera rays go one by one: accel.mesh_bins_ray)
    aovs = r.render(spp=2, seed=3, progress=False, aovs=names).aovs
    with_bins, without = _with_and_without(r, "bins", 4)
    assert with_bins.tobytes() == without.tobytes()
    assert float(without[..., 0].std()) > 0.01
    aovs_tree = r.render(spp=2, seed=3, progress=False, aovs=names).aovs
    assert all(aovs[n].tobytes() == aovs_tree[n].tobytes() for n in names) and (aovs["object_id"] == 1).any()
    r.set_camera(dataclasses.replace(scene.camera, eye=(0.9, 1.2, 2.9)))
    assert _bins(r) == 0
    first = r.render(spp=4, seed=3, progress=False).image
    r.render(spp=1, seed=3, progress=False)
    assert _bins(r) == 0
    with_bins = r.render(spp=4, seed=3, progress=False).image  # (the third render of the view: its bins)
    assert _bins(r) != 0 and with_bins.tobytes() == first.tobytes()
    v = np.asarray(mesh.vertices, np.float32)
    r.set_mesh_points(1, v * np.float32(1.1))
    assert _bins(r) == 0
    moved = r.render(spp=4, seed=3, progress=False).image
    fresh = warprt.Renderer(scene.replace(camera=r.scene.camera, shapes=(
        scene.shapes[0], dataclasses.replace(mesh, vertices=v * np.float32(1.1)))), device="cpu")
    rows = fresh.built.data.insts.numpy()
    assert rows["bins"][0] != 0
    rows["bins"] = 0
    fresh.built.data.insts.assign(rows)
    assert fresh.render(spp=4, seed=3, progress=False).image.tobytes() == moved.tobytes() != first.tobytes()
    r.update(scene)  # (a new scene: its bins too after two renders)
    assert _bins(r) == 0
    r.render(spp=1, seed=3, progress=False)
    r.render(spp=1, seed=3, progress=False)
    assert _bins(r) == 0
    r.render(spp=1, seed=3, progress=False)
    assert _bins(r) != 0
    cam = scene.camera
    for name, changed in (
            ("a lens", scene.replace(camera=dataclasses.replace(cam, aperture=0.05, focus_distance=3.0))),
            ("a moving camera", scene.replace(camera=dataclasses.replace(cam, eye_end=(0.1, 1.6, 3.2)))),
            ("t_min", scene.with_settings(t_min=1e-3)),
            ("a moving instance", scene.replace(shapes=(scene.shapes[0], dataclasses.replace(
                mesh, transform_end=warprt.Transform(translate=(0.4, -0.1, -0.2)))))),
            ("a turned instance", scene.replace(shapes=(scene.shapes[0], dataclasses.replace(
                mesh, transform=warprt.Transform(rotate=(0.0, 20.0, 0.0)))))),
            ("a scaled instance", scene.replace(shapes=(scene.shapes[0], dataclasses.replace(
                mesh, transform=warprt.Transform(scale=1.1))))),
            ("an eye inside", scene.replace(camera=dataclasses.replace(cam, eye=(0.3, 0.0, -0.2))))):
        built = DeviceScene(changed, r.device)  # (the scene as a renderer builds it, without its kernel)
        built.refresh_bins()
        assert int(built.data.insts.numpy()["bins"][0]) == 0, name
    monkeypatch.setattr(accel, "BINS_TRIANGLES", 1281)
    assert _bins(warprt.Renderer(scene, device="cpu")) == 0  # (1280 triangles)


def test_camera_bins_hold_a_triangle_whose_corner_lies_on_a_cells_border():
    """Rays aimed exactly at a triangle's corner placed on a border between cells, the triangle
    reaching away from it on one side: the ray's cell, computed in float32 from its direction,
    can fall on the other side of the border than the corner's in float64; the padding of the
    projected boxes keeps the triangle in both cells, so the bins still give the tree's hit."""
    o = np.zeros(3, np.float32)
    fwd, up = np.array([0.31, -0.17, -1.0]), (0.0, 1.0, 0.0)
    tan_x, tan_y, cell = 0.5, 0.4, 0.4 / 48
    view = np.array([[-9.0, -9.0, -6.0], [9.0, -9.0, -6.0], [0.0, 9.0, -6.0]], np.float32)
    probe = wp.array(view.reshape(-1), dtype=wp.float32, device="cpu")
    head = accel.camera_bins(probe, o, fwd, up, tan_x, tan_y, cell, (view.min(0) * 2, view.max(0) * 2))
    U, V, F = (head[k:k + 3].astype(np.float64) for k in (3, 6, 9))
    g0a, g0b, inv = (float(x) for x in head[12:15])
    nx, ny = (int(x) for x in head.view(np.int32)[15:17])
    rng = np.random.default_rng(11)
    n = 512
    m = rng.integers(4, nx - 4, n)
    side = np.where(np.arange(n) % 2 == 0, 1.0, -1.0)  # the triangle to the right of the border, or left
    border = g0a + m / inv
    b = g0b + rng.uniform(4.0, ny - 4.0, n) / inv
    corner = (2.0 * (F + border[:, None] * U + b[:, None] * V)).astype(np.float32)  # (2·d exactly on the ray d)
    reach_out = (corner.astype(np.float64) + side[:, None] * 0.01 * U).astype(np.float32)
    tri = np.stack([corner, reach_out + (0.004 * V).astype(np.float32), reach_out - (0.004 * V).astype(np.float32)], 1)
    v = tri.reshape(-1, 3)
    f = np.arange(3 * n, dtype=np.int32).reshape(n, 3)
    mesh = wp.Mesh(points=wp.array(v, dtype=wp.vec3, device="cpu"),
                   indices=wp.array(f.reshape(-1), dtype=wp.int32, device="cpu"), bvh_leaf_size=1)
    tree = accel.MeshTree(mesh, n)
    rec = accel.camera_bins(tree.tris, o, fwd, up, tan_x, tan_y, cell, (view.min(0) * 2, view.max(0) * 2))
    assert rec is not None and np.array_equal(rec[:15], head[:15]) and np.array_equal(rec[15:17], head[15:17])
    d = corner * np.float32(0.5)
    via_bins, via_tree, served = _bins_against_tree(mesh, tree, rec, np.zeros((n // 8, 8, 3), np.float32),
                                                    d.reshape(-1, 8, 3), np.full((n // 8, 8), 3.0e38, np.float32))
    assert served.all()
    assert (via_tree[..., 3] >= 0).mean() > 0.9  # (the rays meet their corners)
    np.testing.assert_array_equal(via_bins.view(np.uint32), via_tree.view(np.uint32))


def test_camera_bins_keep_to_their_memory_caps(monkeypatch):
    """A grid of more than ``accel.BINS_MAX_CELLS`` cells gets larger cells, and the bins still
    give the tree's hits; projected boxes covering more than ``BINS_MAX_ENTRIES`` cells in all
    get no bins (a large image, or large triangles against the cells)."""
    v, f, mesh, tree = _bins_mesh()
    o = np.asarray((0.4, 0.9, 3.4), np.float32)
    fwd = -o.astype(np.float64)
    args = (tree.tris, o, fwd, (0.0, 1.0, 0.0), 0.6, 0.45, 0.45 / 48, (v.min(0), v.max(0)))
    full = accel.camera_bins(*args)
    nx, ny = full.view(np.int32)[15:17]
    monkeypatch.setattr(accel, "BINS_MAX_CELLS", 400)
    small = accel.camera_bins(*args)
    sx, sy = small.view(np.int32)[15:17]
    assert nx * ny > 4000 and 300 < sx * sy <= 450
    rng = np.random.default_rng(2)
    d = (v[rng.integers(0, len(v), 2048)] + rng.normal(0, 0.05, (2048, 3)).astype(np.float32) - o).astype(np.float32)
    via_bins, via_tree, served = _bins_against_tree(mesh, tree, small, np.broadcast_to(o, d.shape).reshape(-1, 8, 3),
                                                    d.reshape(-1, 8, 3), np.full((256, 8), 3.0e38, np.float32))
    assert served.all() and (via_tree[..., 3] >= 0).mean() > 0.5
    np.testing.assert_array_equal(via_bins[..., 0].view(np.uint32), via_tree[..., 0].view(np.uint32))
    total = (len(full) - full.view(np.int32)[17]) // 2
    monkeypatch.setattr(accel, "BINS_MAX_CELLS", 1 << 22)
    for room, fits in ((nx * ny, False), (nx * ny + total - 1, False), (nx * ny + total, True)):
        monkeypatch.setattr(accel, "BINS_MAX_ENTRIES", room)
        assert (accel.camera_bins(*args) is not None) == fits
        monkeypatch.setattr(accel, "BINS_MAX_ENTRIES", 1 << 23)
        assert (accel.camera_bins(*args, room) is not None) == fits


def test_a_scenes_camera_bins_share_one_budget(monkeypatch):
    """Instances get camera bins in turn while ``accel.BINS_MAX_ENTRIES`` has room for them: with
    room for one of two, the first gets bins and the second renders through its tree, and the
    image is the same."""
    monkeypatch.setattr(accel, "BINS_TRIANGLES", 1024)
    scene = _balls_scene()
    ball = scene.shapes[1]
    scene = scene.replace(shapes=(scene.shapes[0], dataclasses.replace(ball, transform=warprt.Transform(
        translate=(-0.9, 0.0, -0.5), scale=1.0)), dataclasses.replace(ball, transform=warprt.Transform(
        translate=(0.9, 0.0, -0.3)))))
    both = warprt.Renderer(scene, device="cpu")
    sizes = [accel.camera_bins_size(b.numpy()) for b in both.built._bins]
    assert len(sizes) == 2 and (both.built.data.insts.numpy()["bins"][:2] != 0).all()
    monkeypatch.setattr(accel, "BINS_MAX_ENTRIES", sizes[0] + sizes[1] - 1)
    one = warprt.Renderer(scene, device="cpu")
    rows = one.built.data.insts.numpy()["bins"][:2]
    assert rows[0] != 0 and rows[1] == 0
    image = both.render(spp=2, seed=1, progress=False).image
    assert one.render(spp=2, seed=1, progress=False).image.tobytes() == image.tobytes()


def test_a_rectangle_lights_shadow_rays_never_test_its_own_rectangle():
    """An area light's shadow rays end short of a point of its own surface, which a line meets
    nowhere else: a rectangle light's rectangle is never tested for them (``own_rect`` of
    ``trace.transmittance`` and ``trace.occluded_packet``), where rounding once let a ray from a
    point near the light's plane meet it. Segments through a rectangle: passed when it is the
    light's own, blocked when not, by a rectangle that is not the light's in any case; through
    the shapes' loop (one bounded shape) and through the analytic BVH (two), one by one and as a
    packet."""
    from warprt.trace import make_trace

    a = warprt.Rectangle(corner=(-1.0, -1.0, 0.0), edge1=(2.0, 0.0, 0.0), edge2=(0.0, 2.0, 0.0), material="m")
    b = warprt.Rectangle(corner=(-1.0, -1.0, 2.0), edge1=(2.0, 0.0, 0.0), edge2=(0.0, 2.0, 0.0), material="m")
    # segments from z = -1 along +z: through a (to z = 1), through a and b (to z = 3), beside both
    o = np.array([[0.1 * k - 0.3, 0.05 * k, -1.0] for k in range(8)], np.float32)
    o[7] = (3.0, 0.0, -1.0)
    d = np.tile(np.float32([0.0, 0.0, 1.0]), (8, 1))
    t = np.float32([2.0, 2.0, 4.0, 4.0, 2.0, 4.0, 2.0, 4.0])
    camera = warprt.Camera(eye=(0.0, 0.0, 6.0), look_at=(0.0, 0.0, 0.0), width=4, height=4)
    for shapes in ((a, warprt.Plane(point=(0.0, -5.0, 0.0), material="m")), (a, b)):
        scene = warprt.Scene(camera=camera, shapes=shapes, materials={"m": warprt.Material(kd=0.5)})
        built = DeviceScene(scene, "cpu")
        assert (built.data.bvh_root >= 0) == (len([s for s in shapes if isinstance(s, warprt.Rectangle)]) == 2)
        tr = make_trace(built.features)

        @wp.kernel(enable_backward=False, module="unique", module_options=MODULE_OPTIONS)
        def k(scene: SceneData, o: wp.array(dtype=wp.vec3, ndim=2), d: wp.array(dtype=wp.vec3, ndim=2),
              t: wp.array(dtype=float), own: int, alone: wp.array(dtype=float), packet: wp.array(dtype=int)):
            tm = accel.PacketF()
            for l in range(8):
                tm[l] = t[l]
                alone[l] = tr.transmittance(scene, o[0, l], d[0, l], t[l], 0.0, own)[0]
            packet[0] = tr.occluded_packet(scene, 8, 255, _lanes(o, 0, 0), _lanes(o, 0, 1), _lanes(o, 0, 2),
                                           _lanes(d, 0, 0), _lanes(d, 0, 1), _lanes(d, 0, 2), tm, accel.PacketF(),
                                           accel.PacketI(), accel.PacketI(), own, -1)

        args = [wp.array(o[None], dtype=wp.vec3, device="cpu"), wp.array(d[None], dtype=wp.vec3, device="cpu"),
                wp.array(t, dtype=float, device="cpu")]
        through_b = (t > 3.0) if len(shapes) == 2 and isinstance(shapes[1], warprt.Rectangle) else np.zeros(8, bool)
        beside = np.arange(8) == 7
        for own, passed in ((-1, beside), (0, beside | ~through_b), (1, beside)):
            if own == 1 and not through_b.any():
                continue
            alone = wp.zeros(8, dtype=float, device="cpu")
            packet = wp.zeros(1, dtype=int, device="cpu")
            wp.launch(k, dim=1, device="cpu", inputs=[built.data, *args, own, alone, packet])
            np.testing.assert_array_equal(alone.numpy() > 0.0, passed)
            assert int(packet.numpy()[0]) == int(sum(1 << l for l in range(8) if not passed[l])), own


def _buffer_cell(v: np.ndarray, res: int) -> np.ndarray:
    """The light buffer's cell of directions v (n × 3) from the light, as ``accel.light_buffer``
    defines the faces: the largest component's axis (x over y over z where they tie), its sign,
    the two others (in the order after it) over its size, binned in [-1, 1]."""
    av = np.abs(v)
    a = np.where((av[:, 0] >= av[:, 1]) & (av[:, 0] >= av[:, 2]), 0, np.where(av[:, 1] >= av[:, 2], 1, 2))
    m = av[np.arange(len(v)), a]
    face = 2 * a + (v[np.arange(len(v)), a] < 0)
    tu = v[np.arange(len(v)), (a + 1) % 3] / m
    tv = v[np.arange(len(v)), (a + 2) % 3] / m
    col = np.minimum(np.floor((tu + 1.0) * 0.5 * res), res - 1).astype(np.int64)
    row = np.minimum(np.floor((tv + 1.0) * 0.5 * res), res - 1).astype(np.int64)
    return (face * res + row) * res + col


@pytest.mark.parametrize("res", [8, 128])
def test_a_light_buffer_cell_lists_every_box_a_direction_through_it_meets(res):
    """``accel.light_buffer``: the cell of the direction from the light to any point of a box
    lists that box's id (a box in pieces: its pieces' ids, once a cell), for boxes on every side
    of the light, boxes across the planes through it and boxes near it; the cells hold far fewer
    than all the boxes; and its reach is what its error bound allows from the nearest box."""
    rng = np.random.default_rng(5)
    light = np.array([0.3, 2.0, -0.5])
    centres = light + rng.uniform(-4.0, 4.0, (300, 3))
    centres[:20, 1] = light[1]  # across the plane y = light's, and so on
    centres[20:40, 0] = light[0]
    centres[40:50] = light + rng.uniform(-0.3, 0.3, (10, 3))  # near the light
    half = rng.uniform(0.01, 0.4, (300, 3))
    half[:5] = (3.0, 0.02, 0.02)  # long bars
    lo, hi = centres - half, centres + half
    keep = ~((lo <= light) & (hi >= light)).all(axis=1)  # (no box holds the light)
    lo, hi = lo[keep], hi[keep]
    ids = np.arange(len(lo)) // 2  # two boxes a shape
    cells, items, reach = accel.light_buffer(light, lo, hi, ids, res, 1 << 24)
    assert cells.shape == (6 * res * res + 1,) and cells[0] == 0 and cells[-1] == len(items)
    assert (np.diff(cells) >= 0).all()
    for c in range(6 * res * res):  # each cell's ids increasing, each once
        assert (np.diff(items[cells[c]:cells[c + 1]]) > 0).all()
    pts = lo[:, None] + rng.random((len(lo), 200, 3)) * (hi - lo)[:, None]
    corners = np.stack([np.where(np.array(bits)[None], hi, lo) for bits in np.ndindex(2, 2, 2)], 1)
    pts = np.concatenate([pts, corners], 1)
    cell = _buffer_cell((pts - light).reshape(-1, 3), res).reshape(len(lo), -1)
    for b in range(len(lo)):
        for c in np.unique(cell[b]):
            assert ids[b] in items[cells[c]:cells[c + 1]], (b, c)
    assert len(items) < 0.2 * (6 * res * res) * (ids.max() + 1)
    r_near = np.sqrt((np.maximum(np.maximum(lo - light, light - hi), 0.0) ** 2).sum(axis=1)).min()
    pad = accel.LB_PAD * 2.0 / res
    assert reach == pytest.approx((pad * r_near / 3.0 - accel.LB_POS_ERR * 2.0) / (accel.LB_DIR_ERR + accel.LB_POS_ERR))
    assert accel.light_buffer(light, lo, hi, ids, res, len(items) + len(cells)) is not None
    assert accel.light_buffer(light, lo, hi, ids, res, len(items) + len(cells) - 1) is None  # over its room
    holds = np.vstack([lo, light - 0.01]), np.vstack([hi, light + 0.01])
    assert accel.light_buffer(light, *holds, np.arange(len(lo) + 1), res, 1 << 24) is None  # a box holds the light


def test_a_packets_light_cells_are_the_buffers_cells():
    """``geometry.light_cells``: each lane's cell of the light buffer, as the buffer defines them
    (``_buffer_cell`` above), for origins in every direction, on the faces' edges and corners
    (ties between components, signed zeros), within and beyond the reach; the lanes at the light
    or beyond the reach are left out."""
    from warprt.geometry import light_cells

    res, cell0, reach = 16, 1000, 3.0
    light = np.array([0.25, -1.0, 2.0], np.float32)
    rng = np.random.default_rng(8)
    v = rng.normal(size=(400, 3)).astype(np.float32) * rng.uniform(0.1, 2.5, (400, 1)).astype(np.float32)
    ties = np.array([[1, 1, 0.5], [-1, 1, 0.5], [0.5, -1, -1], [1, 0.5, 1], [-1, -1, -1], [1, 1, 1], [0, 0, 1],
                     [0, -1, 0], [-1, 0, 0], [-0.0, 0.0, -2], [0.999, -1, 0.2], [1, -0.999, 1]], np.float32)
    v[:len(ties)] = ties
    v[len(ties)] = 0.0  # at the light
    v[len(ties) + 1:len(ties) + 9] *= 40.0  # beyond the reach
    o = (light + v).astype(np.float32)
    o = np.concatenate([o, np.zeros((-len(o) % 8, 3), np.float32)]).reshape(-1, 8, 3)
    lanes = rng.integers(1, 256, len(o))
    lanes[:2] = 255  # (every tie)

    @wp.kernel(enable_backward=False, module="unique", module_options=MODULE_OPTIONS)
    def k(p: wp.vec3, o: wp.array(dtype=wp.vec3, ndim=2), lanes: wp.array(dtype=int),
          cells: wp.array(dtype=int, ndim=2), masks: wp.array(dtype=int)):
        i = wp.tid()
        c = accel.PacketI()
        masks[i] = light_cells(p, 3.0, 16, 1000, lanes[i], _lanes(o, i, 0), _lanes(o, i, 1), _lanes(o, i, 2), c)
        for l in range(8):
            cells[i, l] = c[l]

    cells = wp.zeros((len(o), 8), dtype=int, device="cpu")
    masks = wp.zeros(len(o), dtype=int, device="cpu")
    wp.launch(k, dim=len(o), device="cpu", inputs=[wp.vec3(*light), wp.array(o, dtype=wp.vec3, device="cpu"),
                                                   wp.array(lanes, dtype=int, device="cpu"), cells, masks])
    rel = (o.reshape(-1, 3) - light).astype(np.float32)  # (the kernel's float32 difference)
    d2 = (rel.astype(np.float64) ** 2).sum(axis=1)
    near = (d2 <= reach * reach) & (np.abs(rel).max(axis=1) > 0)
    lane_on = ((lanes[:, None] >> np.arange(8)) & 1).astype(bool).reshape(-1)
    want = near & lane_on
    got = ((masks.numpy()[:, None] >> np.arange(8)) & 1).astype(bool).reshape(-1)
    np.testing.assert_array_equal(got, want)
    assert want.sum() > 100 and (lane_on & ~near).sum() > 4
    expect = cell0 + _buffer_cell(rel[want].astype(np.float64), res)
    np.testing.assert_array_equal(cells.numpy().reshape(-1)[want], expect)
