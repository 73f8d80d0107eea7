"""Acceleration: warprt's own BVH over the bounded analytic shapes.

A binary tree whose every node holds the boxes of its two children, so that one node load gives
a ray both tests; a child is either another node or one primitive (leaves of one). It is built
on the host by binned SAH, one tree level at a time over all of that level's nodes at once
(numpy), and refitted on the device when shapes move (a batch's worlds: same tree, new boxes).

Why not ``wp.Bvh``: its ray query visits children in a fixed order, whatever the ray's direction,
so a closest-hit search keeps testing boxes behind the hit it already has, and its slab test
uses NaN-aware min/max (a compare and a blend each on the CPU). Here a ray takes the nearer child
first, keeps the farther one on a stack with its entry distance and drops it once a hit is
nearer, and the slab test is plain selects on a direction with no zero components. Both costs
grow with the boxes a ray crosses, so they matter most in scenes of many small shapes.

Node order is breadth first: a node's children always come after it, so a refit walks the nodes
backwards. A forest (one tree per world of a batch) is the trees one after another, every tree
with the same number of nodes (n − 1 for n primitives), so world w's root is w · (n − 1).
"""

from __future__ import annotations

import math
import os
import re
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import warp as wp

from . import fast

BINS = 16  # SAH split candidates per axis and node
SAH_MIN = 4  # nodes over this many primitives split by SAH, smaller ones at the object median
MEDIAN_FROM_LEVEL = 40  # deeper levels split at the median: depth stays below 40 + log2(n)
STACK = 72  # traversal stack entries: tree depth + 1 at most (a node pops one entry, pushes two)
MAX_DEPTH = STACK - 2
# a traversal's stack: node or primitive refs and their entry distances (fixed-length vectors are
# registers and plain offsets; a local wp.zeros array pays index arithmetic on every access)
StackRefs = wp.types.vector(length=STACK, dtype=wp.int32)
StackDist = wp.types.vector(length=STACK, dtype=wp.float32)


@wp.struct
class BvhNode:
    lo0: wp.vec3  # child 0's box
    hi0: wp.vec3
    lo1: wp.vec3  # child 1's box
    hi1: wp.vec3
    c0: int  # >= 0: the node at that index; < 0: primitive -c0 - 1 (a row of SceneData.bvh_prims)
    c1: int


@wp.func(inline=True)
def safe_inverse(d: wp.vec3) -> wp.vec3:
    """1/d with zero components replaced by 1/1e-20 (slab products stay finite: no 0·inf)."""
    x = wp.where(d[0] == 0.0, 1.0e-20, d[0])
    y = wp.where(d[1] == 0.0, 1.0e-20, d[1])
    z = wp.where(d[2] == 0.0, 1.0e-20, d[2])
    return wp.vec3(1.0 / x, 1.0 / y, 1.0 / z)


@wp.func(inline=True)
def lesser(a: float, b: float) -> float:
    return wp.where(a < b, a, b)


@wp.func(inline=True)
def greater(a: float, b: float) -> float:
    return wp.where(a > b, a, b)


@wp.func(inline=True)
def slab(o: wp.vec3, inv_d: wp.vec3, lo: wp.vec3, hi: wp.vec3) -> wp.vec2:
    """(entry, exit) distances of the ray (o, 1/inv_d) through the box: a hit when entry <= exit."""
    a = wp.cw_mul(lo - o, inv_d)
    b = wp.cw_mul(hi - o, inv_d)
    t_in = greater(greater(lesser(a[0], b[0]), lesser(a[1], b[1])), lesser(a[2], b[2]))
    t_out = lesser(lesser(greater(a[0], b[0]), greater(a[1], b[1])), greater(a[2], b[2]))
    return wp.vec2(t_in, t_out)


PACKET = 8  # camera rays of one pixel traced together through the analytic BVH (trace.trace_packet)
PACKET_MISS = 3.0e38  # a child's entry distance when no lane meets it
PacketF = wp.types.vector(length=PACKET, dtype=wp.float32)
PacketI = wp.types.vector(length=PACKET, dtype=wp.int32)
PacketU = wp.types.vector(length=PACKET, dtype=wp.uint32)  # a packet's lanes' pixel keys


# A lane of a packet read or added to in place. Warp reads ``v[k]`` (k not a constant) by copying
# the whole vector first, and after a store to one of its lanes that copy waits for the store
# (a store-to-load forwarding stall, about as long as a division, in every pass of a loop that
# adds to its lanes); these read and write the lane alone.
@wp.func_native("return v[k];")
def lane(v: wp.ref[PacketF], k: int) -> float:
    """v[k], read in place."""
    ...


@wp.func_native("return v[k];")
def lane_i(v: wp.ref[PacketI], k: int) -> int:
    """v[k], read in place."""
    ...


@wp.func_native("v[k] = v[k] + x;")
def lane_add(v: wp.ref[PacketF], k: int, x: float):
    """v[k] = v[k] + x, in place."""
    ...


@wp.func_native("v[k] = v[k] + x;")
def lane_addi(v: wp.ref[PacketI], k: int, x: int):
    """v[k] = v[k] + x, in place."""
    ...


# A lane mask (i8: -1 or 0 a lane) as the bits of an unsigned (lane l: bit l), through a vector of
# bools, which is one mask-register move on AVX-512; ``__builtin_reduce_or(h & {1, 2, 4, ...})``
# compiled to a masked load and three shuffle-and-or steps, on the path from a node's box tests
# to the branch that picks its next node, which a packet's traversal takes at every node.
# Spliced into the snippets that need it.
_BITS8 = r"""
auto bits8 = [](i8 h) -> unsigned {
    typedef bool b8 __attribute__((ext_vector_type(8)));
    const b8 hb = __builtin_convertvector(h, b8);
    unsigned char m;
    __builtin_memcpy(&m, &hb, 1);
    return m;
};
"""


# The least of a clang vector's 8 lanes (none NaN) as packed minimums: ``__builtin_reduce_min``
# keeps fmin's NaN rule, which LLVM expands to a serial chain of 8 scalar minimums, each with its
# NaN check (perf: a fifth of a camera packet's time). Spliced into the snippets that need it.
_LEAST8 = r"""
auto least8 = [](v8 x) -> float {
    typedef float v4 __attribute__((ext_vector_type(4)));
    typedef float v2 __attribute__((ext_vector_type(2)));
    const v4 a = __builtin_shufflevector(x, x, 0, 1, 2, 3), b = __builtin_shufflevector(x, x, 4, 5, 6, 7);
    const v4 m4 = a < b ? a : b;
    const v2 c = __builtin_shufflevector(m4, m4, 0, 1), d = __builtin_shufflevector(m4, m4, 2, 3);
    const v2 m2 = c < d ? c : d;
    return m2[0] < m2[1] ? m2[0] : m2[1];
};
"""


# One node of the analytic BVH against a packet's 8 rays: per child, the least entry distance
# over the lanes whose ray meets the child's box before that lane's nearest hit (``slab`` and the
# scalar traversal's test, lane by lane, the same operations in the same order), PACKET_MISS
# where none does. On the CPU the lanes are clang vectors (the 8 lanes of both boxes in a few
# vector instructions: written as a per-lane loop in Warp's language, LLVM's SLP vectoriser
# packed and unpacked it lane by lane); on CUDA the same tests one lane at a time.
_PACKET_NODE = r"""
const float* nd = (const float*)nodes.data + 14 * ref;  // BvhNode: lo0, hi0, lo1, hi1, c0, c1
wp::vec2 out;
#if defined(__clang__) && !defined(__CUDA_ARCH__)
typedef float v8 __attribute__((ext_vector_type(8)));
@LEAST8@
v8 Ox, Oy, Oz, Ix, Iy, Iz, B;
__builtin_memcpy(&Ox, &ox, 32); __builtin_memcpy(&Oy, &oy, 32); __builtin_memcpy(&Oz, &oz, 32);
__builtin_memcpy(&Ix, &ix, 32); __builtin_memcpy(&Iy, &iy, 32); __builtin_memcpy(&Iz, &iz, 32);
__builtin_memcpy(&B, &best, 32);
for (int c = 0; c < 2; ++c) {
    const float* b = nd + 6 * c;
    const v8 ax = (b[0] - Ox) * Ix, ay = (b[1] - Oy) * Iy, az = (b[2] - Oz) * Iz;
    const v8 bx = (b[3] - Ox) * Ix, by = (b[4] - Oy) * Iy, bz = (b[5] - Oz) * Iz;
    const v8 lx = ax < bx ? ax : bx, ly = ay < by ? ay : by, lz = az < bz ? az : bz;
    const v8 gx = ax > bx ? ax : bx, gy = ay > by ? ay : by, gz = az > bz ? az : bz;
    const v8 lxy = lx > ly ? lx : ly, gxy = gx < gy ? gx : gy;
    const v8 t_in = lxy > lz ? lxy : lz;
    const v8 t_out = gxy < gz ? gxy : gz;
    const v8 e = ((t_in <= t_out) & (t_out >= 0.0f) & (t_in <= B)) ? t_in : (v8)(3.0e38f);
    // the least entry over the lanes: the scalar loop's value (a zero's sign aside, which only
    // comparisons see)
    out[c] = least8(e);
}
#else
for (int c = 0; c < 2; ++c) {
    const float* b = nd + 6 * c;
    float m = 3.0e38f;
    for (int k = 0; k < 8; ++k) {
        const float ax = (b[0] - ox[k]) * ix[k], ay = (b[1] - oy[k]) * iy[k], az = (b[2] - oz[k]) * iz[k];
        const float bx = (b[3] - ox[k]) * ix[k], by = (b[4] - oy[k]) * iy[k], bz = (b[5] - oz[k]) * iz[k];
        const float lx = ax < bx ? ax : bx, ly = ay < by ? ay : by, lz = az < bz ? az : bz;
        const float gx = ax > bx ? ax : bx, gy = ay > by ? ay : by, gz = az > bz ? az : bz;
        const float lxy = lx > ly ? lx : ly, gxy = gx < gy ? gx : gy;
        const float t_in = lxy > lz ? lxy : lz;
        const float t_out = gxy < gz ? gxy : gz;
        if (t_in <= t_out && t_out >= 0.0f && t_in <= best[k] && t_in < m) m = t_in;
    }
    out[c] = m;
}
#endif
return out;
"""


_PACKET_NODE = _PACKET_NODE.replace("@LEAST8@\n", _LEAST8.lstrip("\n"))


@wp.func_native(_PACKET_NODE)
def packet_node(nodes: wp.array(dtype=BvhNode), ref: int, ox: PacketF, oy: PacketF, oz: PacketF,
                ix: PacketF, iy: PacketF, iz: PacketF, best: PacketF) -> wp.vec2:
    """(entry of child 0, entry of child 1) of node ``ref`` over the packet's lanes (see above)."""
    ...


# --- building on the host ----------------------------------------------------------------------


def _areas(lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Half the surface area of boxes (0 for empty ones, whose lo > hi)."""
    e = np.maximum(hi - lo, 0.0)
    return e[..., 0] * e[..., 1] + e[..., 1] * e[..., 2] + e[..., 2] * e[..., 0]


def _local_starts(sizes: np.ndarray) -> np.ndarray:
    return np.concatenate([[0], np.cumsum(sizes)[:-1]]).astype(np.int64)


def _positions(starts: np.ndarray, ends: np.ndarray) -> np.ndarray:
    """The concatenated ranges [start, end)."""
    sizes = ends - starts
    return np.arange(int(sizes.sum())) + np.repeat(starts - _local_starts(sizes), sizes)


def _sah_sides(plo, phi, c, seg_of, cmin, ext, n_seg):
    """Binned SAH over the segments of one level: (right, ok), ``right`` per primitive (the side
    of its segment's best split) and ``ok`` per segment (False: no split separates anything,
    e.g. equal centroids)."""
    m = c.shape[0]
    scale = np.where(ext > 0, BINS / np.where(ext > 0, ext, 1.0), 0.0)
    b = np.clip(((c - cmin[seg_of]) * scale[seg_of]).astype(np.int64), 0, BINS - 1)  # (m, 3)
    key = ((seg_of[:, None] * 3 + np.arange(3)[None, :]) * BINS + b).reshape(-1)
    src = np.repeat(np.arange(m), 3)
    srt = np.argsort(key, kind="stable")
    ks = key[srt]
    first = np.flatnonzero(np.r_[True, ks[1:] != ks[:-1]])
    cells = ks[first]
    total = n_seg * 3 * BINS
    blo = np.full((total, 3), np.inf)
    bhi = np.full((total, 3), -np.inf)
    cnt = np.zeros(total)
    blo[cells] = np.minimum.reduceat(plo[src[srt]], first, axis=0)
    bhi[cells] = np.maximum.reduceat(phi[src[srt]], first, axis=0)
    cnt[cells] = np.diff(np.r_[first, ks.size])
    blo, bhi, cnt = blo.reshape(n_seg, 3, BINS, 3), bhi.reshape(n_seg, 3, BINS, 3), cnt.reshape(n_seg, 3, BINS)
    l_cost = _areas(np.minimum.accumulate(blo, axis=2), np.maximum.accumulate(bhi, axis=2)) * np.cumsum(cnt, axis=2)
    r_lo = np.minimum.accumulate(blo[:, :, ::-1], axis=2)[:, :, ::-1]
    r_hi = np.maximum.accumulate(bhi[:, :, ::-1], axis=2)[:, :, ::-1]
    r_cnt = np.cumsum(cnt[:, :, ::-1], axis=2)[:, :, ::-1]
    r_cost = _areas(r_lo, r_hi) * r_cnt
    cost = l_cost[:, :, :-1] + r_cost[:, :, 1:]  # split after bin k
    cost = np.where((np.cumsum(cnt, axis=2)[:, :, :-1] > 0) & (r_cnt[:, :, 1:] > 0), cost, np.inf)
    flat = cost.reshape(n_seg, -1)
    best = np.argmin(flat, axis=1)
    ok = np.isfinite(flat[np.arange(n_seg), best])
    axis, k = best // (BINS - 1), best % (BINS - 1)
    right = b[np.arange(m), axis[seg_of]] > k[seg_of]
    return right, ok


def build_tree(lo: np.ndarray, hi: np.ndarray):
    """A BVH over n >= 2 boxes (n × 3 each): (order, c0, c1, boxes). ``order`` lists the
    primitives as the leaves reference them (a child ref < 0 is -(its position in order) - 1),
    c0/c1 are the n − 1 nodes' child refs (nodes breadth first: children after parents) and
    ``boxes`` (n − 1, 4, 3) each node's (lo0, hi0, lo1, hi1). Binned SAH, and the object median
    along the longest axis where SAH separates nothing or from level MEDIAN_FROM_LEVEL on."""
    lo = np.asarray(lo, dtype=np.float64)
    hi = np.asarray(hi, dtype=np.float64)
    n = lo.shape[0]
    if n < 2:
        raise ValueError("a BVH needs at least two primitives")
    cen = 0.5 * (lo + hi)
    order = np.arange(n)
    c0 = np.zeros(n - 1, dtype=np.int64)
    c1 = np.zeros(n - 1, dtype=np.int64)
    boxes = np.zeros((n - 1, 4, 3), dtype=np.float64)
    # the level's segments of ``order``: [start, end), each an inner node with the given index
    seg_start, seg_end, seg_node = np.array([0]), np.array([n]), np.array([0])
    next_node, level = 1, 0
    while seg_start.size:
        if level > MAX_DEPTH:  # cannot happen: median splits halve from MEDIAN_FROM_LEVEL on
            raise RuntimeError("BVH deeper than its traversal stack")
        n_seg = seg_start.size
        sizes = seg_end - seg_start
        seg_of = np.repeat(np.arange(n_seg), sizes)
        pos = _positions(seg_start, seg_end)
        prim = order[pos]
        c = cen[prim]
        starts = _local_starts(sizes)
        cmin, cmax = np.minimum.reduceat(c, starts, axis=0), np.maximum.reduceat(c, starts, axis=0)
        ext = cmax - cmin
        right = np.zeros(pos.size, dtype=bool)
        ok = np.zeros(n_seg, dtype=bool)
        big = np.flatnonzero(sizes > SAH_MIN) if level < MEDIAN_FROM_LEVEL else np.zeros(0, np.int64)
        if big.size:  # SAH on the segments worth binning, the median on the others
            sel = np.flatnonzero(np.isin(seg_of, big))
            renum = np.full(n_seg, -1)
            renum[big] = np.arange(big.size)
            r_big, ok_big = _sah_sides(lo[prim[sel]], hi[prim[sel]], c[sel], renum[seg_of[sel]], cmin[big], ext[big],
                                       big.size)
            right[sel] = r_big
            ok[big] = ok_big
        if not ok.all():  # the object median along the longest centroid axis
            idx = np.flatnonzero(~ok[seg_of])
            axis = np.argmax(ext, axis=1)[seg_of[idx]]
            srt = idx[np.lexsort((c[idx, axis], seg_of[idx]))]
            rank = np.arange(srt.size) - np.searchsorted(seg_of[srt], seg_of[srt], side="left")
            right[srt] = rank >= sizes[seg_of[srt]] // 2
        # stable partition of every segment: its left primitives first
        perm = np.argsort(seg_of * 2 + right, kind="stable")
        order[pos] = prim[perm]
        mid = seg_end - np.bincount(seg_of, weights=right, minlength=n_seg).astype(np.int64)
        # the children [start, mid) and [mid, end): one primitive is a leaf, more a new node
        k_start = np.stack([seg_start, mid], axis=1).reshape(-1)
        k_end = np.stack([mid, seg_end], axis=1).reshape(-1)
        k_prims = order[_positions(k_start, k_end)]
        k_first = _local_starts(k_end - k_start)
        klo = np.minimum.reduceat(lo[k_prims], k_first, axis=0)
        khi = np.maximum.reduceat(hi[k_prims], k_first, axis=0)
        inner = (k_end - k_start) >= 2
        ids = next_node + np.cumsum(inner) - 1
        ref = np.where(inner, ids, -k_start - 1).reshape(-1, 2)
        next_node += int(inner.sum())
        c0[seg_node], c1[seg_node] = ref[:, 0], ref[:, 1]
        boxes[seg_node, 0], boxes[seg_node, 1] = klo[0::2], khi[0::2]
        boxes[seg_node, 2], boxes[seg_node, 3] = klo[1::2], khi[1::2]
        seg_start, seg_end, seg_node = k_start[inner], k_end[inner], ids[inner]
        level += 1
    return order, c0, c1, boxes


def tree_depth(c0: np.ndarray, c1: np.ndarray) -> int:
    """Levels of nodes from the root down to the deepest (a check for the traversal stack)."""
    depth = np.zeros(c0.size, dtype=np.int64)
    depth[0] = 1
    for i in range(c0.size):  # breadth first: parents before children
        for c in (c0[i], c1[i]):
            if c >= 0:
                depth[c] = depth[i] + 1
    return int(depth.max())


# A point light's light buffer (Haines and Greenberg's, 1986): a cube of 6 · res² cells around the
# light, each listing the analytic BVH's primitives whose box some direction through the cell
# meets. A shadow ray towards the light can only meet a primitive listed in the cell of its
# origin's direction from the light (``trace.occluded_packet``), so it tests those few instead of
# walking the tree: every answer is the walk's, since each primitive is tested the same way.
LB_RES = 128  # cells along a cube face's side
LB_RECT_PIECES = 64  # a rectangle's boxes in a light buffer: pieces about as long as it is wide, up to this many
LB_PAD = 0.25  # each box's cells padded by this share of a cell (in the face's tangent units)
LB_MAX_ITEMS = 1 << 21  # a scene's buffers hold at most this many cells and (cell, primitive) entries
LB_DIR_ERR = 1.3e-6  # bound on a float32 shadow ray's direction error (unit vector) per unit length
LB_POS_ERR = 3e-7  # and on a float32 position's rounding, relative to its magnitude


def light_buffer(pos, lo: np.ndarray, hi: np.ndarray, ids: np.ndarray, res: int = LB_RES, room: int = LB_MAX_ITEMS):
    """The light buffer of a point light at ``pos`` over boxes ``lo``, ``hi`` (n × 3, padded
    like the BVH's) of the primitives ``ids`` (n: a shape in pieces has a box a piece, each with
    its id, and is listed once a cell): (cells, items, reach), or None where it would hold more
    than ``room`` cells and items together or where no ray could use it.

    Face f looks along axis a = f // 2, positive for even f, its cell (row, column) holding the
    directions v from the light with |v_a| the largest component and (v_b, v_c) / |v_a| in that
    cell of [-1, 1]² (b = (a + 1) % 3, c = (a + 2) % 3): cell index f · res² + row · res + column,
    row along c. ``cells`` (6 · res² + 1) are each cell's first entry in ``items`` (the ids, a
    cell's in increasing order) and the end. A box's cells hold every direction to its points,
    widened by LB_PAD of a cell. ``reach`` is the distance from the light within which a ray's
    origin may use the buffer: a float32 segment's points and their directions from the light
    stray from the exact line by LB_DIR_ERR × its length and LB_POS_ERR × its coordinates, which
    seen from the nearest box (r_near away) must stay within the padding (a face's tangent
    changes at most 3× as fast as the angle)."""
    p = np.asarray(pos, dtype=np.float64)
    lo = np.asarray(lo, dtype=np.float64) - p
    hi = np.asarray(hi, dtype=np.float64) - p
    n = lo.shape[0]
    if n == 0:
        return None
    pad = LB_PAD * 2.0 / res
    r_near = float(np.sqrt((np.maximum(np.maximum(lo, -hi), 0.0) ** 2).sum(axis=1)).min())
    reach = (pad * r_near / 3.0 - LB_POS_ERR * float(np.abs(p).max())) / (LB_DIR_ERR + LB_POS_ERR)
    if not reach > 0.0:
        return None
    cell_ids, box_ids = [], []
    total = 0
    cell = lambda t: np.clip(np.floor((t + 1.0) * 0.5 * res), 0, res - 1).astype(np.int64)  # a tangent's bin
    for f in range(6):
        a, s = f // 2, 1.0 if f % 2 == 0 else -1.0
        b, c = (a + 1) % 3, (a + 2) % 3
        z0 = lo[:, a] if s > 0 else -hi[:, a]
        z1 = hi[:, a] if s > 0 else -lo[:, a]
        on = np.flatnonzero(z1 > 0.0)
        if on.size == 0:
            continue
        z0, z1 = z0[on], z1[on]
        # a box reaching the plane through the light (z0 <= 0): z over (0, z1], so a tangent
        # y / z over [y0 / z1, ∞) where its y > 0, (-∞, y1 / z1] where y < 0, else all
        cross = z0 <= 0.0
        zs = np.where(cross, 1.0, z0)
        ranges = []
        for ax in (b, c):
            l0, l1 = lo[on, ax], hi[on, ax]
            t_lo = np.where(cross, np.where(l0 > 0.0, l0 / z1, -np.inf), np.minimum(l0 / zs, l0 / z1)) - pad
            t_hi = np.where(cross, np.where(l1 < 0.0, l1 / z1, np.inf), np.maximum(l1 / zs, l1 / z1)) + pad
            ranges.append((np.maximum(t_lo, -1.0), np.minimum(t_hi, 1.0)))
        (u0, u1), (v0, v1) = ranges
        seen = (u1 >= -1.0) & (u0 <= 1.0) & (v1 >= -1.0) & (v0 <= 1.0)
        i0, i1, k0, k1 = cell(u0[seen]), cell(u1[seen]), cell(v0[seen]), cell(v1[seen])
        boxes = on[seen]
        nu, nv = i1 - i0 + 1, k1 - k0 + 1
        count = nu * nv
        total += int(count.sum())
        if total > 8 * room:  # (a bound on the work before the pieces' pairs merge)
            return None
        # every (box, cell) pair of the box's rectangle of cells
        rep = np.repeat(np.arange(boxes.size), count)
        local = np.arange(rep.size) - np.repeat(np.cumsum(count) - count, count)
        col = i0[rep] + local % nu[rep]
        row = k0[rep] + local // nu[rep]
        cell_ids.append(f * res * res + row * res + col)
        box_ids.append(boxes[rep])
    if not cell_ids:
        return None
    cell_ids = np.concatenate(cell_ids)
    item = np.asarray(ids, dtype=np.int64)[np.concatenate(box_ids)]
    span = int(item.max()) + 1
    key = np.unique(cell_ids * span + item)  # one entry per (cell, id), sorted
    cell_ids, item = key // span, key % span
    if 6 * res * res + 1 + cell_ids.size > room:
        return None
    cells = np.zeros(6 * res * res + 1, dtype=np.int64)
    np.cumsum(np.bincount(cell_ids, minlength=6 * res * res), out=cells[1:])
    return cells.astype(np.int32), item.astype(np.int32), reach


def forest_nodes(trees, device) -> "wp.array":
    """The nodes of several trees, one after another, as a BvhNode array; tree k's node and
    primitive refs are offset by k · (its node count) and k · (its primitive count)."""
    rows = []
    node_off = prim_off = 0
    for order, c0, c1, boxes in trees:
        n_nodes = c0.size
        rec = np.zeros(n_nodes, dtype=BvhNode.numpy_dtype())
        rec["lo0"], rec["hi0"], rec["lo1"], rec["hi1"] = (boxes[:, k].astype(np.float32) for k in range(4))
        rec["c0"] = np.where(c0 >= 0, c0 + node_off, c0 - prim_off)
        rec["c1"] = np.where(c1 >= 0, c1 + node_off, c1 - prim_off)
        rows.append(rec)
        node_off += n_nodes
        prim_off += order.size
    return wp.array(np.concatenate(rows), dtype=BvhNode, device=device)


@wp.func
def child_box(nodes: wp.array(dtype=BvhNode), lowers: wp.array(dtype=wp.vec3), uppers: wp.array(dtype=wp.vec3),
              c: int):
    """The box of child ref c: its primitive's, or the union of its node's two child boxes."""
    if c < 0:
        return lowers[-c - 1], uppers[-c - 1]
    ch = nodes[c]
    return wp.min(ch.lo0, ch.lo1), wp.max(ch.hi0, ch.hi1)


@wp.kernel(module="warprt_accel", enable_backward=False)
def refit_kernel(nodes: wp.array(dtype=BvhNode), lowers: wp.array(dtype=wp.vec3), uppers: wp.array(dtype=wp.vec3),
                 n_nodes: int):
    """Tree w's boxes (a forest of equal trees) from the boxes of the primitives its leaves
    reference (``lowers``/``uppers`` in leaf order), children before parents."""
    w = wp.tid()
    for k in range(n_nodes):
        i = w * n_nodes + n_nodes - 1 - k
        nd = nodes[i]
        lo0, hi0 = child_box(nodes, lowers, uppers, nd.c0)
        lo1, hi1 = child_box(nodes, lowers, uppers, nd.c1)
        nd.lo0 = lo0
        nd.hi0 = hi0
        nd.lo1 = lo1
        nd.hi1 = hi1
        nodes[i] = nd


# --- meshes: Warp's tree, traversed in native code -----------------------------------------------
#
# A mesh keeps its ``wp.Mesh`` (built with leaves of one triangle: its SAH build and refit are
# Warp's), and on the CPU a copy of that tree in the layout above: every node holds both
# children's boxes, and the triangles' corners are stored in leaf order, so a node costs one load
# and a triangle no index lookups. ``mesh_tree_kernel`` writes the copy from Warp's nodes (O(n),
# a few ms for a mesh of 300k triangles) after every build or refit. The traversal is C++
# (``func_native``): written in Warp's Python language the same algorithm was slower than Warp's
# own query, and the C++ form is faster than it (``mesh_trees`` in ``warprt.fast``). A triangle
# is Woop, Benthin and Wald's watertight test computed as Warp's ``intersect_ray_tri_woop``
# computes it (FMA-compensated edge functions, again in double where one is zero, t, u and v from
# 1/det), with the ray's shear set up once per ray: each triangle's t, u and v are Warp's bit for
# bit. The boxes' slab test takes a margin of 4e-7 (Warp's
# none). The C++ is sensitive to its shape: variants that look equivalent (a loop over a leaf's
# triangles, a ``while (node >= 0)`` loop, the leaf test called from a third place) were slower
# than Warp's own query, so time a change here, before and after it: ``python -m
# benchmarks.ablation --scenes d --only mesh_trees`` (its ratio is Warp's query over this one).
# On CUDA the snippet calls ``wp::mesh_query_ray`` itself (no copy is made there), as it does for
# a tree it cannot take (a mesh of one triangle, a leaf of several) and for a ray whose stack would
# pass 80 entries.
# Every traversal reads a node's children first and prefetches their boxes and children (or a leaf
# child's triangle) while it tests the node's own boxes: on a large mesh, whose tree outgrows the
# caches, a node's first load is otherwise the traversal's hottest instruction (``node_prefetch``).

_TREE_COPY = r"""
const wp::Mesh mesh = wp::mesh_get(mid);
const wp::BVH& bvh = mesh.bvh;
if (i == 0) {
    // the root, or -1 where it is a leaf (a mesh of one triangle: Warp's query takes it)
    const int r = *bvh.root;
    info.data[0] = bvh.node_lowers[r].b ? -1 : r;
}
if (i >= bvh.num_nodes) return 0;
const wp::BVHPackedNodeHalf l = bvh.node_lowers[i], u = bvh.node_uppers[i];
float* N = (float*)nodes;
int* K = (int*)kids;
float* T = (float*)tris;
if (l.b) {
    for (int k = (int)l.i; k < (int)u.i; ++k) {
        const int f = bvh.primitive_indices[k];
        for (int c = 0; c < 3; ++c) {
            const wp::vec3 p = mesh.points[mesh.indices[3 * f + c]];
            T[9 * k + 3 * c + 0] = p[0];
            T[9 * k + 3 * c + 1] = p[1];
            T[9 * k + 3 * c + 2] = p[2];
        }
    }
    return (int)u.i - (int)l.i;
}
const int ch[2] = {(int)l.i, (int)u.i};
for (int c = 0; c < 2; ++c) {
    const wp::BVHPackedNodeHalf cl = bvh.node_lowers[ch[c]], cu = bvh.node_uppers[ch[c]];
    float* b = N + 12 * i + 6 * c;
    b[0] = cl.x; b[1] = cl.y; b[2] = cl.z; b[3] = cu.x; b[4] = cu.y; b[5] = cu.z;
    // a child leaf: -(its position in leaf order) - 1
    K[2 * i + c] = cl.b ? -(int)cl.i - 1 : ch[c];
}
return 0;
"""


@wp.func_native(_TREE_COPY)
def _tree_copy_node(mid: wp.uint64, i: int, nodes: wp.uint64, kids: wp.uint64, tris: wp.uint64,
                    info: wp.array(dtype=wp.int32)) -> int:
    ...


@wp.kernel(module="warprt_accel", enable_backward=False)
def mesh_tree_kernel(mid: wp.uint64, nodes: wp.uint64, kids: wp.uint64, tris: wp.uint64,
                     info: wp.array(dtype=wp.int32)):
    """Node i of the mesh's Warp tree into the copy (``MeshTree``); ``info``: the root, and the
    most triangles in a leaf."""
    i = wp.tid()
    n = _tree_copy_node(mid, i, nodes, kids, tris, info)
    if n > 1:
        wp.atomic_max(info, 1, n)


# The tree copy as a 4-wide tree for the packets (``mesh_tree_packet``, ``mesh_tree_occluded_packet``):
# each wide node holds up to 4 children, taken from the binary tree by opening, from a binary node's
# two children on, the internal child of largest surface area until there are 4 (or only leaves);
# every internal child becomes a wide node of its own, level by level (node 0: the root). A wide
# node is 32 floats: its children's boxes as rows (lo x, lo y, lo z, hi x, hi y, hi z: 4 each),
# then the 4 children as int32 (a wide node's index; a leaf: -(its leaf position) - 1, as the
# binary copy's; WIDE_EMPTY: none), then 4 unused. The boxes are the binary copy's own (so a
# packet tests the same boxes, a level of nodes at a time), gathered by ``wide_boxes_kernel`` after
# every build and refit (``MeshTree.refresh``); a mesh's normal cones, where it has them, are laid
# out the same way (``MeshTree.wide_rows``: 16 floats a node, rows of axis x, y, z and threshold).
# A packet visits about half the nodes it would visit in the binary tree, each visit testing 4
# boxes for its lanes at once (``wide_tree`` in ``warprt.fast``); the collapse takes a fraction of
# a second on the host for a mesh of 300k triangles.
WIDE = 4
WIDE_EMPTY = 0x7FFFFFFF
WIDE_STACK = 96  # a packet's stacked nodes (3 pushed a visit at most; past them the lanes go alone)


def widen(kids: np.ndarray, areas: np.ndarray, root: int) -> tuple[np.ndarray, np.ndarray]:
    """The 4-wide tree (see above) over the binary copy's children ``kids`` (slots, 2) with their
    boxes' areas ``areas`` (slots, 2): (children (n, 4) int32, sources (n, 4) int64: 2 × the binary
    node + the slot each child's box comes from, -1 for none)."""
    kids = np.asarray(kids, np.int64).reshape(-1, 2)
    areas = np.asarray(areas, np.float64).reshape(-1, 2)
    none = np.int64(-(1 << 40))
    frontier = np.array([root], np.int64)
    out_kids, out_src = [], []
    count = 1
    while frontier.size:
        rows = np.arange(frontier.size)
        ref = np.full((frontier.size, WIDE), none)
        src = np.full((frontier.size, WIDE), -1, np.int64)
        area = np.full((frontier.size, WIDE), -1.0)
        ref[:, :2] = kids[frontier]
        src[:, 0], src[:, 1] = 2 * frontier, 2 * frontier + 1
        area[:, :2] = areas[frontier]
        for n in range(2, WIDE):
            # open each node's largest internal child: its first child in its slot, the second in slot n
            cand = np.where(ref[:, :n] >= 0, area[:, :n], -1.0)
            j = cand.argmax(axis=1)
            ok = cand[rows, j] >= 0.0
            r, j = rows[ok], j[ok]
            b = ref[r, j]
            ref[r, n], src[r, n], area[r, n] = kids[b, 1], 2 * b + 1, areas[b, 1]
            ref[r, j], src[r, j], area[r, j] = kids[b, 0], 2 * b, areas[b, 0]
        internal = ref >= 0
        children = ref[internal]
        ref[internal] = count + np.arange(children.size)
        count += children.size
        out_kids.append(np.where(ref == none, WIDE_EMPTY, ref))
        out_src.append(src)
        frontier = children
    return np.concatenate(out_kids).astype(np.int32), np.concatenate(out_src)


@wp.kernel(module="warprt_accel", enable_backward=False)
def wide_boxes_kernel(boxes: wp.array(dtype=wp.float32), src: wp.array(dtype=wp.int32),
                      wide: wp.array(dtype=wp.float32)):
    """Child slot i of the wide tree (node i // 4, slot i % 4): its box from the binary copy's
    child src[i] (``widen``; 6 floats each in ``boxes``) into the node's rows of 4 (none for an
    empty slot). Run after every build and refit, so a kernel rather than numpy's gather, which
    takes several times as long."""
    i = wp.tid()
    s = src[i]
    if s < 0:
        return
    n = i // 4
    c = i - 4 * n
    for k in range(6):
        wide[32 * n + 4 * k + c] = boxes[6 * s + k]


class MeshTree:
    """The CPU copy of a ``wp.Mesh``'s tree and its wide form (see above); ``refresh`` after the
    mesh is refitted."""

    def __init__(self, mesh: "wp.Mesh", n_faces: int):
        dev = mesh.device
        self.mesh = mesh
        slots = max(2 * n_faces - 1, 1)  # Warp's node indices for n leaves of one triangle
        self.nodes = wp.zeros(12 * slots, dtype=wp.float32, device=dev)
        self.kids = wp.zeros(2 * slots, dtype=wp.int32, device=dev)
        self.tris = wp.zeros(9 * n_faces, dtype=wp.float32, device=dev)
        self._info = wp.zeros(2, dtype=wp.int32, device=dev)  # the root, the largest leaf
        self.slots = slots
        self.n_faces = n_faces
        self.balls: wp.array | None = None  # interior balls (``interior_balls``), set by ``find_balls``
        self.escape: wp.array | None = None  # escape horizons (``escape_horizons``), set by ``find_balls``
        self.frames: wp.array | None = None  # their sectors' frames (``escape_frames``), where found
        self.cones: wp.array | None = None  # normal cones (``normal_cones``), set by ``find_balls``
        self.wide: wp.array | None = None  # the 4-wide tree (``widen``) of a usable tree
        self.wide_cones: wp.array | None = None  # its normal cones
        self._wide_src: wp.array | None = None  # ``widen``'s sources, one a child slot
        self.found_without = frozenset()  # the mechanisms find_balls left out (``warprt.fast``)
        self.refresh()

    def find_balls(self, points: np.ndarray, faces: np.ndarray, off: frozenset = frozenset()) -> None:
        """Find the mesh's interior balls, escape horizons and normal cones (None where it has
        none, or where ``off`` switches them off: ``warprt.fast``)."""
        self.found_without = off & _FOUND  # (what was left out: build.DeviceScene finds them again for others)
        edges = edge_keys(faces)
        blocks = None
        if "interior_balls" not in off:
            with fast.timed("interior_balls"):
                blocks = interior_balls(self.mesh, points, faces, edges)
        self.balls = None if blocks is None else wp.array(blocks.reshape(-1), dtype=wp.float32,
                                                          device=self.mesh.device)
        h = None
        bounds = "escape_horizons" not in off and horizon_bounds_found(self, len(faces))
        if "escaping_faces" not in off:
            h = escape_horizons(self, points, faces, edges, bounds=bounds)
        self.escape = None if h is None else wp.array(h.reshape(-1), dtype=wp.uint32, device=self.mesh.device)
        # (the frames where the bounds were found: the escaping faces alone have every sector alike)
        self.frames = None if h is None or not bounds else wp.array(
            escape_frames(h[:, :3].copy().view(np.float32)).reshape(-1), dtype=wp.float32, device=self.mesh.device)
        c = None
        if "normal_cones" not in off:
            with fast.timed("normal_cones"):
                c = normal_cones(self, points, faces, edges)
        self.cones = None if c is None else wp.array(c.reshape(-1), dtype=wp.float32, device=self.mesh.device)
        self.wide_cones = None if c is None or self.wide is None else wp.array(
            self.wide_rows(c.reshape(-1, 4)).reshape(-1), dtype=wp.float32, device=self.mesh.device)

    def wide_rows(self, values: np.ndarray) -> np.ndarray:
        """Values of the binary copy's children ((2 × slots, k): node i's child c in row 2i + c) in
        the wide tree's layout: (wide nodes, 4k), each value a row of the node's 4 children."""
        src = self._wide_src.numpy().reshape(-1, WIDE)
        g = np.where((src >= 0)[..., None], values[np.maximum(src, 0)], 0.0).astype(np.float32)
        return g.transpose(0, 2, 1).reshape(len(src), -1)

    def refresh(self) -> None:
        wp.launch(mesh_tree_kernel, dim=self.slots, device=self.mesh.device,
                  inputs=[self.mesh.id, self.nodes.ptr, self.kids.ptr, self.tris.ptr, self._info])
        root, largest_leaf = (int(x) for x in self._info.numpy())
        self.root = root
        # Warp's builder keeps to leaves of one triangle unless triangles cannot be told apart
        # (equal centroids); a tree with a larger leaf, or a leaf for a root, is not used:
        # Warp's query serves it
        self.usable = largest_leaf <= 1 and root >= 0
        if self.usable:
            if self.wide is None:  # (a refit keeps the topology: only the boxes change)
                boxes = self.nodes.numpy().reshape(-1, 6)
                ext = np.maximum(boxes[:, 3:] - boxes[:, :3], 0.0)
                areas = ext[:, 0] * ext[:, 1] + ext[:, 1] * ext[:, 2] + ext[:, 2] * ext[:, 0]
                kids, src = widen(self.kids.numpy(), areas, root)
                w = np.zeros((len(kids), 32), np.float32)
                w[:, 24:28] = kids.view(np.float32)
                self.wide = wp.array(w.reshape(-1), dtype=wp.float32, device=self.mesh.device)
                self._wide_src = wp.array(src.reshape(-1).astype(np.int32), dtype=wp.int32, device=self.mesh.device)
            src, dev = self._wide_src, self.mesh.device
            wp.launch(wide_boxes_kernel, dim=src.shape[0], device=dev, inputs=[self.nodes, src, self.wide])

    def record(self) -> dict:
        """The instance record's fields for this tree."""
        if not self.usable:
            return dict(NO_TREE)
        return dict(tree_nodes=self.nodes.ptr, tree_kids=self.kids.ptr, tree_tris=self.tris.ptr, tree_root=self.root,
                    wide=self.wide.ptr, balls=0, n_balls=0, escape=0 if self.escape is None else self.escape.ptr,
                    frames=0 if self.frames is None else self.frames.ptr, prefetch=1,
                    cones=0, wide_cones=0, shadow_packets=int(self.n_faces >= SHADOW_PACKET_TRIANGLES), bins=0)

    def ball_fields(self) -> dict:
        """The instance record's fields for shadow rays from outside the solid: its interior balls
        and normal cones (none where the mesh has none)."""
        cones = 0 if self.cones is None or not self.usable else self.cones.ptr
        wide_cones = 0 if self.wide_cones is None or not self.usable else self.wide_cones.ptr
        if self.balls is None or not self.usable:
            return dict(balls=0, n_balls=0, cones=cones, wide_cones=wide_cones)
        return dict(balls=self.balls.ptr, n_balls=self.balls.shape[0] // 4, cones=cones, wide_cones=wide_cones)


# the mechanisms ``MeshTree.find_balls`` may leave out (``warprt.fast``)
_FOUND = frozenset(("interior_balls", "escaping_faces", "escape_horizons", "normal_cones"))

NO_TREE = dict(tree_nodes=0, tree_kids=0, tree_tris=0, tree_root=0, wide=0, balls=0, n_balls=0, escape=0, frames=0,
               cones=0, wide_cones=0, shadow_packets=0, bins=0, prefetch=0)

# the hit as five floats: t (-1: none), u, v, and the face index as face // 4096 and face % 4096
# (each exact in a float32 for any face count Warp can index)
MeshRayHit = wp.types.vector(length=5, dtype=wp.float32)

# Woop, Benthin and Wald's watertight test of the triangle at leaf position k, as
# wp::intersect_ray_tri_woop computes it once the ray's shear (kx, ky, kz, Sx, Sy, Sz and the
# origin's sheared coordinates okx, oky, okz) is set: leaves tt, U, V and rcp (a miss returns)
_WOOP = r"""
        const float* t = TR + 9 * k;
        const float Ax0 = t[kx] - okx, Ay0 = t[ky] - oky, Az0 = t[kz] - okz;
        const float Bx0 = t[3 + kx] - okx, By0 = t[3 + ky] - oky, Bz0 = t[3 + kz] - okz;
        const float Cx0 = t[6 + kx] - okx, Cy0 = t[6 + ky] - oky, Cz0 = t[6 + kz] - okz;
        const float Ax = Ax0 - Sx * Az0, Ay = Ay0 - Sy * Az0;
        const float Bx = Bx0 - Sx * Bz0, By = By0 - Sy * Bz0;
        const float Cx = Cx0 - Sx * Cz0, Cy = Cy0 - Sy * Cz0;
        float U = wp::diff_product(Cx, By, Cy, Bx), V = wp::diff_product(Ax, Cy, Ay, Cx), W = wp::diff_product(Bx, Ay, By, Ax);
        if (U == 0.0f || V == 0.0f || W == 0.0f) {
            U = (float)((double)Cx * By - (double)Cy * Bx);
            V = (float)((double)Ax * Cy - (double)Ay * Cx);
            W = (float)((double)Bx * Ay - (double)By * Ax);
        }
        if ((U < 0.0f || V < 0.0f || W < 0.0f) && (U > 0.0f || V > 0.0f || W > 0.0f)) return;
        const float det = U + V + W;
        if (det == 0.0f) return;
        const float T = U * (Sz * Az0) + V * (Sz * Bz0) + W * (Sz * Cz0);
        if (wp::xorf(T, wp::sign_mask(det)) < 0.0f) return;
        const float rcp = 1.0f / det;
        const float tt = T * rcp;
"""

# the tree copy's arrays (N, C, TR) and the ray's origin, direction and 1/d (ox..., dx..., ix...);
# the ray's shear (kx, ky, kz, Sx, Sy, Sz and the origin's sheared coordinates okx, oky, okz) for
# ``_WOOP``, from the ray; and the slab tests of both children of the
# tree copy's ``node`` (entry n0 / n1, exit f0 / f1, children k0 / k1) from its 1/d (ix, iy, iz):
# the scalar traversals' shared pieces, spliced into each as text
_RAY = r"""
    const float* N = (const float*)nodes;
    const int* C = (const int*)kids;
    const float* TR = (const float*)tris;
    const float ox = o[0], oy = o[1], oz = o[2], dx = d[0], dy = d[1], dz = d[2];
    const float ix = 1.0f / (dx == 0.0f ? 1e-20f : dx), iy = 1.0f / (dy == 0.0f ? 1e-20f : dy),
                iz = 1.0f / (dz == 0.0f ? 1e-20f : dz);
"""
_SHEAR = r"""
    int kz = fabsf(dx) > fabsf(dy) ? (fabsf(dx) > fabsf(dz) ? 0 : 2) : (fabsf(dy) > fabsf(dz) ? 1 : 2);
    int kx = kz == 2 ? 0 : kz + 1, ky = kx == 2 ? 0 : kx + 1;
    const float dk[3] = {dx, dy, dz};
    if (dk[kz] < 0.0f) { int tmp = kx; kx = ky; ky = tmp; }
    const float Sx = dk[kx] / dk[kz], Sy = dk[ky] / dk[kz], Sz = 1.0f / dk[kz];
    const float ok[3] = {ox, oy, oz};
    const float okx = ok[kx], oky = ok[ky], okz = ok[kz];
"""
_PREFETCH = r"""
        // the children's data fetched while this node's boxes are tested (children k0, k1 of node)
        if (k0 >= 0) { __builtin_prefetch(N + 12 * k0); __builtin_prefetch(C + 2 * k0); }
        else { __builtin_prefetch(TR + 9 * (-k0 - 1)); __builtin_prefetch(TR + 9 * (-k0 - 1) + 8); }
        if (k1 >= 0) { __builtin_prefetch(N + 12 * k1); __builtin_prefetch(C + 2 * k1); }
        else { __builtin_prefetch(TR + 9 * (-k1 - 1)); __builtin_prefetch(TR + 9 * (-k1 - 1) + 8); }
"""
_NODE_BOXES = r"""
        const float* nd = N + 12 * node;
        int k0 = C[2 * node], k1 = C[2 * node + 1];
@PREFETCH@
        float a0 = (nd[0] - ox) * ix, b0 = (nd[3] - ox) * ix;
        float a1 = (nd[1] - oy) * iy, b1 = (nd[4] - oy) * iy;
        float a2 = (nd[2] - oz) * iz, b2 = (nd[5] - oz) * iz;
        float n0 = fmaxf(fmaxf(fminf(a0, b0), fminf(a1, b1)), fmaxf(fminf(a2, b2), 0.0f));
        float f0 = fminf(fminf(fmaxf(a0, b0), fmaxf(a1, b1)), fmaxf(a2, b2));
        float c0x = (nd[6] - ox) * ix, d0x = (nd[9] - ox) * ix;
        float c1y = (nd[7] - oy) * iy, d1y = (nd[10] - oy) * iy;
        float c2z = (nd[8] - oz) * iz, d2z = (nd[11] - oz) * iz;
        float n1 = fmaxf(fmaxf(fminf(c0x, d0x), fminf(c1y, d1y)), fmaxf(fminf(c2z, d2z), 0.0f));
        float f1 = fminf(fminf(fmaxf(c0x, d0x), fmaxf(c1y, d1y)), fmaxf(c2z, d2z));
"""


# a packet's lane l: its ray's shear (``_SHEAR``'s, kept per lane in KX..OKZ) from the packet's
# vectors Ox..Dz; and in ``tri_test``, lane l's shear for ``_WOOP``
_LANE_SHEAR = r"""
        const float dxl = Dx[l], dyl = Dy[l], dzl = Dz[l];
        int kz = fabsf(dxl) > fabsf(dyl) ? (fabsf(dxl) > fabsf(dzl) ? 0 : 2) : (fabsf(dyl) > fabsf(dzl) ? 1 : 2);
        int kx = kz == 2 ? 0 : kz + 1, ky = kx == 2 ? 0 : kx + 1;
        const float dk[3] = {dxl, dyl, dzl};
        if (dk[kz] < 0.0f) { int tmp = kx; kx = ky; ky = tmp; }
        KX[l] = kx; KY[l] = ky; KZ[l] = kz;
        SX[l] = dk[kx] / dk[kz]; SY[l] = dk[ky] / dk[kz]; SZ[l] = 1.0f / dk[kz];
        const float okk[3] = {Ox[l], Oy[l], Oz[l]};
        OKX[l] = okk[kx]; OKY[l] = okk[ky]; OKZ[l] = okk[kz];
"""
# the packet's rays as vectors from its lanes (ox..dz, t_max: Ox..Dz, Bv) and their 1/d (Ix, Iy, Iz)
_LANE_RAYS = r"""
    v8 Ox, Oy, Oz, Dx, Dy, Dz, Bv;
    __builtin_memcpy(&Ox, &ox, 32); __builtin_memcpy(&Oy, &oy, 32); __builtin_memcpy(&Oz, &oz, 32);
    __builtin_memcpy(&Dx, &dx, 32); __builtin_memcpy(&Dy, &dy, 32); __builtin_memcpy(&Dz, &dz, 32);
    __builtin_memcpy(&Bv, &t_max, 32);
    const v8 Ix = 1.0f / (Dx == 0.0f ? (v8)(1e-20f) : Dx), Iy = 1.0f / (Dy == 0.0f ? (v8)(1e-20f) : Dy),
             Iz = 1.0f / (Dz == 0.0f ? (v8)(1e-20f) : Dz);
"""
_LANE_TRI = r"""
        const int kx = KX[l], ky = KY[l], kz = KZ[l];
        const float Sx = SX[l], Sy = SY[l], Sz = SZ[l], okx = OKX[l], oky = OKY[l], okz = OKZ[l];
"""


# A wide node's visit for a packet (``widen``'s layout, at W + 32 × node): its children read, their
# data prefetched (a wide node's two cache lines, a leaf's triangle), and each child's box tested
# for the 8 lanes with their 1/d (Ix, Iy, Iz) by the scalar traversal's slab test with its margin
# (entry e[c]: the least over the lanes that meet it; lane bits m[c]; 0 for an empty slot).
# ``_WIDE_VISIT_CONES`` also prefetches an inner child's normal cones (rows at CN + 16 × node) and
# drops the lanes whose direction a child's cone shows cannot cross its triangles on the way in.
# ``_WIDE_LEAVES``: each leaf child's triangle tested (``tri_test``) for the lanes that meet its
# box, its bits then cleared (``changed``: a leaf was tested). ``_WIDE_ORDER``: the cnt children
# in ch / ce (their entries) sorted farthest first (insertion; the nearest is last).
_WIDE_VISIT = r"""
        const float* nd = W + 32 * node;
        int kc[4];
        __builtin_memcpy(kc, nd + 24, 16);
        for (int c = 0; c < 4; ++c) {
            const int k = kc[c];
            if (k >= 0) {
                if (k != WIDE_EMPTY) {
                    __builtin_prefetch(W + 32 * k); __builtin_prefetch(W + 32 * k + 16);
@CONE_PREFETCH@
                }
            } else { __builtin_prefetch(TR + 9 * (-k - 1)); __builtin_prefetch(TR + 9 * (-k - 1) + 8); }
        }
        float e[4];
        unsigned m[4];
        for (int c = 0; c < 4; ++c) {
            const v8 ax = (nd[c] - Ox) * Ix, ay = (nd[4 + c] - Oy) * Iy, az = (nd[8 + c] - Oz) * Iz;
            const v8 bx = (nd[12 + c] - Ox) * Ix, by = (nd[16 + c] - Oy) * Iy, bz = (nd[20 + c] - Oz) * Iz;
            const v8 lx = ax < bx ? ax : bx, ly = ay < by ? ay : by, lz = az < bz ? az : bz;
            const v8 gx = ax > bx ? ax : bx, gy = ay > by ? ay : by, gz = az > bz ? az : bz;
            const v8 l0 = lx > ly ? lx : ly, lz0 = lz > 0.0f ? lz : (v8)(0.0f);
            const v8 tn = l0 > lz0 ? l0 : lz0;
            const v8 g0 = gx < gy ? gx : gy;
            const v8 tf = g0 < gz ? g0 : gz;
            i8 h = (tn <= tf * 1.0000004f) & (tn <= Bv);
@CONE@
            e[c] = least8(h ? tn : (v8)(3.0e38f));  // (entries are >= +0, never NaN)
            m[c] = kc[c] == WIDE_EMPTY ? 0u : bits8(h);
        }
""".replace("WIDE_EMPTY", str(WIDE_EMPTY))
_WIDE_VISIT_CONES = _WIDE_VISIT.replace("@CONE_PREFETCH@",
                                        "                    if (CN != nullptr) __builtin_prefetch(CN + 16 * k);")
_WIDE_VISIT_CONES = _WIDE_VISIT_CONES.replace("@CONE@\n", r"""
            if (CN != nullptr) {
                const float* cc = CN + 16 * node;
                h = h & ((Ux * cc[c] + Uy * cc[4 + c] + Uz * cc[8 + c]) < cc[12 + c]);
            }
""".lstrip("\n"))
_WIDE_VISIT = _WIDE_VISIT.replace("@CONE_PREFETCH@\n", "").replace("@CONE@\n", "")
_WIDE_LEAVES = r"""
        bool changed = false;
        for (int c = 0; c < 4; ++c) {
            if (m[c] && kc[c] < 0) {
                for (unsigned q = m[c]; q; q &= q - 1) tri_test(-kc[c] - 1, __builtin_ctz(q));
                m[c] = 0; changed = true;
            }
        }
"""
_WIDE_ORDER = r"""
            for (int a = 1; a < cnt; ++a) {
                const int kk = ch[a];
                const float ee = ce[a];
                int b = a - 1;
                while (b >= 0 && ce[b] < ee) { ch[b + 1] = ch[b]; ce[b + 1] = ce[b]; --b; }
                ch[b + 1] = kk; ce[b + 1] = ee;
            }
"""


def _no_prefetch(text: str) -> str:
    """``text`` without its prefetches (``warprt.fast``: node_prefetch switched off)."""
    return re.sub(r"__builtin_prefetch\([^;]*\)", "(void)0", text)


def _splice(snippet: str) -> str:
    """A traversal snippet with its shared pieces (``_WOOP``, ``_RAY``, ``_SHEAR``, ``_NODE_BOXES``,
    ``_PREFETCH``, ``_LEAST8``, ``_BITS8``, ``_LANE_RAYS``, ``_LANE_SHEAR``, ``_LANE_TRI``,
    ``_WIDE_VISIT``, ``_WIDE_VISIT_CONES``, ``_WIDE_LEAVES``, ``_WIDE_ORDER``) in place; the node
    prefetches (``_PREFETCH``, the wide visits') only while node_prefetch is on (``warprt.fast``)."""
    keep = not fast.import_off("node_prefetch")
    for name, text in (("WOOP", _WOOP), ("RAY", _RAY), ("SHEAR", _SHEAR), ("NODE_BOXES", _NODE_BOXES),
                       ("PREFETCH", _PREFETCH), ("LEAST8", _LEAST8), ("BITS8", _BITS8),
                       ("LANE_SHEAR", _LANE_SHEAR), ("LANE_TRI", _LANE_TRI), ("LANE_RAYS", _LANE_RAYS),
                       ("WIDE_VISIT", _WIDE_VISIT), ("WIDE_VISIT_CONES", _WIDE_VISIT_CONES),
                       ("WIDE_LEAVES", _WIDE_LEAVES), ("WIDE_ORDER", _WIDE_ORDER)):
        if not keep and name in ("PREFETCH", "WIDE_VISIT", "WIDE_VISIT_CONES"):
            text = _no_prefetch(text)
        snippet = snippet.replace(f"@{name}@\n", text.lstrip("\n"))
    return snippet


_TREE_RAY = _splice(r"""
wp::vec_t<5, wp::float32> out;
out[0] = -1.0f;
#if !defined(__CUDA_ARCH__)
if (nodes != 0) {
@RAY@
    float best = t_max, bu = 0.0f, bv = 0.0f;
    int hitp = -1;
    auto fminf = [](float a, float b) { return a < b ? a : b; };
    auto fmaxf = [](float a, float b) { return a > b ? a : b; };
    int sn[80];
    float st[80];
    int sp = 0;
    int node = root;
    // the ray's shear (Woop, Benthin and Wald), set up once per ray
@SHEAR@
    // the watertight test, as wp::intersect_ray_tri_woop computes it once the shear is set
    auto tri_test = [&](int k) {
@WOOP@
        // an exact tie goes to the lower leaf, whatever the order the leaves are met in
        if (tt >= 0.0f && (tt < best || (tt == best && k < hitp))) { best = tt; bu = U * rcp; bv = V * rcp; hitp = k; }
    };
    while (true) {
@NODE_BOXES@
        bool h0 = n0 <= f0 * 1.0000004f && n0 <= best;
        bool h1 = n1 <= f1 * 1.0000004f && n1 <= best;
        if (h0 && k0 < 0) { tri_test(-k0 - 1); h0 = false; }
        if (h1 && k1 < 0) { tri_test(-k1 - 1); h1 = false; }
        h0 = h0 && n0 <= best;
        h1 = h1 && n1 <= best;
        if (h0 && h1) {
            if (sp == 80) { sp = -1; break; }  // a tree this deep: Warp's query below takes the ray
            bool first0 = n0 <= n1;
            sn[sp] = first0 ? k1 : k0;
            st[sp] = first0 ? n1 : n0;
            ++sp;
            node = first0 ? k0 : k1;
            continue;
        }
        if (h0) { node = k0; continue; }
        if (h1) { node = k1; continue; }
        bool found = false;
        while (sp > 0) {
            --sp;
            if (st[sp] <= best) { node = sn[sp]; found = true; break; }
        }
        if (!found) break;
    }
    if (sp < 0) hitp = -2;
    else if (hitp >= 0) {
        const int face = wp::mesh_get(mid).bvh.primitive_indices[hitp];
        out[0] = best; out[1] = bu; out[2] = bv; out[3] = (float)(face >> 12); out[4] = (float)(face & 4095);
    }
    if (hitp != -2) return out;
}
#endif
// no copy (CUDA, a mesh of one triangle, or leaves of several) or a stack too short: Warp's query
float t, u, v, sign;
wp::vec3 n;
int face;
if (wp::mesh_query_ray(mid, o, d, t_max, t, u, v, sign, n, face)) {
    out[0] = t; out[1] = u; out[2] = v; out[3] = (float)(face >> 12); out[4] = (float)(face & 4095);
}
return out;
""")


@wp.func_native(_TREE_RAY)
def mesh_tree_ray(mid: wp.uint64, nodes: wp.uint64, kids: wp.uint64, tris: wp.uint64, root: int,
                  o: wp.vec3, d: wp.vec3, t_max: float) -> MeshRayHit:
    """The nearest triangle of mesh ``mid`` along (o, d) in [0, t_max] (see above)."""
    ...



# Whether any triangle blocks the segment (o, o + t_max·d) (object space): 1 if one does, 0 if
# none, -1 where this function cannot answer (CUDA, no tree copy, or past 80 stacked nodes: the
# caller asks ``mesh_first_hit`` instead). A shadow ray needs no nearest hit, so the traversal
# stops at the first triangle it meets at 0 < t < t_max that the ray does not leave (the test of
# ``trace.leaves_face``, computed here from the leaf-ordered corners exactly as there: Warp's
# normalize(cross(q - p, r - p)) and the same products). The answer is the one the nearest-hit
# loop gives (an occluder exists or not), without ordering the hits or stepping over the face the
# ray leaves, so it costs less than ``mesh_tree_ray`` with that check, and the more of the shadow
# rays are blocked the more it saves. With a closed mesh's normal cones
# (``normal_cones``, below; 0: none) it skips the children whose every triangle the ray leaves.
_TREE_OCCLUDED = _splice(r"""
#if !defined(__CUDA_ARCH__)
if (nodes != 0) {
@RAY@
    auto fminf = [](float a, float b) { return a < b ? a : b; };
    auto fmaxf = [](float a, float b) { return a > b ? a : b; };
    int sn[80];
    int sp = 0;
    int node = root;
    bool blocked = false;
    // the normal cones (``normal_cones``; 0: none) and the ray's unit direction for them
    const float* CN = (const float*)cones;
    const float dl = 1.0f / sqrtf(dx * dx + dy * dy + dz * dz);
    const float ux = dx * dl, uy = dy * dl, uz = dz * dl;
@SHEAR@
    auto tri_test = [&](int k) {
@WOOP@
        if (tt > 0.0f && tt < t_max) {
            const wp::vec3 p(t[0], t[1], t[2]), q(t[3], t[4], t[5]), r(t[6], t[7], t[8]);
            const wp::vec3 n = wp::normalize(wp::cross(q - p, r - p));
            if (!(wp::dot(n, o - p) * wp::dot(n, d) >= 0.0f)) blocked = true;  // not a face it leaves
        }
    };
    while (true) {
@NODE_BOXES@
        bool h0 = n0 <= f0 * 1.0000004f && n0 <= t_max;
        bool h1 = n1 <= f1 * 1.0000004f && n1 <= t_max;
        if (CN != nullptr) {  // a child whose every triangle the ray leaves is skipped
            const float* c = CN + 8 * node;
            h0 = h0 && ux * c[0] + uy * c[1] + uz * c[2] < c[3];
            h1 = h1 && ux * c[4] + uy * c[5] + uz * c[6] < c[7];
        }
        if (h0 && k0 < 0) { tri_test(-k0 - 1); h0 = false; }
        if (h1 && k1 < 0) { tri_test(-k1 - 1); h1 = false; }
        if (blocked) return 1;
        if (h0 && h1) {
            if (sp == 80) return -1;  // a tree this deep: the nearest-hit loop takes the ray
            const bool first0 = n0 <= n1;
            sn[sp++] = first0 ? k1 : k0;
            node = first0 ? k0 : k1;
            continue;
        }
        if (h0) { node = k0; continue; }
        if (h1) { node = k1; continue; }
        if (sp == 0) return 0;
        node = sn[--sp];
    }
}
#endif
return -1;
""")


@wp.func_native(_TREE_OCCLUDED)
def mesh_tree_occluded(nodes: wp.uint64, kids: wp.uint64, tris: wp.uint64, root: int, cones: wp.uint64,
                       o: wp.vec3, d: wp.vec3, t_max: float) -> int:
    """1 when a triangle blocks (o, o + t_max·d), 0 when none does, -1 to ask the nearest-hit
    loop (see above); ``cones``: the mesh's normal cones where both ends lie outside its solid,
    else 0."""
    ...

# ``mesh_tree_occluded`` for up to 8 shadow rays at once (a camera packet's lanes' light samples,
# ``trace.occluded_packet``): the tree copy's traversal with the 8 lanes' slab tests for both
# children as clang vectors (each lane's test the scalar one), a node opened while any live lane
# meets a child (and, with normal cones, may cross a triangle of it on the way in), each leaf's
# triangle tested for those lanes with each lane's shear (``_WOOP``) and ``leaves_face``'s check,
# and a lane retired at its first occluder. Every lane's answer is the one it gets alone (any-hit:
# an occluder exists or not, in whatever order the leaves are met). The lanes share each node's
# loads, and share more of the nodes with the lanes' light points in one quarter of the light
# (``sampling.sobol_split_index``), where their rays diverge less (``mesh_shadow_packets`` in
# ``warprt.fast``; ``python -m benchmarks.ablation`` times it switched off). On the smallest
# meshes, whose traversals are a few nodes, the
# lanes' set-up would cost more than it saves, so the renderer takes it for meshes of
# SHADOW_PACKET_TRIANGLES or more (``MeshTree.record``'s shadow_packets).
SHADOW_PACKET_TRIANGLES = 1024
SHADOW_PACKET_MIN = 4  # the fewest lanes in a mesh's box worth a packet
_TREE_OCCLUDED_PACKET = _splice(r"""
#if defined(__clang__) && !defined(__CUDA_ARCH__)
if (wide != 0) {
typedef float v8 __attribute__((ext_vector_type(8)));
typedef int i8 __attribute__((ext_vector_type(8)));
@LEAST8@
@BITS8@
const float* W = (const float*)wide; const float* TR = (const float*)tris;
const float* CN = (const float*)cones;
@LANE_RAYS@
const v8 Ln = 1.0f / __builtin_elementwise_sqrt(Dx * Dx + Dy * Dy + Dz * Dz);
const v8 Ux = Dx * Ln, Uy = Dy * Ln, Uz = Dz * Ln;
int KX[8], KY[8], KZ[8];
float SX[8], SY[8], SZ[8], OKX[8], OKY[8], OKZ[8], TM[8];
for (int l = 0; l < 8; ++l) {
@LANE_SHEAR@
    TM[l] = ((lanes >> l) & 1) ? Bv[l] : -1.0f;
    if (TM[l] < 0.0f) Bv[l] = -1.0f;
}
unsigned live = (unsigned)lanes, blocked = 0;
auto tri_test = [&](int k, int l) {
@LANE_TRI@
@WOOP@
    if (tt > 0.0f && tt < TM[l]) {
        const wp::vec3 p(t[0], t[1], t[2]), q(t[3], t[4], t[5]), r(t[6], t[7], t[8]);
        const wp::vec3 nn = wp::normalize(wp::cross(q - p, r - p));
        const wp::vec3 o(Ox[l], Oy[l], Oz[l]), d(Dx[l], Dy[l], Dz[l]);
        if (!(wp::dot(nn, o - p) * wp::dot(nn, d) >= 0.0f)) blocked |= 1u << l;
    }
};
int sn[STACK];
int sp = 0;
int node = 0;
while (true) {
@WIDE_VISIT_CONES@
@WIDE_LEAVES@
    if (changed && (live & blocked)) {
        live &= ~blocked;
        if (!live) break;
        for (int l = 0; l < 8; ++l) if (blocked & (1u << l)) Bv[l] = -1.0f;
    }
    int cnt = 0, ch[4];
    float ce[4];
    for (int c = 0; c < 4; ++c) if (m[c]) { ch[cnt] = kc[c]; ce[cnt] = e[c]; ++cnt; }
    if (cnt == 1) { node = ch[0]; continue; }
    if (cnt > 1) {
        if (sp + cnt > STACK) return -1;
@WIDE_ORDER@
        for (int a = 0; a < cnt - 1; ++a) sn[sp++] = ch[a];
        node = ch[cnt - 1];
        continue;
    }
    if (sp == 0) break;
    node = sn[--sp];
}
return (int)blocked;

}
#endif
return -1;
""".replace("STACK", str(WIDE_STACK)))


@wp.func_native(_TREE_OCCLUDED_PACKET)
def mesh_tree_occluded_packet(wide: wp.uint64, tris: wp.uint64, cones: wp.uint64,
                              ox: PacketF, oy: PacketF, oz: PacketF, dx: PacketF, dy: PacketF, dz: PacketF,
                              t_max: PacketF, lanes: int) -> int:
    """The lanes (of the bit mask ``lanes``) whose segment (o, o + t_max·d) a triangle blocks, as
    ``mesh_tree_occluded`` answers each alone, through the wide tree ``wide`` (``widen``) with its
    normal cones ``cones`` (0: none; see above); -1 where this function cannot answer (CUDA, no
    tree copy, past WIDE_STACK stacked nodes: the caller asks each lane alone)."""
    ...


# Interior balls of a closed mesh (shadow rays only): balls lying wholly inside the solid the
# mesh bounds, each farther from every triangle than its radius. A shadow segment from a point
# outside the solid that passes through such a ball enters the solid, so it crosses a triangle at
# 0 < t < t_max, which ``mesh_tree_occluded`` would find and count as blocking (a triangle the
# segment meets on the way in is never one it leaves): the ball answers "blocked" without the
# traversal, the same answer. That needs the segment's origin outside the solid: a shading point
# that a camera outside the solid sees (``build.DeviceScene`` keeps the balls of an instance only
# while the camera and every light stay outside its box, and drops them for meshes whose points
# move). A mesh qualifies when every edge is shared by exactly two triangles (closed), so that
# the inside is well defined, and from BALLS_MIN_TRIANGLES triangles on (smaller trees are quick).
# Centres: the points of a BALLS_GRID³ lattice over the mesh's box that a ray-parity count puts
# inside, each with its distance to the nearest triangle; the farthest from the surface first,
# then greedily any centre not within 0.8 of a chosen ball's radius, up to BALLS_MAX; a chosen
# centre is kept only where two more parity counts in other directions agree; each then moved
# once to the best of its 5³ neighbours at half the lattice step (within 0.9 of its radius, so
# still inside); radii shrunk by BALLS_SHRINK (the float32 ball test and the distances' rounding).
BALLS_MIN_TRIANGLES = 512
BALLS_GRID = 24
BALLS_BIG = 500_000  # from this many triangles a 16³ lattice (a probe deep inside visits much of the tree)
BALLS_MAX = 32
BALLS_SHRINK = 1.0e-3
# the ray-parity counts' directions (unit, none along an axis or a diagonal of the lattice)
_PARITY_0 = wp.constant(wp.vec3(0.5773503, 0.5773503, 0.5773503))
_PARITY_1 = wp.constant(wp.vec3(-0.2672612, 0.5345225, 0.8017837))
_PARITY_2 = wp.constant(wp.vec3(0.7071068, -0.5, -0.5))


@wp.kernel(module="warprt_accel", enable_backward=False)
def interior_probe_kernel(mid: wp.uint64, pts: wp.array(dtype=wp.vec3), rays: int, out: wp.array(dtype=float)):
    """out[i]: the distance from pts[i] to the mesh's nearest triangle where the first ``rays``
    (0, 1 or 3) ray-parity counts (``_PARITY_0`` ...) all say inside; 0 elsewhere."""
    i = wp.tid()
    p = pts[i]
    odd = int(1)
    if rays > 0:
        odd = odd & wp.mesh_query_ray_count_intersections(mid, p, _PARITY_0)
    if rays > 1:
        odd = odd & wp.mesh_query_ray_count_intersections(mid, p, _PARITY_1)
        odd = odd & wp.mesh_query_ray_count_intersections(mid, p, _PARITY_2)
    out[i] = 0.0
    if odd != 0:
        q = wp.mesh_query_point_no_sign(mid, p, 1.0e30)
        if q.result:
            out[i] = wp.length(wp.mesh_eval_position(mid, q.face, q.u, q.v) - p)


def edge_keys(faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The 3F edges of the triangles ``faces`` (F, 3) as keys of their two corners whatever their
    order (edge k of face i at row k·F + i: corners (0, 1), (1, 2), (2, 0)), and the order that
    sorts the keys (stable), for ``closed_surface`` and ``interior_balls`` to share."""
    f = np.asarray(faces, dtype=np.int64)
    e = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    key = e.min(axis=1) * (int(f.max(initial=0)) + 1) + e.max(axis=1)
    return key, np.argsort(key, kind="stable")


def closed_surface(faces: np.ndarray, edges: tuple | None = None) -> bool:
    """Whether every edge of the triangles ``faces`` (F, 3) is shared by exactly two of them
    (``edges``: their ``edge_keys`` when already at hand)."""
    key, order = edge_keys(faces) if edges is None else edges
    key = key[order]
    # each key exactly twice: equal in pairs, and each pair unlike the next
    return bool(len(faces) > 0 and np.array_equal(key[0::2], key[1::2]) and np.all(key[1:-1:2] != key[2::2]))


def winds_outwards(points: np.ndarray, faces: np.ndarray) -> bool:
    """Whether a closed mesh's triangles wind outwards (counter-clockwise seen from outside): its
    signed volume, the sum of the tetrahedra from the origin, is positive."""
    v = np.asarray(points, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    return bool(np.einsum("ij,ij->i", v[f[:, 0]], np.cross(v[f[:, 1]], v[f[:, 2]])).sum() > 0.0)


def _in_pieces(n: int, smallest: int, device, launch) -> None:
    """``launch(lo, hi)`` over [0, n) in as many pieces as the CPU has cores, none smaller than
    ``smallest`` (a CPU launch runs on one thread); one piece on other devices."""
    pieces = min(os.cpu_count() or 1, max(1, n // smallest)) if device.is_cpu else 1
    bounds = np.linspace(0, n, pieces + 1).astype(int)

    def run(k: int) -> None:
        if bounds[k + 1] > bounds[k]:
            launch(int(bounds[k]), int(bounds[k + 1]))

    if pieces == 1:
        run(0)
    else:
        with ThreadPoolExecutor(max_workers=pieces) as pool:
            list(pool.map(run, range(pieces)))


def _probe(mesh: "wp.Mesh", pts: np.ndarray, rays: int) -> np.ndarray:
    """``interior_probe_kernel`` over pts, split over the cores (a probe deep inside a large mesh
    visits much of its tree)."""
    dev = mesh.device
    out = wp.zeros(len(pts), dtype=float, device=dev)
    a = wp.array(pts.astype(np.float32), dtype=wp.vec3, device=dev)
    _in_pieces(len(pts), 1024, dev, lambda lo, hi: wp.launch(interior_probe_kernel, dim=hi - lo, device=dev,
                                                             inputs=[mesh.id, a[lo:hi], rays, out[lo:hi]]))
    return out.numpy().astype(np.float64)


def interior_balls(mesh: "wp.Mesh", points: np.ndarray, faces: np.ndarray,
                   edges: tuple | None = None) -> np.ndarray | None:
    """The interior balls of a closed mesh (see above) as blocks of 8: float32 (B, 4, 8) holding
    the centres' x, y, z and the squared radii (padding: radius² -1, never met); None when the
    mesh does not qualify or no centre is inside (``edges``: the faces' ``edge_keys``)."""
    if len(faces) < BALLS_MIN_TRIANGLES or not closed_surface(faces, edges):
        return None
    lo, hi = points.min(axis=0).astype(np.float64), points.max(axis=0).astype(np.float64)
    grid_n = BALLS_GRID if len(faces) < BALLS_BIG else 16
    axes = [np.linspace(lo[a], hi[a], grid_n + 2)[1:-1] for a in range(3)]
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3).astype(np.float32).astype(np.float64)
    r = _probe(mesh, grid, 1)  # one parity count for the lattice; the chosen centres get three
    inside = r > 0.0
    if not inside.any():
        return None
    c, r = grid[inside], r[inside]
    order = np.argsort(-r, kind="stable")
    c, r = c[order], r[order]
    covered = np.zeros(len(c), dtype=bool)
    chosen = []
    for i in range(len(c)):
        if len(chosen) == BALLS_MAX:
            break
        if not covered[i]:
            chosen.append(i)
            covered |= np.linalg.norm(c - c[i], axis=1) < 0.8 * r[i]
    c, r = c[chosen], r[chosen]
    keep = _probe(mesh, c, 3) > 0.0  # inside by all three counts
    if not keep.any():
        return None
    c, r = c[keep], r[keep]
    # each centre to the best of its 5 x 5 x 5 neighbours at half the lattice step, all within 0.9
    # of its ball's radius (so inside the solid: their distances need no parity)
    step = np.minimum((hi - lo).max() / (grid_n + 1) * 0.5, 0.9 * r / (2.0 * np.sqrt(3.0)))
    off = np.stack(np.meshgrid(*[np.arange(-2, 3)] * 3, indexing="ij"), -1).reshape(-1, 3)
    cand = (c[:, None, :] + off[None] * step[:, None, None]).reshape(-1, 3).astype(np.float32).astype(np.float64)
    rc = _probe(mesh, cand, 0).reshape(len(c), -1)
    best = rc.argmax(axis=1)
    c = cand.reshape(len(c), -1, 3)[np.arange(len(c)), best]
    r = rc[np.arange(len(c)), best] * (1.0 - BALLS_SHRINK)
    blocks = np.zeros(((len(r) + 7) // 8, 4, 8), dtype=np.float32)
    blocks[:, 3, :] = -1.0
    for k in range(len(r)):
        blocks[k // 8, :3, k % 8] = c[k]
        blocks[k // 8, 3, k % 8] = np.float32(r[k]) * np.float32(r[k])
    return blocks


# Whether the segment (o, o + t_max·d), 0 < t < t_max, passes through one of the n balls (blocks of
# 8: x, y, z, radius²): the point of the ray nearest each centre, if within the segment, closer
# than the radius. Object space, d not necessarily of unit length. 0 on CUDA (no balls there).
_BALLS = r"""
#if defined(__clang__) && !defined(__CUDA_ARCH__)
typedef float v8 __attribute__((ext_vector_type(8)));
typedef int i8 __attribute__((ext_vector_type(8)));
const float* S = (const float*)balls;
const float inv = 1.0f / (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
const v8 ox = o[0], oy = o[1], oz = o[2], dx = d[0], dy = d[1], dz = d[2];
for (int b = 0; b < n; b += 8) {
    v8 cx, cy, cz, r2;
    __builtin_memcpy(&cx, S + 4 * b, 32); __builtin_memcpy(&cy, S + 4 * b + 8, 32);
    __builtin_memcpy(&cz, S + 4 * b + 16, 32); __builtin_memcpy(&r2, S + 4 * b + 24, 32);
    cx -= ox; cy -= oy; cz -= oz;
    const v8 tc = (cx * dx + cy * dy + cz * dz) * inv;
    const v8 px = cx - tc * dx, py = cy - tc * dy, pz = cz - tc * dz;
    const i8 h = (tc > 0.0f) & (tc < t_max) & (px * px + py * py + pz * pz < r2);
    if (__builtin_reduce_or(h)) return 1;
}
#endif
return 0;
"""


@wp.func_native(_BALLS)
def mesh_balls_hit(balls: wp.uint64, n: int, o: wp.vec3, d: wp.vec3, t_max: float) -> int:
    """1 when (o, o + t_max·d) passes through one of the n interior balls at ``balls`` (see above)."""
    ...


# Normal cones of a closed mesh (shadow rays only): a shadow segment whose two ends lie outside
# the solid (winding number 0) and which crosses the surface crosses it at least twice, once on
# the way in (against a triangle's outward normal n: n.d < 0) and once on the way out (n.d > 0):
# the winding number it starts and ends with is the same, and each crossing changes it by one.
# So the any-hit traversal (``mesh_tree_occluded``) may skip every triangle the ray can only leave
# (n.d > 0) and still gives the same answer: for each child of each node of the tree copy a cone
# (unit axis a, s) holds the outward normals of the child's subtree (each within arcsin(s -
# CONE_MARGIN) of a), and a ray whose unit direction has u.a >= s skips the child. A ray leaving a
# mesh's own surface skips the patch around its origin (all faces it leaves), where its traversal
# otherwise goes deepest. The cones bound each child's normals from
# its own children's cones (axis: the normalised sum of the subtree's unit normals), in float64;
# the margin covers the float32 axis, s and ray direction. A mesh qualifies when every edge is
# shared by exactly two triangles that run it in opposite directions (closed and consistently
# wound: the winding number is then well defined); "outward" is the side its signed volume says.
# Like the interior balls, the cones need the segment's origin outside the solid, and are given
# under the same rules (``build.DeviceScene.refresh_balls``).
CONE_MARGIN = 1.0e-5


def normal_cones(tree: MeshTree, points: np.ndarray, faces: np.ndarray, edges: tuple | None = None
                 ) -> np.ndarray | None:
    """Each node of the tree copy's two cones (see above), (slots, 2, 4) float32: the child's axis
    and s (2: none, the child's normals spread too far); None for a mesh that is not closed and
    consistently wound, or a tree the copy could not take."""
    if not tree.usable:
        return None
    f = np.asarray(faces, dtype=np.int64)
    key, order = edge_keys(f) if edges is None else edges
    if not closed_surface(f, (key, order)):
        return None
    # the two uses of each edge run it in opposite directions (rows as in ``edge_keys``)
    e = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    ascending = (e[:, 0] < e[:, 1])[order]
    if not np.all(ascending[0::2] != ascending[1::2]):
        return None
    outward = 1.0 if winds_outwards(points, f) else -1.0
    corners = tree.tris.numpy().astype(np.float64).reshape(-1, 3, 3)  # in leaf order
    normal = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    length = np.linalg.norm(normal, axis=1, keepdims=True)
    if not np.all(length > 0.0):
        return None
    normal *= outward / length
    kids = tree.kids.numpy().reshape(-1, 2)
    levels = []  # the inner nodes level by level from the root
    frontier = np.array([tree.root])
    while frontier.size:
        levels.append(frontier)
        below = kids[frontier].reshape(-1)
        frontier = below[below >= 0]
    axis = np.zeros((len(kids), 3))
    total = np.zeros((len(kids), 3))  # the sum of the subtree's unit normals
    half = np.zeros(len(kids))  # the cone's half angle
    out = np.zeros((len(kids), 2, 4), dtype=np.float32)
    out[:, :, 3] = 2.0
    for nodes in reversed(levels):  # children before their parents
        k = kids[nodes]
        leaf = k < 0
        inner = np.where(leaf, 0, k)
        c_axis = np.where(leaf[..., None], normal[np.where(leaf, -k - 1, 0)], axis[inner])
        c_total = np.where(leaf[..., None], c_axis, total[inner])
        c_half = np.where(leaf, 0.0, half[inner])
        t = c_total.sum(axis=1)
        size = np.linalg.norm(t, axis=1)
        a = t / np.where(size > 0.0, size, 1.0)[:, None]
        spread = np.arccos(np.clip(np.einsum("ni,nci->nc", a, c_axis), -1.0, 1.0)) + c_half
        axis[nodes], total[nodes] = a, t
        half[nodes] = np.where(size > 1e-9, spread.max(axis=1), np.pi)
        out[nodes, :, :3] = c_axis
        out[nodes, :, 3] = np.where(c_half < 0.5 * np.pi, np.sin(np.minimum(c_half, 0.5 * np.pi)) + CONE_MARGIN, 2.0)
    return out


# Escaping faces (shadow rays from a mesh's own surface): a face of a mesh whose every vertex lies
# behind its plane (or on it, within ESCAPE_TOL of the mesh's largest coordinate: the float32
# rounding of a planar quad's fourth corner) has the whole mesh behind it, so a shadow ray that
# leaves a point of that face towards its front can meet no triangle of the mesh at t > 0: its
# origin is spawned in front of the plane (by far more than ESCAPE_TOL) and it only moves away.
# ``escape_sides`` marks each face 1 (every vertex behind: rays towards the front escape), 2
# (every vertex in front: rays towards the back escape) or 0: escape horizons of zero on that
# side (below), found without a traversal. A convex mesh escapes everywhere, the outer half of a
# torus too. First verdicts reject most faces of a bumpy mesh
# cheaply (the third corners of the faces across its edges, then the extreme vertices in 64
# directions); a face is accepted only against every vertex, within ESCAPE_BUDGET vertex tests
# (past it, no face escapes).
ESCAPE_TOL = 5.0e-7
ESCAPE_BUDGET = 50_000_000
ESCAPE_MAX_TRIANGLES = 500_000  # (larger meshes: none, for the build's time: about 1 s a million)


def _unit_normals(v: np.ndarray, f: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The faces' unit normals (their winding's; zero-area faces: the zero vector) and the
    cross products' lengths, float64."""
    a = v[f[:, 0]]
    n = np.cross(v[f[:, 1]] - a, v[f[:, 2]] - a)
    length = np.linalg.norm(n, axis=1)
    return n / np.where(length > 0.0, length, 1.0)[:, None], length


def escape_sides(points: np.ndarray, faces: np.ndarray, edges: tuple | None = None) -> np.ndarray | None:
    """Each face's escaping side (see above) as uint8, or None when none escapes (``edges``: the
    faces' ``edge_keys``)."""
    v = np.asarray(points, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    if len(f) == 0 or len(f) > ESCAPE_MAX_TRIANGLES:
        return None
    tol = ESCAPE_TOL * float(np.abs(v).max())
    n, length = _unit_normals(v, f)
    off = np.einsum("fj,fj->f", n, v[f[:, 0]])

    def verdict(faces_, pts):  # 1: every point of pts (per face, or shared) behind, 2: in front
        h = np.einsum("fj,fkj->fk", n[faces_], pts) if pts.ndim == 3 else n[faces_] @ pts.T
        h = h - off[faces_, None]
        return np.where(h.max(axis=1) <= tol, 1, 0) | np.where(h.min(axis=1) >= -tol, 2, 0)

    side = np.where(length > 0.0, 3, 0)
    # first verdicts: each face's neighbours across its edges (their third corners: a concave
    # edge rejects both faces), then the extreme vertices in 64 directions
    third = np.concatenate([f[:, 2], f[:, 0], f[:, 1]])
    owner = np.tile(np.arange(len(f)), 3)
    key, order = edge_keys(f) if edges is None else edges
    pair = np.flatnonzero(key[order[1:]] == key[order[:-1]])
    p, q = order[pair], order[pair + 1]
    for a_, b_ in ((p, q), (q, p)):
        np.bitwise_and.at(side, owner[a_], verdict(owner[a_], v[third[b_]][:, None, :]))
    dirs = np.random.default_rng(0).normal(size=(64, 3))
    proj = dirs @ v.T
    ext = np.unique(np.concatenate([np.argmax(proj, axis=1), np.argmin(proj, axis=1)]))
    for lo in range(0, len(f), 16384):  # (in pieces: a face by a hundred vertices each)
        c = np.flatnonzero(side[lo:lo + 16384]) + lo
        if len(c):
            side[c] &= verdict(c, v[ext])
    cand = np.flatnonzero(side)
    if len(cand) == 0 or len(cand) * len(v) > ESCAPE_BUDGET:
        return None
    for lo in range(0, len(cand), 256):  # every vertex for the faces still in the running
        c = cand[lo:lo + 256]
        side[c] &= verdict(c, v)
    return side.astype(np.uint8) if side.any() else None


# Escape horizons (shadow rays from a mesh's own surface). A shadow ray leaving a point of face f
# towards its side A (the face's unit normal, or its opposite: the side the shading point is seen
# from) can meet a triangle of the mesh only in a direction some point of f sees a point of that
# triangle in. Around A, directions fall into 8 sectors of azimuth (45 degrees each, from a frame
# t, b = A x t with t across A and the axis of A's least component); per face and side, each
# sector keeps an upper bound on the sine of the elevation (above f's plane) of every direction
# in it from a point of f to a point of another triangle. A ray whose elevation passes its
# sector's bound meets none: it skips the instance (``lights.area_lights_packet``'s and
# ``point_lights_packet``'s ``skip`` and ``face``, ``trace.occluded_packet``). Escaping faces
# (above) are horizons of zero. The bounds cost tens of microseconds a face to find, so meshes of
# more than HORIZON_MAX_TRIANGLES keep the escaping faces alone: there the build takes seconds,
# and the shadow packets and normal cones already skip most of the work the horizons would, so
# they save no more than a render's noise (``escape_horizons`` in ``warprt.fast``).
#
# The bounds (``horizon_kernel``, C++ in double over the CPU tree copy, once per asset): for a
# part of the mesh (a node's box, or a triangle), the top of its box along A over its distance
# from the ball around f, and, once the balls are apart, the cap of directions from f's ball to
# the part's ball: its top elevation and the sectors its azimuths cross (widened by
# HORIZON_MARGIN). A box wholly behind f's plane adds nothing; a node whose bound raises no
# sector is pruned; a node seen under less than HORIZON_DETAIL radians is taken whole; a
# triangle's own bound is the least of its cap, of its plane (f on or above the triangle's plane:
# every direction into the triangle lies below that plane; per sector, in closed form) and, where
# the plane does not apply, of the exact highest direction of the cone the nine corner
# differences span (on a generator, or on the sector between two; 1 when the triangle, seen
# along A, lies over f by more than the tolerance). The tolerance is ESCAPE_TOL of the mesh's
# largest coordinate (the float32 rounding of a planar quad: a shading point is spawned off its
# face by far more). The bounds are stored rounded up to 1/255 with HORIZON_MARGIN added (the
# float32 test's rounding); a side whose every sector reaches HORIZON_GIVE_UP is closed. Closed
# meshes get their outer side only (the inner one serves a camera inside the solid, where every
# direction meets the mesh soon). Each face: its unit normal (float32, the axis both the bounds
# and the test use), a word of flags (bit s: side s has an open sector), and 8 bytes per side;
# and, where the bounds were found (not for the escaping faces alone, whose 8 sectors are alike),
# the sectors' frame in an array of its own (``escape_frames``: made once, not by every ray's test).
HORIZON_MARGIN = 2.0e-3
HORIZON_DETAIL = 0.1
HORIZON_GIVE_UP = 0.9
HORIZON_BUDGET = 4096  # node visits a face and side (past them: closed)
HORIZON_MAX_TRIANGLES = 8192
# words of a face's record (uint32): its unit normal A (float32), the flags, 8 sector bytes per side
ESCAPE_WORDS = 8

_HORIZON_FACE = r"""
#if !defined(__CUDA_ARCH__)
auto fmax = [](double a, double b) { return a > b ? a : b; };
auto fmin = [](double a, double b) { return a < b ? a : b; };
auto fabs = [](double a) { return a < 0.0 ? -a : a; };
auto sqrt = [](double a) { return __builtin_sqrt(a); };
auto sub = [](const double* a, const double* b, double* r) {
    r[0] = a[0] - b[0]; r[1] = a[1] - b[1]; r[2] = a[2] - b[2]; };
auto dot = [](const double* a, const double* b) { return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]; };
auto cross = [](const double* a, const double* b, double* r) {
    r[0] = a[1] * b[2] - a[2] * b[1]; r[1] = a[2] * b[0] - a[0] * b[2]; r[2] = a[0] * b[1] - a[1] * b[0]; };
const float* N = (const float*)nodes;
const int* C = (const int*)kids;
const float* TR = (const float*)tris;
const int face = wp::mesh_get(mid).bvh.primitive_indices[k];
unsigned int* out = (unsigned int*)outp + ESCAPE_WORDS * face;
for (int w = 0; w < ESCAPE_WORDS; ++w) out[w] = w < 4 ? 0u : 0xffffffffu;  // every sector closed
const float* fk = TR + 9 * k;
double F[3][3];
for (int j = 0; j < 3; ++j) for (int i = 0; i < 3; ++i) F[j][i] = (double)fk[3 * j + i];
double e1[3], e2[3], nn[3];
sub(F[1], F[0], e1); sub(F[2], F[0], e2); cross(e1, e2, nn);
const double len = sqrt(dot(nn, nn));
if (!(len > 0.0)) return 0;
const float a32[3] = {(float)(nn[0] / len), (float)(nn[1] / len), (float)(nn[2] / len)};
__builtin_memcpy(out, a32, 12);
const double PI = 3.14159265358979323846, SECTOR = PI / 4.0;
double cf[3];  // the face's centre and the radius of its ball
for (int i = 0; i < 3; ++i) cf[i] = (F[0][i] + F[1][i] + F[2][i]) / 3.0;
double rf = 0.0;
for (int j = 0; j < 3; ++j) { double w[3]; sub(F[j], cf, w); rf = fmax(rf, sqrt(dot(w, w))); }
rf = rf * (1.0 + 1e-9) + tol;
const double sdetail = __builtin_sin(detail);
// per sector: its centre's direction, and its ends widened by the margin (cos, sin of each);
// cw, sw: cos and sin of half a sector plus the margin
double cen[8][2], ends[8][4];
for (int s = 0; s < 8; ++s) {
    const double c = (s + 0.5) * SECTOR, p0 = s * SECTOR - margin, p1 = (s + 1) * SECTOR + margin;
    cen[s][0] = __builtin_cos(c); cen[s][1] = __builtin_sin(c);
    ends[s][0] = __builtin_cos(p0); ends[s][1] = __builtin_sin(p0);
    ends[s][2] = __builtin_cos(p1); ends[s][3] = __builtin_sin(p1);
}
const double cw = __builtin_cos(0.5 * SECTOR + margin), sw = __builtin_sin(0.5 * SECTOR + margin);
unsigned int usable = 0u;
int visits = 0;
const unsigned char known = ((const unsigned char*)escapes)[face];
for (int side = 0; side < 2; ++side) {
    if (!(sides >> side & 1)) continue;
    visits = 0;
    if (known >> side & 1) {  // every vertex behind this side (escape_sides): zero all round
        for (int w = 0; w < 2; ++w) out[4 + 2 * side + w] = 0u;
        usable |= 1u << side;
        continue;
    }
    const double sg = side == 0 ? 1.0 : -1.0;
    const double A[3] = {sg * (double)a32[0], sg * (double)a32[1], sg * (double)a32[2]};
    // the sectors' frame (as ``escape_frames`` makes the test's, in double here): t across A
    // and the axis of A's least component, b = A x t; sector s holds the azimuths
    // [s, s + 1) * 45 degrees from t
    const int ax = fabs(A[0]) <= fabs(A[1]) ? (fabs(A[0]) <= fabs(A[2]) ? 0 : 2) : (fabs(A[1]) <= fabs(A[2]) ? 1 : 2);
    double ev[3] = {0.0, 0.0, 0.0}; ev[ax] = 1.0;
    double t[3], b[3]; cross(A, ev, t);
    const double tl = sqrt(dot(t, t)); t[0] /= tl; t[1] /= tl; t[2] /= tl;
    cross(A, t, b);
    double flo = 1e300;  // the face's lowest corner along A
    for (int j = 0; j < 3; ++j) flo = fmin(flo, dot(F[j], A));
    double h[8] = {0, 0, 0, 0, 0, 0, 0, 0};
    double hmin = 0.0;
    auto least = [&](int m) {  // the lowest bound over the sectors of mask m
        double v = 2.0;
        for (int s = 0; s < 8; ++s) if (m >> s & 1) v = fmin(v, h[s]);
        return v;
    };
    // the sectors (bit s: sector s) whose azimuths come within ``half`` (its sine and cosine,
    // plus the margin) of direction w's: the sector's centre within half + 22.5 degrees
    auto sectors = [&](const double* w, double sh, double ch) -> int {
        const double x = dot(w, t), y = dot(w, b), l = sqrt(x * x + y * y);
        if (!(l > 0.0)) return 255;
        const double lim = ch * cw - sh * sw;  // cos(half + 22.5 degrees + margin)
        int m = 0;
        for (int s = 0; s < 8; ++s) if (x * cen[s][0] + y * cen[s][1] >= lim * l) m |= 1 << s;
        return m;
    };
    // an upper bound on the sine of the elevation of every direction from the face to a part of
    // the mesh: its box's top along A (hb) over its distance from the face's ball, and, where the
    // part's ball (c, r) is clear of the face's, the top of the cap of directions to that ball;
    // m: the sectors those directions take (all, unless the cap says fewer); sb: the cap's sine
    auto bound = [&](double hb, const double* lo, const double* hi, const double* c, double r, double floor, int& m,
                     double& sb) -> double {
        double dd = 0.0;
        for (int i = 0; i < 3; ++i) { const double e = fmax(fmax(lo[i] - cf[i], cf[i] - hi[i]), 0.0); dd += e * e; }
        dd = sqrt(dd);
        double v = dd > rf ? fmin(1.0, (hb - flo) / (dd - rf)) : 1.0;
        m = 255; sb = 1.0;
        double w[3]; sub(c, cf, w);
        const double dist = sqrt(dot(w, w)), R = rf + r;
        if (dist > R * 1.0001) {
            sb = R / dist;
            const double cb = sqrt(1.0 - sb * sb), se = fmax(-1.0, fmin(1.0, dot(w, A) / dist));
            const double ce = sqrt(1.0 - se * se);
            if (ce * cb - se * sb > 0.0) {  // the cap's top below the pole
                v = fmin(v, fmax(0.0, se * cb + ce * sb));
                if (v <= floor) return v;
                if (ce * cb + se * sb > 0.0) {  // nor holding the opposite pole: fewer sectors
                    const double sh = fmin(1.0, sb / ce);
                    m = sectors(w, sh, sqrt(1.0 - sh * sh));
                }
            }
        }
        return v;
    };
    auto raise = [&](int m, const double* v) {
        for (int s = 0; s < 8; ++s) if ((m >> s & 1) && v[s] > h[s]) h[s] = v[s];
        hmin = least(255);
    };
    // a triangle's share, per sector: the least of its box-and-cap bound, its plane's bound (the
    // face on or above the triangle's plane: directions into it lie below that plane) and the
    // highest direction of the cone the nine corner differences span
    auto triangle = [&](const float* tp) {
        double T[3][3], lo[3] = {1e300, 1e300, 1e300}, hi[3] = {-1e300, -1e300, -1e300};
        for (int j = 0; j < 3; ++j) for (int i = 0; i < 3; ++i) {
            T[j][i] = (double)tp[3 * j + i]; lo[i] = fmin(lo[i], T[j][i]); hi[i] = fmax(hi[i], T[j][i]); }
        double hb = -1e300;
        for (int j = 0; j < 3; ++j) hb = fmax(hb, dot(T[j], A));
        if (hb <= flo + tol) return;  // behind (or on) the face's plane
        double ct[3];
        for (int i = 0; i < 3; ++i) ct[i] = (T[0][i] + T[1][i] + T[2][i]) / 3.0;
        double rt = 0.0;
        for (int j = 0; j < 3; ++j) { double w[3]; sub(T[j], ct, w); rt = fmax(rt, sqrt(dot(w, w))); }
        int m; double sb;
        const double v = bound(hb, lo, hi, ct, rt, hmin, m, sb);
        if (v <= hmin || v <= least(m)) return;
        double val[8];
        for (int s = 0; s < 8; ++s) val[s] = v;
        bool plane = false;
        double u1[3], u2[3], mt[3];
        sub(T[1], T[0], u1); sub(T[2], T[0], u2); cross(u1, u2, mt);
        const double ml = sqrt(dot(mt, mt));
        if (ml > 0.0) {
            mt[0] /= ml; mt[1] /= ml; mt[2] /= ml;
            double am = dot(A, mt);
            if (am < 0.0) { am = -am; mt[0] = -mt[0]; mt[1] = -mt[1]; mt[2] = -mt[2]; }
            double below = 1e300;
            for (int j = 0; j < 3; ++j) { double w[3]; sub(F[j], T[0], w); below = fmin(below, dot(w, mt)); }
            if (am > 0.0 && below >= -tol) {
                // at azimuth phi the highest direction below the plane: tan e = -rho cos(phi - psi) / (A.m);
                // over a sector the least cos(phi - psi): -1 where the sector (plus the margin)
                // holds psi + 180 degrees, else at one of its ends
                const double mx = dot(mt, t), my = dot(mt, b), rho = sqrt(mx * mx + my * my);
                for (int s = 0; s < 8; ++s) {
                    const double cmin = -(mx * cen[s][0] + my * cen[s][1]) >= cw * rho ? -1.0
                        : fmin(mx * ends[s][0] + my * ends[s][1], mx * ends[s][2] + my * ends[s][3])
                          / fmax(rho, 1e-300);
                    const double X = -rho * cmin;
                    val[s] = fmin(val[s], X <= 0.0 ? 0.0 : X / sqrt(X * X + am * am));
                }
                plane = true;
            }
        }
        if (!plane) {
            // the cone of directions from the face to the triangle, spanned by the nine corner
            // differences: its highest direction lies on a generator or on the sector between
            // two (where A's projection onto their plane falls between them), unless the cone
            // holds A itself: then some point of the triangle lies straight above the face
            double W[9][3]; int nw = 0;
            for (int i = 0; i < 3; ++i) for (int j = 0; j < 3; ++j) {
                double w[3]; sub(T[i], F[j], w);
                const double l = sqrt(dot(w, w));
                if (l > 0.0) { W[nw][0] = w[0] / l; W[nw][1] = w[1] / l; W[nw][2] = w[2] / l; ++nw; }
            }
            double M = 0.0;
            for (int a = 0; a < nw; ++a) M = fmax(M, dot(W[a], A));
            for (int a = 0; a < nw; ++a) for (int c2 = a + 1; c2 < nw; ++c2) {
                double cn[3]; cross(W[a], W[c2], cn);
                const double cl2 = dot(cn, cn);
                if (!(cl2 > 1e-24)) continue;
                const double ac = dot(A, cn) / cl2;
                const double P[3] = {A[0] - ac * cn[0], A[1] - ac * cn[1], A[2] - ac * cn[2]};
                double x1[3], x2[3]; cross(P, W[c2], x1); cross(W[a], P, x2);
                if (dot(x1, cn) >= 0.0 && dot(x2, cn) >= 0.0) M = fmax(M, sqrt(dot(P, P)));
            }
            // a point of the triangle above the face: the triangle clipped by the face, both
            // seen along A (coordinates t, b; the third: the height along A)
            double poly[9][3], tmp[9][3]; int np = 3;
            double f2[3][2];
            for (int j = 0; j < 3; ++j) { f2[j][0] = dot(F[j], t); f2[j][1] = dot(F[j], b); }
            for (int j = 0; j < 3; ++j) {
                poly[j][0] = dot(T[j], t); poly[j][1] = dot(T[j], b); poly[j][2] = dot(T[j], A);
            }
            const double orient = (f2[1][0] - f2[0][0]) * (f2[2][1] - f2[0][1])
                                  - (f2[1][1] - f2[0][1]) * (f2[2][0] - f2[0][0]);
            for (int e = 0; e < 3 && np > 0; ++e) {
                const double* pa = f2[e]; const double* pb = f2[(e + 1) % 3];
                int n2 = 0;
                for (int i = 0; i < np; ++i) {
                    const double* P0 = poly[i]; const double* P1 = poly[(i + 1) % np];
                    const double s0 = ((pb[0] - pa[0]) * (P0[1] - pa[1]) - (pb[1] - pa[1]) * (P0[0] - pa[0])) * orient;
                    const double s1 = ((pb[0] - pa[0]) * (P1[1] - pa[1]) - (pb[1] - pa[1]) * (P1[0] - pa[0])) * orient;
                    if (s0 >= 0.0) { for (int c3 = 0; c3 < 3; ++c3) tmp[n2][c3] = P0[c3]; ++n2; }
                    if ((s0 >= 0.0) != (s1 >= 0.0)) {
                        const double u = s0 / (s0 - s1);
                        for (int c3 = 0; c3 < 3; ++c3) tmp[n2][c3] = P0[c3] + u * (P1[c3] - P0[c3]);
                        ++n2;
                    }
                }
                np = n2;
                for (int i = 0; i < np; ++i) for (int c3 = 0; c3 < 3; ++c3) poly[i][c3] = tmp[i][c3];
            }
            double fhi = -1e300;  // the face's highest corner: its plane is across A up to rounding
            for (int j = 0; j < 3; ++j) fhi = fmax(fhi, dot(F[j], A));
            for (int i = 0; i < np; ++i) if (poly[i][2] > fhi + tol) M = 1.0;
            for (int s = 0; s < 8; ++s) val[s] = fmin(val[s], M);
        }
        raise(m, val);
    };
    // depth first, the child of the higher bound on top; a stacked node's bound is checked again
    // when it is taken (the sectors may have risen past it meanwhile)
    int stack[128], smask[128];
    double sval[128];
    int sp = 0;
    int node = root;
    while (true) {
        const float* nd = N + 12 * node;
        ++visits;
        int pk[2], pm[2];
        double pv[2];
        int np2 = 0;
        for (int c = 0; c < 2; ++c) {
            const int kid = C[2 * node + c];
            if (kid < 0 && -kid - 1 == k) continue;  // the face itself
            if (kid < 0) { triangle(TR + 9 * (-kid - 1)); continue; }
            double lo[3], hi[3], cb[3], r = 0.0, hb = 0.0;
            for (int i = 0; i < 3; ++i) {
                lo[i] = nd[6 * c + i]; hi[i] = nd[6 * c + 3 + i];
                hb += fmax(lo[i] * A[i], hi[i] * A[i]);
                cb[i] = 0.5 * (lo[i] + hi[i]);
                r += 0.25 * (hi[i] - lo[i]) * (hi[i] - lo[i]);
            }
            if (hb <= flo + tol) continue;  // the box is behind the face's plane
            int m; double sb;
            const double v = bound(hb, lo, hi, cb, sqrt(r), hmin, m, sb);
            if (v <= hmin || v <= least(m)) continue;  // raises no sector
            if (sb < sdetail) { double val[8]; for (int s = 0; s < 8; ++s) val[s] = v; raise(m, val); continue; }
            pk[np2] = kid; pm[np2] = m; pv[np2] = v; ++np2;
        }
        if (np2 == 2 && pv[0] > pv[1]) {
            int tk = pk[0]; pk[0] = pk[1]; pk[1] = tk; tk = pm[0]; pm[0] = pm[1]; pm[1] = tk;
            double tv = pv[0]; pv[0] = pv[1]; pv[1] = tv;
        }
        if (sp + np2 > 128 || visits > budget) { hmin = 1.0; break; }  // too deep or too long: closed
        for (int i = 0; i < np2; ++i) { stack[sp] = pk[i]; smask[sp] = pm[i]; sval[sp] = pv[i]; ++sp; }
        if (hmin >= giveup) break;
        bool found = false;
        while (sp > 0) {
            --sp;
            if (sval[sp] > hmin && sval[sp] > least(smask[sp])) { node = stack[sp]; found = true; break; }
        }
        if (!found) break;
    }
    if (hmin >= giveup) for (int s = 0; s < 8; ++s) h[s] = 1.0;
    unsigned char q[8];
    bool open = false;
    for (int s = 0; s < 8; ++s) {
        const double x = __builtin_ceil((h[s] + margin) * 255.0);
        q[s] = x >= 255.0 ? 255 : (unsigned char)x;
        open = open || q[s] < 255;
    }
    __builtin_memcpy(out + 4 + 2 * side, q, 8);
    if (open) usable |= 1u << side;
}
out[3] = usable;
return visits;
#endif
return 0;
"""


@wp.func_native(_HORIZON_FACE.replace("ESCAPE_WORDS", str(ESCAPE_WORDS)))
def _horizon_face(mid: wp.uint64, nodes: wp.uint64, kids: wp.uint64, tris: wp.uint64, root: int, k: int,
                  escapes: wp.uint64, tol: float, margin: float, detail: float, giveup: float, budget: int,
                  sides: int, outp: wp.uint64) -> int:
    ...


@wp.kernel(module="warprt_accel", enable_backward=False)
def horizon_kernel(mid: wp.uint64, nodes: wp.uint64, kids: wp.uint64, tris: wp.uint64, root: int, first: int,
                   escapes: wp.uint64, tol: float, margin: float, detail: float, giveup: float, budget: int,
                   sides: int, outp: wp.uint64):
    """The escape horizons of the face at leaf position ``first`` + tid (see above)."""
    _horizon_face(mid, nodes, kids, tris, root, first + wp.tid(), escapes, tol, margin, detail, giveup, budget, sides,
                  outp)


def horizon_bounds_found(tree: "MeshTree", n: int) -> bool:
    """Whether ``escape_horizons`` finds the bounds of a mesh of n triangles with this tree copy
    (else its records hold the escaping faces alone)."""
    return n <= HORIZON_MAX_TRIANGLES and tree.usable


def escape_horizons(tree: "MeshTree", points: np.ndarray, faces: np.ndarray,
                    edges: tuple | None = None, bounds: bool = True) -> np.ndarray | None:
    """Every face's escape horizons (see above) as uint32 (F, 8), or None where no face has an
    open sector (``edges``: the faces' ``edge_keys``). Meshes of up to HORIZON_MAX_TRIANGLES
    triangles get the traversal's bounds over the tree copy (a CPU mesh's: only the CPU has
    one); larger ones, trees the copy cannot take, and ``bounds`` False (``warprt.fast``:
    escape_horizons switched off) the escaping faces alone (``escape_sides``: zero on their
    escaping side, the other closed)."""
    v = np.asarray(points, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    n = len(f)
    edges = edge_keys(f) if edges is None else edges
    with fast.timed("escaping_faces"):
        known = escape_sides(v, f, edges)
    known = np.zeros(n, dtype=np.uint8) if known is None else known
    if not bounds or not horizon_bounds_found(tree, n):
        if not known.any():
            return None
        h = np.zeros((n, ESCAPE_WORDS), dtype=np.uint32)
        h[:, :3] = _unit_normals(v, f)[0].astype(np.float32).view(np.uint32)
        h[:, 3] = known
        h[:, 4:6] = np.where((known & 1 != 0)[:, None], 0, 0xFFFFFFFF)
        h[:, 6:8] = np.where((known & 2 != 0)[:, None], 0, 0xFFFFFFFF)
        return h
    sides = 3
    if closed_surface(f, edges):  # the outer side only: the front where the faces wind outwards
        sides = 1 if winds_outwards(v, f) else 2
    dev = tree.mesh.device
    out = wp.empty(ESCAPE_WORDS * n, dtype=wp.uint32, device=dev)
    esc = wp.array(known, dtype=wp.uint8, device=dev)
    tol = float(ESCAPE_TOL * float(np.abs(v).max(initial=0.0)))
    with fast.timed("escape_horizons"):
        _in_pieces(n, 256, dev, lambda lo, hi: wp.launch(
            horizon_kernel, dim=hi - lo, device=dev,
            inputs=[tree.mesh.id, tree.nodes.ptr, tree.kids.ptr, tree.tris.ptr, tree.root, lo, esc.ptr, tol,
                    HORIZON_MARGIN, HORIZON_DETAIL, HORIZON_GIVE_UP, HORIZON_BUDGET, sides, out.ptr]))
        h = out.numpy().reshape(n, ESCAPE_WORDS)
    return h if np.any(h[:, 3]) else None


def escape_frames(a: np.ndarray) -> np.ndarray:
    """The sectors' frame of each face whose unit normal (float32) is a row of ``a`` (F, 3): t, a
    unit vector across A and the axis of A's least component, then b = A x t, as (F, 8) float32
    (2 unused), by the float32 operations ``horizon_escapes`` once made per ray (its sectors the
    same, bit for bit; a zero normal gives a frame never read)."""
    a = np.asarray(a, dtype=np.float32).reshape(-1, 3)
    m = np.abs(a)
    ax = np.where(m[:, 0] <= m[:, 1], np.where(m[:, 0] <= m[:, 2], 0, 2), np.where(m[:, 1] <= m[:, 2], 1, 2))
    zero = np.zeros(len(a), np.float32)
    t = np.where((ax == 0)[:, None], np.stack([zero, a[:, 2], -a[:, 1]], 1),
                 np.where((ax == 1)[:, None], np.stack([-a[:, 2], zero, a[:, 0]], 1), np.stack([a[:, 1], -a[:, 0], zero], 1)))
    with np.errstate(divide="ignore", invalid="ignore"):  # (a zero normal's frame: NaN, never read)
        il = np.float32(1.0) / np.sqrt(t[:, 0] * t[:, 0] + t[:, 1] * t[:, 1] + t[:, 2] * t[:, 2])
        t = t * il[:, None]
        b = np.stack([a[:, 1] * t[:, 2] - a[:, 2] * t[:, 1], a[:, 2] * t[:, 0] - a[:, 0] * t[:, 2],
                      a[:, 0] * t[:, 1] - a[:, 1] * t[:, 0]], 1)
    return np.concatenate([t, b, np.zeros((len(a), 2), np.float32)], 1).astype(np.float32)


# Whether the ray along d (object space, any length) from the face and side ``code`` = 2 face +
# side (0: along the face's normal, 1: against it) escapes the mesh by its horizons (see above);
# and whether that side has an open sector at all. 0 on CUDA (no horizons there).
_HORIZON_ESCAPES = r"""
#if !defined(__CUDA_ARCH__)
if (escape == 0) return 0;
const unsigned int* w = (const unsigned int*)escape + ESCAPE_WORDS * (code >> 1);
float A[3];
__builtin_memcpy(A, w, 12);
const float dx = d[0], dy = d[1], dz = d[2];
// side 1 leaves against A: A and t negated (b = A x t is the same), and so are d.A and d.t,
// exactly (each product and each sum negated)
const float sg = (code & 1) ? -1.0f : 1.0f;
const float dA = sg * (dx * A[0] + dy * A[1] + dz * A[2]);
if (!(dA > 0.0f)) return 0;
int s = 0;  // (without frames, the escaping faces alone: every sector alike)
if (frames != 0) {
    float R[6];  // the sectors' frame t, b (``escape_frames``)
    __builtin_memcpy(R, (const float*)frames + 8 * (code >> 1), 24);
    const float x = sg * (dx * R[0] + dy * R[1] + dz * R[2]), y = dx * R[3] + dy * R[4] + dz * R[5];
    // the sector of (x, y), 45 degrees each from t (the lower half as the upper turned half
    // round), without branches: which one is a coin toss to the branch predictor
    const int lower = y < 0.0f;
    const float xs = lower ? -x : x, ys = lower ? -y : y;
    s = 4 * lower + (xs > 0.0f ? (ys < xs ? 0 : 1) : (ys > -xs ? 2 : 3));
}
const unsigned char q = ((const unsigned char*)(w + 4 + 2 * (code & 1)))[s];
if (q == 255) return 0;
const float h = (float)q * (1.0f / 255.0f);
return dA * dA > h * h * (dx * dx + dy * dy + dz * dz) ? 1 : 0;
#else
return 0;
#endif
"""


@wp.func_native(_HORIZON_ESCAPES.replace("ESCAPE_WORDS", str(ESCAPE_WORDS)))
def horizon_escapes(escape: wp.uint64, frames: wp.uint64, code: int, d: wp.vec3) -> int:
    """1 when the ray along d from face and side ``code`` (2 face + side) passes its horizon (see
    above), so it meets no triangle of the mesh (``frames``: the faces' ``escape_frames``, 0 for
    the escaping faces alone)."""
    ...


_HORIZON_OPEN = r"""
#if !defined(__CUDA_ARCH__)
return escape == 0 ? 0 : (int)(((const unsigned int*)escape)[ESCAPE_WORDS * face + 3] >> side & 1u);
#else
return 0;
#endif
"""


@wp.func_native(_HORIZON_OPEN.replace("ESCAPE_WORDS", str(ESCAPE_WORDS)))
def horizon_open(escape: wp.uint64, face: int, side: int) -> int:
    """1 when side ``side`` (0: along the normal) of face ``face`` has an open sector (see above)."""
    ...


# A packet of up to 8 rays (one pixel's camera rays, in the mesh's object space) through the tree
# copy's wide form (``widen``) together: each wide node's 4 boxes tested for the 8 lanes as clang
# vectors (``_WIDE_VISIT``), a child opened while any lane meets it no later than that lane's
# nearest hit, the children met stacked farthest first (by the least entry over the lanes); a
# leaf's triangle tested for each lane that meets its box, by the scalar query's watertight test
# with that lane's shear. A lane's result is the scalar query's: the nearest triangle, an exact
# tie going to the lower leaf in both, so the order the packet meets the leaves in changes
# nothing. Lanes with t_max < 0 take no part. Without the copy (CUDA, or a tree it cannot take)
# or past WIDE_STACK stacked nodes it returns 0 and the caller sends each lane through
# ``mesh_tree_ray`` alone. On a mesh of HIT_PREFETCH_TRIANGLES or more, whose corners are seldom
# in the caches, it prefetches each lane's hit's corners, which the caller then reads through the
# mesh's indices (``trace.leaves_face``, ``mesh_details``): the lanes' misses overlap instead of
# coming one lane at a time (smaller meshes, whose corners stay in the caches, gain nothing:
# ``hit_prefetch`` in ``warprt.fast``).
HIT_PREFETCH_TRIANGLES = 65536
_TREE_PACKET = _splice(r"""
bool alone = true;
#if defined(__clang__) && !defined(__CUDA_ARCH__)
if (wide != 0) {
    typedef float v8 __attribute__((ext_vector_type(8)));
    typedef int i8 __attribute__((ext_vector_type(8)));
@LEAST8@
@BITS8@
    const float* W = (const float*)wide;
    const float* TR = (const float*)tris;
@LANE_RAYS@
    int KX[8], KY[8], KZ[8], bh[8];
    float SX[8], SY[8], SZ[8], OKX[8], OKY[8], OKZ[8], bt[8], bu[8], bv[8];
    for (int l = 0; l < 8; ++l) {
@LANE_SHEAR@
        bt[l] = Bv[l]; bu[l] = 0.0f; bv[l] = 0.0f; bh[l] = -1;
    }
    auto tri_test = [&](int k, int l) {
@LANE_TRI@
@WOOP@
        if (tt >= 0.0f && (tt < bt[l] || (tt == bt[l] && k < bh[l]))) { bt[l] = tt; bu[l] = U * rcp; bv[l] = V * rcp; bh[l] = k; }
    };
    int sn[STACK];
    float st[STACK];
    int sp = 0;
    int node = 0;
    float far_all = -1.0f;  // the farthest any lane still searches
    for (int l = 0; l < 8; ++l) far_all = bt[l] > far_all ? bt[l] : far_all;
    bool overflow = false;
    while (far_all >= 0.0f) {
@WIDE_VISIT@
@WIDE_LEAVES@
        if (changed) {
            __builtin_memcpy(&Bv, bt, 32);
            far_all = -1.0f;
            for (int l = 0; l < 8; ++l) far_all = bt[l] > far_all ? bt[l] : far_all;
        }
        int cnt = 0, ch[4];
        float ce[4];
        for (int c = 0; c < 4; ++c) if (m[c] && e[c] <= far_all) { ch[cnt] = kc[c]; ce[cnt] = e[c]; ++cnt; }
        if (cnt == 1) { node = ch[0]; continue; }
        if (cnt > 1) {
            if (sp + cnt > STACK) { overflow = true; break; }
@WIDE_ORDER@
            for (int a = 0; a < cnt - 1; ++a) { sn[sp] = ch[a]; st[sp] = ce[a]; ++sp; }
            node = ch[cnt - 1];
            continue;
        }
        bool found = false;
        while (sp > 0) {
            --sp;
            if (st[sp] <= far_all) { node = sn[sp]; found = true; break; }
        }
        if (!found) break;
    }
    if (!overflow) {
        alone = false;
        const wp::Mesh& mesh = *(const wp::Mesh*)mid;
        for (int l = 0; l < 8; ++l) {
            if (bh[l] >= 0) {
                t[l] = bt[l]; u[l] = bu[l]; v[l] = bv[l];
                const int f = mesh.bvh.primitive_indices[bh[l]];
                face[l] = f;
                if (prefetch != 0 && mesh.num_tris >= HIT_PREFETCH_TRIANGLES) {  // (see above)
                    const int* ix = mesh.indices + 3 * f;
                    __builtin_prefetch(&mesh.points[ix[0]]); __builtin_prefetch(&mesh.points[ix[1]]);
                    __builtin_prefetch(&mesh.points[ix[2]]);
                }
            } else {
                t[l] = -1.0f; face[l] = -1;
            }
        }
    }
}
#endif
return alone ? 0 : 1;
""".replace("HIT_PREFETCH_TRIANGLES", str(HIT_PREFETCH_TRIANGLES)).replace("STACK", str(WIDE_STACK)))


@wp.func_native(_TREE_PACKET)
def mesh_tree_packet(mid: wp.uint64, wide: wp.uint64, tris: wp.uint64, prefetch: int,
                     ox: PacketF, oy: PacketF, oz: PacketF, dx: PacketF, dy: PacketF, dz: PacketF, t_max: PacketF,
                     t: wp.ref[PacketF], u: wp.ref[PacketF], v: wp.ref[PacketF], face: wp.ref[PacketI]) -> int:
    """Each lane's nearest triangle of mesh ``mid`` in [0, t_max] (t -1 and face -1 for none; see
    above); 0 where the lanes must go one by one instead (``mesh_tree_ray``), 1 when done."""
    ...


# Screen-space bins for camera rays (``camera_bins``): seen from one point (a pinhole camera's
# eye in the mesh's object space), each cell of a grid over the tangent plane (BINS_PER_PIXEL
# cells along a pixel's side) lists the triangles whose projected box, padded for rounding,
# covers it and whose projection comes within that padding of it, nearest first by their least
# depth. A ray from that point through a cell meets no triangle outside its list, and none whose
# least depth lies past its nearest hit, so the walk down the list stops there. Each candidate
# is tested as the packets' traversal tests it (``_WOOP`` with the lane's shear, an exact tie to
# the lower leaf): a lane gets the tree's hit, except where two triangles meet the ray at the
# same t or within rounding of it (a ray through a shared corner or edge) and rounding put one's
# box entry past the other's t, so that the tree's walk never tested it: the bins then give the
# nearer one, or at the same t the lower leaf (test_accel). On a large mesh a lane tests a few
# triangles of its cell where a packet through the wide tree makes tens of node visits and
# triangle tests (``camera_bins`` in ``warprt.fast``).
# The bins' record, float32 words: 0-2 the origin, 3-5 / 6-8 / 9-11 the axes U, V (tangent) and
# F (forward, unit), 12-13 the grid's lower corner in tangent coordinates (a = U·d / F·d, b), 14
# the cells per tangent unit, then as int32 words 15 nx, 16 ny, 17 the first entry's word; from
# word BINS_HEAD the nx·ny + 1 cell offsets; the entries as (least depth, leaf position) pairs.
BINS_HEAD = 20
BINS_TRIANGLES = 1024  # meshes with this many triangles or more get bins (as the shadow packets)
BINS_PER_PIXEL = 2  # cells along a pixel's side (3 or 4: more entries, and slower on a large mesh)
BINS_MAX_CELLS = 1 << 22  # a larger grid gets larger cells (16 MB of offsets)
BINS_MAX_ENTRIES = 1 << 23  # cells and entries over all of a scene's bins (about 48 MB)
BINS_AFTER_RENDERS = 2  # a changed view gets bins once rendered this many times (build.DeviceScene.rendering)
# the bins' record (``bins``) and the triangles in leaf order (``tris``) for the walks below
_BINS_RECORD = r"""
const float* B = (const float*)bins;
const int* BI = (const int*)bins;
const float* TR = (const float*)tris;
const int nx = BI[15], ny = BI[16];
const int* OFF = BI + BINS_HEAD;
const float* EZ = B + BI[17];
const int* EK = BI + BI[17];
""".replace("BINS_HEAD", str(BINS_HEAD))
# a ray's cell (its origin ol0..ol2, direction dl0..dl2): ``cl`` -1 where the bins cannot serve
# it (another origin, a direction off the grid), and ``rl``, the depth of t = 1 along it
_BINS_CELL = r"""
        int cl = -1;
        float rl = 0.0f;
        if (ol0 == B[0] && ol1 == B[1] && ol2 == B[2]) {
            const float w = dl0 * B[9] + dl1 * B[10] + dl2 * B[11];
            const float ca = ((dl0 * B[3] + dl1 * B[4] + dl2 * B[5]) / w - B[12]) * B[14];
            const float cb = ((dl0 * B[6] + dl1 * B[7] + dl2 * B[8]) / w - B[13]) * B[14];
            if (w > 0.0f && ca >= 0.0f && ca < (float)nx && cb >= 0.0f && cb < (float)ny) {
                cl = (int)cb * nx + (int)ca;
                rl = w * 1.00001f;  // a point at t lies at depth t·w: past bt·w (and rounding), past the hit
            }
        }
"""
# the walk down cell cl's list for the ray (ol0..ol2, dl0..dl2) from bt (its reach): the nearest
# triangle (bt, bu, bv; leaf position bh, -1 for none), by the packets' test and tie rule
_BINS_WALK = _splice(r"""
        const float ox = ol0, oy = ol1, oz = ol2, dx = dl0, dy = dl1, dz = dl2;  // (the names _SHEAR reads)
@SHEAR@
        float bu = 0.0f, bv = 0.0f;
        int bh = -1;
        auto tri_test = [&](int k) {
@WOOP@
            if (tt >= 0.0f && (tt < bt || (tt == bt && k < bh))) { bt = tt; bu = U * rcp; bv = V * rcp; bh = k; }
        };
        for (int j = OFF[cl], e = OFF[cl + 1]; j < e; ++j) {
            if (EZ[2 * j] > bt * rl) break;
            tri_test(EK[2 * j + 1]);
        }
""")
_BINS_PACKET = r"""
#if defined(__clang__) && !defined(__CUDA_ARCH__)
if (bins == 0) return 0;
@RECORD@
int cell[8];
float reach[8];
// every lane that takes part starts at the bins' origin and heads into the grid, or the tree
// takes the packet
for (int l = 0; l < 8; ++l) {
    cell[l] = -1;
    if (t_max[l] < 0.0f) continue;
    {
        const float ol0 = ox[l], ol1 = oy[l], ol2 = oz[l], dl0 = dx[l], dl1 = dy[l], dl2 = dz[l];
@CELL@
        if (cl < 0) return 0;
        cell[l] = cl;
        reach[l] = rl;
    }
}
const wp::Mesh& mesh = *(const wp::Mesh*)mid;
for (int l = 0; l < 8; ++l) {
    if (cell[l] < 0) continue;
    {
        const float ol0 = ox[l], ol1 = oy[l], ol2 = oz[l], dl0 = dx[l], dl1 = dy[l], dl2 = dz[l];
        const int cl = cell[l];
        const float rl = reach[l];
        float bt = t_max[l];
@WALK@
        if (bh >= 0) {
            t[l] = bt; u[l] = bu; v[l] = bv;
            const int f = mesh.bvh.primitive_indices[bh];
            face[l] = f;
            if (prefetch != 0) {  // (as mesh_tree_packet prefetches a large mesh's hits)
                const int* ix = mesh.indices + 3 * f;
                __builtin_prefetch(&mesh.points[ix[0]]); __builtin_prefetch(&mesh.points[ix[1]]);
                __builtin_prefetch(&mesh.points[ix[2]]);
            }
        } else {
            t[l] = -1.0f; face[l] = -1;
        }
    }
}
return 1;
#else
return 0;
#endif
""".replace("@RECORD@\n", _BINS_RECORD.lstrip("\n")).replace("@CELL@\n", _BINS_CELL.lstrip("\n")).replace(
    "@WALK@\n", _BINS_WALK.lstrip("\n"))
# ``mesh_tree_ray``'s answer for one ray through the bins: t -2 where they cannot serve it
_BINS_RAY = r"""
wp::vec_t<5, wp::float32> out;
out[0] = -2.0f;
#if !defined(__CUDA_ARCH__)
if (bins != 0) {
@RECORD@
    const float ol0 = o[0], ol1 = o[1], ol2 = o[2], dl0 = d[0], dl1 = d[1], dl2 = d[2];
@CELL@
    if (cl >= 0) {
        float bt = t_max;
@WALK@
        out[0] = -1.0f;
        if (bh >= 0) {
            const int f = wp::mesh_get(mid).bvh.primitive_indices[bh];
            out[0] = bt; out[1] = bu; out[2] = bv; out[3] = (float)(f >> 12); out[4] = (float)(f & 4095);
        }
    }
}
#endif
return out;
""".replace("@RECORD@\n", _BINS_RECORD.lstrip("\n")).replace("@CELL@\n", _BINS_CELL.lstrip("\n")).replace(
    "@WALK@\n", _BINS_WALK.lstrip("\n"))


@wp.func_native(_BINS_RAY)
def mesh_bins_ray(mid: wp.uint64, bins: wp.uint64, tris: wp.uint64, o: wp.vec3, d: wp.vec3,
                  t_max: float) -> MeshRayHit:
    """``mesh_tree_ray``'s answer for a ray from the bins' origin through the mesh's camera bins
    (see above); t -2 where the bins cannot serve it (none, another origin, off the grid)."""
    ...


@wp.func_native(_BINS_PACKET)
def mesh_bins_packet(mid: wp.uint64, bins: wp.uint64, tris: wp.uint64, prefetch: int,
                     ox: PacketF, oy: PacketF, oz: PacketF, dx: PacketF, dy: PacketF, dz: PacketF, t_max: PacketF,
                     t: wp.ref[PacketF], u: wp.ref[PacketF], v: wp.ref[PacketF], face: wp.ref[PacketI]) -> int:
    """``mesh_tree_packet``'s answer through the mesh's camera bins (see above); 0 where the
    packet must go through the tree instead (no bins, a lane from elsewhere or outside the grid)."""
    ...


@wp.func
def _bins_corner(tris: wp.array(dtype=wp.float32), i: int, j: int, o: wp.vec3d) -> wp.vec3d:
    return wp.vec3d(wp.float64(tris[9 * i + 3 * j]), wp.float64(tris[9 * i + 3 * j + 1]),
                    wp.float64(tris[9 * i + 3 * j + 2])) - o


@wp.kernel(module="warprt_accel", enable_backward=False)
def camera_bins_kernel(tris: wp.array(dtype=wp.float32), frame: wp.array(dtype=wp.vec3d), grid: wp.vec3d, nx: int,
                       ny: int, fill: int, max_cells: int, counts: wp.array(dtype=wp.int32),
                       depth: wp.array(dtype=wp.float32), leaf: wp.array(dtype=wp.int32), bad: wp.array(dtype=wp.int32)):
    """``camera_bins``' cells of triangle i (frame: the origin, U, V, F; grid: its lower corner
    (a, b) and cells per tangent unit): with ``fill`` 0 each cell's count, with 1 its entries
    (``counts`` then the cells' next free entries). A CPU launch runs its triangles in order, so
    each cell's entries come in leaf order. ``bad``: 1 where a triangle is not wholly in front, 2
    where the count's boxes would cover more than ``max_cells`` cells (counted in bad[1]); later
    triangles then stop."""
    i = wp.tid()
    if bad[0] != 0:
        return
    o, U, V, F = frame[0], frame[1], frame[2], frame[3]
    p0 = _bins_corner(tris, i, 0, o)
    p1 = _bins_corner(tris, i, 1, o)
    p2 = _bins_corner(tris, i, 2, o)
    z0, z1, z2 = wp.dot(p0, F), wp.dot(p1, F), wp.dot(p2, F)
    zmin = wp.min(z0, wp.min(z1, z2))
    far = wp.max(wp.length(p0), wp.max(wp.length(p1), wp.length(p2)))
    if not (zmin > wp.float64(1.0e-4) * far):
        bad[0] = 1
        return
    a0, a1, a2 = wp.dot(p0, U) / z0, wp.dot(p1, U) / z1, wp.dot(p2, U) / z2
    b0, b1, b2 = wp.dot(p0, V) / z0, wp.dot(p1, V) / z1, wp.dot(p2, V) / z2
    # padding: the float32 rounding of a ray's tangent coordinates and of the watertight test
    mag = wp.float64(0.0)
    for j in range(9):
        mag = wp.max(mag, wp.abs(wp.float64(tris[9 * i + j])))
    mag = mag + wp.max(wp.abs(o[0]), wp.max(wp.abs(o[1]), wp.abs(o[2])))
    big = wp.max(wp.max(wp.abs(a0), wp.max(wp.abs(a1), wp.abs(a2))), wp.max(wp.abs(b0), wp.max(wp.abs(b1), wp.abs(b2))))
    pad = wp.float64(1.0e-5) * (wp.float64(1.0) + wp.float64(2.0) * big) + wp.float64(1.0e-5) * mag / zmin
    inv = grid[2]
    x0 = wp.max(int(wp.floor((wp.min(a0, wp.min(a1, a2)) - pad - grid[0]) * inv)), 0)
    x1 = wp.min(int(wp.floor((wp.max(a0, wp.max(a1, a2)) + pad - grid[0]) * inv)) + 1, nx)
    y0 = wp.max(int(wp.floor((wp.min(b0, wp.min(b1, b2)) - pad - grid[1]) * inv)), 0)
    y1 = wp.min(int(wp.floor((wp.max(b0, wp.max(b1, b2)) + pad - grid[1]) * inv)) + 1, ny)
    if fill == 0:
        box = wp.max(x1 - x0, 0) * wp.max(y1 - y0, 0)
        if bad[1] + box > max_cells:
            bad[0] = 2
            return
        bad[1] = bad[1] + box
    area = (a1 - a0) * (b2 - b0) - (a2 - a0) * (b1 - b0)
    sgn = wp.float64(1.0)
    if area < wp.float64(0.0):
        sgn = wp.float64(-1.0)
    exact = wp.abs(area) > wp.float64(1.0e-12)
    zlo = wp.float32(zmin * wp.float64(1.0 - 1.0e-6))  # rounded down: the walk never stops early
    cell = wp.float64(1.0) / inv
    for cy in range(y0, y1):
        lb = grid[1] + wp.float64(cy) * cell
        hb = lb + cell
        for cx in range(x0, x1):
            la = grid[0] + wp.float64(cx) * cell
            ha = la + cell
            inside = True
            if exact:  # a cell wholly beyond one of the edges' lines (by more than the padding) is left out
                for e in range(3):
                    va, vb, wa, wb = a0, b0, a1, b1
                    if e == 1:
                        va, vb, wa, wb = a1, b1, a2, b2
                    if e == 2:
                        va, vb, wa, wb = a2, b2, a0, b0
                    na = -(wb - vb) * sgn
                    nb = (wa - va) * sgn
                    most = wp.max(na * (la - va), na * (ha - va)) + wp.max(nb * (lb - vb), nb * (hb - vb))
                    if most < -wp.float64(2.0) * pad * (wp.abs(na) + wp.abs(nb)):
                        inside = False
            if inside:
                c = cy * nx + cx
                if fill == 0:
                    counts[c] = counts[c] + 1
                else:
                    at = counts[c]
                    counts[c] = at + 1
                    depth[at] = zlo
                    leaf[at] = i


@wp.kernel(module="warprt_accel", enable_backward=False)
def camera_bins_sort_kernel(offsets: wp.array(dtype=wp.int32), depth: wp.array(dtype=wp.float32),
                            leaf: wp.array(dtype=wp.int32)):
    """Each cell's entries by least depth, nearest first (insertion: equal depths keep leaf order)."""
    c = wp.tid()
    for j in range(offsets[c] + 1, offsets[c + 1]):
        z = depth[j]
        k = leaf[j]
        m = j - 1
        while m >= offsets[c] and depth[m] > z:
            depth[m + 1] = depth[m]
            leaf[m + 1] = leaf[m]
            m -= 1
        depth[m + 1] = z
        leaf[m + 1] = k


def camera_bins_size(rec: np.ndarray) -> int:
    """The cells and entries a bins record holds: what it takes of BINS_MAX_ENTRIES."""
    ints = rec.view(np.int32)
    return int(ints[15]) * int(ints[16]) + (len(rec) - int(ints[17])) // 2


def camera_bins(tris: "wp.array", origin, forward, up, tan_x: float, tan_y: float, cell: float,
                box: tuple, max_entries: int | None = None) -> np.ndarray | None:
    """The bins' record (see above) of the triangles ``tris`` (float32 corners in leaf order, 9
    a triangle, on the CPU) seen from ``origin`` (float32 object-space point) looking along
    ``forward`` with ``up``, over the view's tangent rectangle [-tan_x, tan_x] × [-tan_y, tan_y]
    in cells of ``cell`` tangent units (larger past BINS_MAX_CELLS cells); None where bins cannot
    serve: a triangle not wholly in front of the origin, nothing of the mesh's ``box`` (lo, hi)
    in view, more cells and entries than ``max_entries`` (BINS_MAX_ENTRIES by default) in all, or
    not on the CPU."""
    max_entries = BINS_MAX_ENTRIES if max_entries is None else max_entries
    o32 = np.asarray(origin, np.float32)
    f = np.asarray(forward, np.float64)
    f = f / np.linalg.norm(f)
    ux = np.cross(f, np.asarray(up, np.float64))
    if not np.linalg.norm(ux) > 0:
        return None
    U32 = (ux / np.linalg.norm(ux)).astype(np.float32)
    V64 = np.cross(U32.astype(np.float64), f)
    V32 = (V64 / np.linalg.norm(V64)).astype(np.float32)
    F32 = f.astype(np.float32)
    U, V, F = (x.astype(np.float64) for x in (U32, V32, F32))
    o = o32.astype(np.float64)
    # the grid: the view's rectangle (two cells more each way), cut to the mesh's projected box
    lo, hi = (np.asarray(x, np.float64) for x in box)
    corners = np.array([[x, y, zz] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for zz in (lo[2], hi[2])]) - o
    cz = corners @ F
    g0a, g1a = -tan_x - 2 * cell, tan_x + 2 * cell
    g0b, g1b = -tan_y - 2 * cell, tan_y + 2 * cell
    if (cz > 0).all():
        ca, cb = (corners @ U) / cz, (corners @ V) / cz
        g0a, g1a = max(g0a, ca.min() - 2 * cell), min(g1a, ca.max() + 2 * cell)
        g0b, g1b = max(g0b, cb.min() - 2 * cell), min(g1b, cb.max() + 2 * cell)
    if not (g1a > g0a and g1b > g0b):
        return None
    cells = (g1a - g0a) * (g1b - g0b) / (cell * cell)
    if cells > BINS_MAX_CELLS:  # (a large image: larger cells)
        cell *= math.sqrt(cells / BINS_MAX_CELLS)
    inv = np.float32(1.0 / cell)
    g0a32, g0b32 = np.float32(g0a), np.float32(g0b)
    nx = int(math.ceil((g1a - float(g0a32)) * float(inv)))
    ny = int(math.ceil((g1b - float(g0b32)) * float(inv)))
    dev = tris.device
    if not dev.is_cpu or nx * ny >= max_entries:  # (the kernels count and fill in one thread's order: CPU only)
        return None
    n = tris.shape[0] // 9
    frame = wp.array(np.array([o, U, V, F]), dtype=wp.vec3d, device=dev)
    grid = wp.vec3d(float(g0a32), float(g0b32), float(inv))
    counts = wp.zeros(nx * ny, dtype=wp.int32, device=dev)
    bad = wp.zeros(2, dtype=wp.int32, device=dev)
    none_f, none_i = wp.zeros(1, dtype=wp.float32, device=dev), wp.zeros(1, dtype=wp.int32, device=dev)
    args = [tris, frame, grid, nx, ny]
    # (the count stops once the projected boxes cover 4 times the room: a bound on its work)
    wp.launch(camera_bins_kernel, dim=n, device=dev, inputs=[*args, 0, 4 * (max_entries - nx * ny), counts, none_f,
                                                             none_i, bad])
    if bad.numpy()[0]:
        return None
    offs = np.zeros(nx * ny + 1, np.int64)
    np.cumsum(counts.numpy(), out=offs[1:])
    total = int(offs[-1])
    if nx * ny + total > max_entries:
        return None
    offs = offs.astype(np.int32)
    depth = wp.zeros(max(total, 1), dtype=wp.float32, device=dev)
    leaf = wp.zeros(max(total, 1), dtype=wp.int32, device=dev)
    counts.assign(offs[:-1])
    wp.launch(camera_bins_kernel, dim=n, device=dev, inputs=[*args, 1, 0, counts, depth, leaf, bad])
    offsets = wp.array(offs, dtype=wp.int32, device=dev)
    wp.launch(camera_bins_sort_kernel, dim=nx * ny, device=dev, inputs=[offsets, depth, leaf])
    first = BINS_HEAD + nx * ny + 1
    first += first & 1
    rec = np.zeros(first + 2 * total, np.float32)
    head = rec[:BINS_HEAD]
    head[0:3], head[3:6], head[6:9], head[9:12] = o32, U32, V32, F32
    head[12], head[13], head[14] = g0a32, g0b32, inv
    ints = rec.view(np.int32)
    ints[15], ints[16], ints[17] = nx, ny, first
    ints[BINS_HEAD:BINS_HEAD + nx * ny + 1] = offs
    pairs = rec[first:].reshape(-1, 2)
    pairs[:, 0] = depth.numpy()[:total]
    pairs.view(np.int32)[:, 1] = leaf.numpy()[:total]
    return rec
