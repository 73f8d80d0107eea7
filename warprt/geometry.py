"""Ray-shape intersection for the analytic shapes, and robust ray spawning (Warp device functions).

All rays carry a unit direction, so a ray parameter t is a distance. Each ``intersect_*`` returns
the nearest t in the open range (t_min, t_max), or -1.0 for a miss; a hit exactly at t_max is
excluded, as in ``wp.mesh_query_ray``. A ray parallel to a plane, rectangle or disk misses it, even
when it runs inside it.

Spawning secondary rays without self-intersection ("acne"): every hit point is first refined onto
its surface (spheres: projected to the radius; planar shapes and triangles: projected onto their
plane), so its error along the normal is a few ulps of the coordinates involved, not of the ray
length. Each hit also carries ``mag``, a per-component bound of the magnitudes those coordinates
had (a rectangle: |corner| + |edge1| + |edge2|, component by component). The new origin is moved
off the surface along the geometric normal by ``spawn_offset_n(ng, mag)`` = (|ng| · mag) · 2^-17:
the error bound projected on the normal, about 64 float32 ulps of it. The offset follows the
error, not the shape's size: a ground 800 units wide at y = 0 has mag_y = 0 and its rays leave
from (almost exactly) the surface, while a sphere far from the origin still gets an offset that
covers the ulps of its centre. ``spawn_offset(mag)`` (a scalar) is kept for steps along a ray.
"""

from __future__ import annotations

import warp as wp

from .accel import PacketF, PacketI

MISS = -1.0
SPAWN_REL = 1.0 / 131072.0  # 2^-17
SPAWN_ABS = 1.0e-30


@wp.func
def max_abs(v: wp.vec3) -> float:
    return wp.max(wp.abs(v[0]), wp.max(wp.abs(v[1]), wp.abs(v[2])))


@wp.func
def spawn_offset(mag: float) -> float:
    return mag * SPAWN_REL + SPAWN_ABS


@wp.func
def abs3(v: wp.vec3) -> wp.vec3:
    return wp.vec3(wp.abs(v[0]), wp.abs(v[1]), wp.abs(v[2]))


@wp.func
def spawn_offset_n(ng: wp.vec3, mag: wp.vec3) -> float:
    """Offset along the unit normal ``ng`` that clears a hit point whose coordinates were computed
    from values of per-component magnitude ``mag``: the bound projected on the normal."""
    return wp.dot(abs3(ng), mag) * SPAWN_REL + SPAWN_ABS


@wp.func
def spawn_origin(p: wp.vec3, ng: wp.vec3, mag: wp.vec3, side: float) -> wp.vec3:
    """p moved off its surface to the ``side`` (+1: along ng, -1: against it)."""
    return p + ng * (side * spawn_offset_n(ng, mag))


@wp.func
def quat_rotate_mag(q: wp.quat, m: wp.vec3) -> wp.vec3:
    """Per-component bound of the terms ``wp.quat_rotate(q, x)`` adds up for any x with |x| <= m:
    x (2w² - 1) + 2w (q × x) + 2 q (q · x), each term in absolute value. An axis-aligned rotation
    keeps a zero component zero; a general one spreads every component over all three."""
    a = wp.vec3(wp.abs(q[0]), wp.abs(q[1]), wp.abs(q[2]))
    w = wp.abs(q[3])
    cross_abs = wp.vec3(a[1] * m[2] + a[2] * m[1], a[2] * m[0] + a[0] * m[2], a[0] * m[1] + a[1] * m[0])
    return m * wp.abs(2.0 * w * w - 1.0) + cross_abs * (2.0 * w) + a * (2.0 * wp.dot(a, m))


@wp.func
def disk_extent(n: wp.vec3, r: float) -> wp.vec3:
    """Half-extent along each axis of a disk of radius r and unit normal n: r·sqrt(1 - n_i²)."""
    return wp.vec3(r * wp.sqrt(wp.max(0.0, 1.0 - n[0] * n[0])), r * wp.sqrt(wp.max(0.0, 1.0 - n[1] * n[1])),
                   r * wp.sqrt(wp.max(0.0, 1.0 - n[2] * n[2])))


@wp.func
def sphere_roots(o: wp.vec3, d: wp.vec3, c: wp.vec3, r: float) -> wp.vec2:
    """Both ray parameters where the ray meets the sphere (t0 <= t1), or (-inf, -inf) for a miss.

    Numerically careful form (Haines et al., Ray Tracing Gems ch. 7): the discriminant is taken
    from the perpendicular distance to the centre, and the smaller root from c/q.
    """
    f = o - c
    b = -wp.dot(f, d)
    l = f + b * d  # f - (f.d) d: centre-to-ray perpendicular
    disc = r * r - wp.dot(l, l)
    if disc < 0.0 or r <= 0.0:
        return wp.vec2(-1.0e38, -1.0e38)
    q = b + wp.where(b >= 0.0, wp.sqrt(disc), -wp.sqrt(disc))
    cc = wp.dot(f, f) - r * r
    t0 = float(0.0)
    t1 = float(0.0)
    if q == 0.0:
        t0 = 0.0
        t1 = 0.0
    else:
        t0 = cc / q
        t1 = q
    return wp.vec2(wp.min(t0, t1), wp.max(t0, t1))


@wp.func
def intersect_sphere(o: wp.vec3, d: wp.vec3, c: wp.vec3, r: float, t_min: float, t_max: float) -> float:
    roots = sphere_roots(o, d, c, r)
    if roots[0] > t_min and roots[0] < t_max:
        return roots[0]
    if roots[1] > t_min and roots[1] < t_max:
        return roots[1]
    return MISS


@wp.func
def intersect_plane(o: wp.vec3, d: wp.vec3, p0: wp.vec3, n: wp.vec3, t_min: float, t_max: float) -> float:
    denom = wp.dot(n, d)
    if denom == 0.0:
        return MISS
    t = wp.dot(n, p0 - o) / denom
    if t > t_min and t < t_max:
        return t
    return MISS



# The start of a packet's ray test on the CPU: its lanes' origins and directions loaded as clang
# vectors (``_LOAD_RAYS``), and with their lengths (``_PACKET_RAYS``, from the ``#if`` on); spliced
# into the snippets below, the compiled C++ the same as written out. ``_VMIN_VMAX``: Warp's CPU
# fmin / fmax lane by lane.
_LOAD_RAYS = r"""typedef float v8 __attribute__((ext_vector_type(8)));
typedef int i8 __attribute__((ext_vector_type(8)));
v8 Ox, Oy, Oz, Dx, Dy, Dz;
__builtin_memcpy(&Ox, &ox, 32); __builtin_memcpy(&Oy, &oy, 32); __builtin_memcpy(&Oz, &oz, 32);
__builtin_memcpy(&Dx, &dx, 32); __builtin_memcpy(&Dy, &dy, 32); __builtin_memcpy(&Dz, &dz, 32);
"""
_PACKET_RAYS = r"""#if defined(__clang__) && !defined(__CUDA_ARCH__)
""" + _LOAD_RAYS + r"""v8 Tm;
__builtin_memcpy(&Tm, &t_max, 32);"""
_VMIN_VMAX = r"""auto vmax = [](v8 a, v8 b) -> v8 { return a >= b ? a : (b == b ? b : a); };
auto vmin = [](v8 a, v8 b) -> v8 { return a <= b ? a : (b == b ? b : a); };
"""



# A leaf of the analytic BVH (a sphere or a rectangle, kind kk, row ii) against a camera packet's
# first n lanes at once, as ``trace_packet``'s loop over its lanes does it: each lane's bound (its
# nearest hit so far, widened by the tie rule where this shape would win a tie), the shape's hit
# in (t_min, bound) as ``intersect_sphere`` / ``intersect_rect`` find it, and the lane's nearest
# hit, kind and row replaced where the hit is nearer (or ties and wins). Returns the farthest
# nearest hit over the lanes (from 0, in lane order, as the loop takes it).
_LEAF_UPDATE = r"""
i8 act;
for (int l = 0; l < 8; ++l) act[l] = l < n ? -1 : 0;
v8 B; i8 K, I;
__builtin_memcpy(&B, &best, 32); __builtin_memcpy(&K, &kind, 32); __builtin_memcpy(&I, &index, 32);
const i8 first = (K != -1) & ((kk < K) | ((kk == K) & (ii < I)));
const v8 hi_t = first ? B * 1.0000002f + 1.0e-38f : B;
"""
_LEAF_STORE = r"""
const i8 upd = act & (t >= 0.0f) & ((t < B) | (first & (t == B)));
B = upd ? t : B; K = upd ? (i8)(kk) : K; I = upd ? (i8)(ii) : I;
__builtin_memcpy(&best, &B, 32); __builtin_memcpy(&kind, &K, 32); __builtin_memcpy(&index, &I, 32);
for (int l = 0; l < n; ++l) far = wp::max(far, B[l]);
"""
_LEAF_LANES = r"""
for (int l = 0; l < n; ++l) {
    const float b = best[l];
    const int k = kind[l];
    const bool first = k != -1 && (kk < k || (kk == k && ii < index[l]));
    const float hi_t = first ? b * 1.0000002f + 1.0e-38f : b;
    float t = -1.0f;
    @LANE_HIT@
    if (t >= 0.0f && (t < b || (first && t == b))) { best[l] = t; kind[l] = kk; index[l] = ii; }
    far = wp::max(far, best[l]);
}
"""

# ``sphere_roots`` for a packet's 8 rays (clang vectors; ``vmin``/``vmax`` as Warp's CPU fmin/fmax):
# each lane's roots lo <= hi of the sphere of radius r centred at c0 (+ dc·time when ``moving``),
# -1e38 for both where the ray misses it. Spliced into the sphere snippets below.
_SPHERE_ROOTS = r"""v8 cx = (v8)(c0[0]), cy = (v8)(c0[1]), cz = (v8)(c0[2]);
if (moving != 0) { cx = c0[0] + dc[0] * Tt; cy = c0[1] + dc[1] * Tt; cz = c0[2] + dc[2] * Tt; }
const v8 fx = Ox - cx, fy = Oy - cy, fz = Oz - cz;
const v8 b = -((fx * Dx + fy * Dy) + fz * Dz);
const v8 lx = fx + b * Dx, ly = fy + b * Dy, lz = fz + b * Dz;
const v8 disc = r * r - ((lx * lx + ly * ly) + lz * lz);
const v8 sq = __builtin_elementwise_sqrt(disc);
const v8 q = b + (b >= 0.0f ? sq : -sq);
const v8 cc = ((fx * fx + fy * fy) + fz * fz) - r * r;
const i8 zero_q = q == 0.0f;
const v8 t0 = zero_q ? (v8)(0.0f) : cc / q, t1 = zero_q ? (v8)(0.0f) : q;
const i8 miss = (disc < 0.0f) | (i8)(r <= 0.0f ? -1 : 0);
const v8 lo = miss ? (v8)(-1.0e38f) : vmin(t0, t1), hi = miss ? (v8)(-1.0e38f) : vmax(t0, t1);"""


_SPHERE_LEAF_PACKET = (r"""
float far = 0.0f;
#if defined(__clang__) && !defined(__CUDA_ARCH__)
""" + _LOAD_RAYS + r"""v8 Tt;
__builtin_memcpy(&Tt, &time, 32);
""" + _VMIN_VMAX + _LEAF_UPDATE + r"""
@SPHERE_ROOTS@
const v8 t = ((lo > t_min) & (lo < hi_t)) ? lo : (((hi > t_min) & (hi < hi_t)) ? hi : (v8)(-1.0f));
""" + _LEAF_STORE + r"""
#else
""" + _LEAF_LANES.replace("@LANE_HIT@", r"""{
        float cx = c0[0], cy = c0[1], cz = c0[2];
        if (moving != 0) { cx = c0[0] + dc[0] * time[l]; cy = c0[1] + dc[1] * time[l]; cz = c0[2] + dc[2] * time[l]; }
        const float fx = ox[l] - cx, fy = oy[l] - cy, fz = oz[l] - cz;
        const float bb = -((fx * dx[l] + fy * dy[l]) + fz * dz[l]);
        const float lx = fx + bb * dx[l], ly = fy + bb * dy[l], lz = fz + bb * dz[l];
        const float disc = r * r - ((lx * lx + ly * ly) + lz * lz);
        float lo = -1.0e38f, hi = -1.0e38f;
        if (!(disc < 0.0f || r <= 0.0f)) {
            const float q = bb + (bb >= 0.0f ? sqrtf(disc) : -sqrtf(disc));
            const float cc = ((fx * fx + fy * fy) + fz * fz) - r * r;
            const float t0 = q == 0.0f ? 0.0f : cc / q, t1 = q == 0.0f ? 0.0f : q;
            lo = wp::min(t0, t1); hi = wp::max(t0, t1);
        }
        if (lo > t_min && lo < hi_t) t = lo;
        else if (hi > t_min && hi < hi_t) t = hi;
    }""") + r"""
#endif
return far;
""").replace("@SPHERE_ROOTS@", _SPHERE_ROOTS)


@wp.func_native(_SPHERE_LEAF_PACKET)
def sphere_leaf_packet(c0: wp.vec3, dc: wp.vec3, moving: int, r: float, kk: int, ii: int, n: int, t_min: float,
                       ox: PacketF, oy: PacketF, oz: PacketF, dx: PacketF, dy: PacketF, dz: PacketF, time: PacketF,
                       best: wp.ref[PacketF], kind: wp.ref[PacketI], index: wp.ref[PacketI]) -> float:
    """The sphere (centre c0, + dc·time when ``moving``) as a leaf for the packet's lanes (see above)."""
    ...


_RECT_LEAF_PACKET = (r"""
float far = 0.0f;
const float n0 = e1[1] * e2[2] - e1[2] * e2[1], n1 = e1[2] * e2[0] - e1[0] * e2[2], n2 = e1[0] * e2[1] - e1[1] * e2[0];
const float nn = (n0 * n0 + n1 * n1) + n2 * n2;
#if defined(__clang__) && !defined(__CUDA_ARCH__)
""" + _LOAD_RAYS + _LEAF_UPDATE + r"""
const v8 denom = (n0 * Dx + n1 * Dy) + n2 * Dz;
const v8 tp = ((n0 * (c[0] - Ox) + n1 * (c[1] - Oy)) + n2 * (c[2] - Oz)) / denom;
const v8 rx = (Ox + tp * Dx) - c[0], ry = (Oy + tp * Dy) - c[1], rz = (Oz + tp * Dz) - c[2];
const v8 ax = ry * e2[2] - rz * e2[1], ay = rz * e2[0] - rx * e2[2], az = rx * e2[1] - ry * e2[0];
const v8 a = ((ax * n0 + ay * n1) + az * n2) / nn;
const v8 bx = e1[1] * rz - e1[2] * ry, by = e1[2] * rx - e1[0] * rz, bz = e1[0] * ry - e1[1] * rx;
const v8 b = ((bx * n0 + by * n1) + bz * n2) / nn;
const i8 ok = (denom != 0.0f) & (tp > t_min) & (tp < hi_t) & (a >= 0.0f) & (a <= 1.0f) & (b >= 0.0f) & (b <= 1.0f);
const v8 t = ok ? tp : (v8)(-1.0f);
""" + _LEAF_STORE + r"""
#else
""" + _LEAF_LANES.replace("@LANE_HIT@", r"""{
        const float denom = (n0 * dx[l] + n1 * dy[l]) + n2 * dz[l];
        if (denom != 0.0f) {
            const float tp = ((n0 * (c[0] - ox[l]) + n1 * (c[1] - oy[l])) + n2 * (c[2] - oz[l])) / denom;
            if (tp > t_min && tp < hi_t) {
                const float rx = (ox[l] + tp * dx[l]) - c[0], ry = (oy[l] + tp * dy[l]) - c[1];
                const float rz = (oz[l] + tp * dz[l]) - c[2];
                const float ax = ry * e2[2] - rz * e2[1], ay = rz * e2[0] - rx * e2[2], az = rx * e2[1] - ry * e2[0];
                const float a = ((ax * n0 + ay * n1) + az * n2) / nn;
                const float bx = e1[1] * rz - e1[2] * ry, by = e1[2] * rx - e1[0] * rz, bz = e1[0] * ry - e1[1] * rx;
                const float b2 = ((bx * n0 + by * n1) + bz * n2) / nn;
                if (a >= 0.0f && a <= 1.0f && b2 >= 0.0f && b2 <= 1.0f) t = tp;
            }
        }
    }""") + r"""
#endif
return far;
""")


@wp.func_native(_RECT_LEAF_PACKET)
def rect_leaf_packet(c: wp.vec3, e1: wp.vec3, e2: wp.vec3, kk: int, ii: int, n: int, t_min: float, ox: PacketF,
                     oy: PacketF, oz: PacketF, dx: PacketF, dy: PacketF, dz: PacketF, best: wp.ref[PacketF],
                     kind: wp.ref[PacketI], index: wp.ref[PacketI]) -> float:
    """The parallelogram c + a e1 + b e2 as a leaf for the packet's lanes (see above)."""
    ...


_PLANE_LEAF_PACKET = (r"""
float far = 0.0f;
#if defined(__clang__) && !defined(__CUDA_ARCH__)
""" + _LOAD_RAYS + _LEAF_UPDATE + r"""
const v8 denom = (pn[0] * Dx + pn[1] * Dy) + pn[2] * Dz;
const v8 tp = ((pn[0] * (p0[0] - Ox) + pn[1] * (p0[1] - Oy)) + pn[2] * (p0[2] - Oz)) / denom;
const v8 t = ((denom != 0.0f) & (tp > t_min) & (tp < hi_t)) ? tp : (v8)(-1.0f);
""" + _LEAF_STORE + r"""
#else
""" + _LEAF_LANES.replace("@LANE_HIT@", r"""{
        const float denom = (pn[0] * dx[l] + pn[1] * dy[l]) + pn[2] * dz[l];
        if (denom != 0.0f) {
            const float tp = ((pn[0] * (p0[0] - ox[l]) + pn[1] * (p0[1] - oy[l])) + pn[2] * (p0[2] - oz[l])) / denom;
            if (tp > t_min && tp < hi_t) t = tp;
        }
    }""") + r"""
#endif
return far;
""")


@wp.func_native(_PLANE_LEAF_PACKET)
def plane_leaf_packet(p0: wp.vec3, pn: wp.vec3, kk: int, ii: int, n: int, t_min: float, ox: PacketF, oy: PacketF,
                      oz: PacketF, dx: PacketF, dy: PacketF, dz: PacketF, best: wp.ref[PacketF],
                      kind: wp.ref[PacketI], index: wp.ref[PacketI]) -> float:
    """The plane through p0 of normal pn for the packet's lanes, as ``intersect_plane`` in the loops
    over the shapes (see above)."""
    ...

# Shadow rays of a camera packet's 8 shading points met by one sphere or one plane at once, as
# clang vectors on the CPU: ``sphere_roots`` and ``intersect_plane``'s operations in the same order
# (Warp's CPU fmin / fmax for the roots' order; Warp's C++ compiler fuses nothing), so a lane is
# blocked exactly when the scalar test says so. On CUDA the same operations lane by lane.
_SPHERE_HITS_PACKET = r"""
int res = 0;
if (!(r <= 0.0f)) {
@PACKET_RAYS@
v8 Tt;
__builtin_memcpy(&Tt, &time, 32);
@VMIN_VMAX@@SPHERE_ROOTS@
const i8 hit = ((lo > 0.0f) & (lo < Tm)) | ((hi > 0.0f) & (hi < Tm));
for (int l = 0; l < 8; ++l) res |= ((lanes >> l) & 1) && hit[l] ? 1 << l : 0;
#else
for (int l = 0; l < 8; ++l) {
    if (!((lanes >> l) & 1)) continue;
    float cx = c0[0], cy = c0[1], cz = c0[2];
    if (moving != 0) { cx = c0[0] + dc[0] * time[l]; cy = c0[1] + dc[1] * time[l]; cz = c0[2] + dc[2] * time[l]; }
    const float fx = ox[l] - cx, fy = oy[l] - cy, fz = oz[l] - cz;
    const float b = -((fx * dx[l] + fy * dy[l]) + fz * dz[l]);
    const float lx = fx + b * dx[l], ly = fy + b * dy[l], lz = fz + b * dz[l];
    const float disc = r * r - ((lx * lx + ly * ly) + lz * lz);
    if (disc < 0.0f) continue;
    const float q = b + (b >= 0.0f ? sqrtf(disc) : -sqrtf(disc));
    if (q == 0.0f) continue;
    const float t0 = (((fx * fx + fy * fy) + fz * fz) - r * r) / q, t1 = q;
    const float lo = wp::min(t0, t1), hi = wp::max(t0, t1);
    if ((lo > 0.0f && lo < t_max[l]) || (hi > 0.0f && hi < t_max[l])) res |= 1 << l;
}
#endif
}
return res;
""".replace("@PACKET_RAYS@\n", _PACKET_RAYS + "\n").replace("@VMIN_VMAX@", _VMIN_VMAX).replace(
    "@SPHERE_ROOTS@", _SPHERE_ROOTS)


@wp.func_native(_SPHERE_HITS_PACKET)
def sphere_hits_packet(c0: wp.vec3, dc: wp.vec3, moving: int, r: float, lanes: int, ox: PacketF, oy: PacketF,
                       oz: PacketF, dx: PacketF, dy: PacketF, dz: PacketF, t_max: PacketF, time: PacketF) -> int:
    """The lanes (of the bit mask ``lanes``) whose ray (o, d) meets the sphere of radius r, centre
    c0 (+ dc·time when ``moving``), in (0, t_max): where ``sphere_roots`` has a root there."""
    ...


# The cell of a point light's buffer (``accel.light_buffer``) holding the direction from the light
# at p to each lane's origin, as an index into ``SceneData.lb_cells`` (the buffer's first cell
# cell0, res² cells a face): the face of the direction's largest component (x over y over z where
# they tie), its other two over that one's size, in [-1, 1], binned. Returns the lanes (of the bit
# mask ``lanes``) whose origin lies within ``reach`` of the light and not at it; the others' cells
# are undefined.
_LIGHT_CELLS = r"""
int res = 0;
#if defined(__clang__) && !defined(__CUDA_ARCH__)
typedef float v8 __attribute__((ext_vector_type(8)));
typedef int i8 __attribute__((ext_vector_type(8)));
v8 Ox, Oy, Oz;
__builtin_memcpy(&Ox, &ox, 32); __builtin_memcpy(&Oy, &oy, 32); __builtin_memcpy(&Oz, &oz, 32);
const v8 Vx = Ox - p[0], Vy = Oy - p[1], Vz = Oz - p[2];
const v8 ax = Vx < 0.0f ? -Vx : Vx, ay = Vy < 0.0f ? -Vy : Vy, az = Vz < 0.0f ? -Vz : Vz;
const i8 fx = (ax >= ay) & (ax >= az);
const i8 fy = ~fx & (ay >= az);
const v8 m = fx ? ax : (fy ? ay : az);
const v8 va = fx ? Vx : (fy ? Vy : Vz);
const i8 ok = (((Vx * Vx + Vy * Vy) + Vz * Vz) <= reach * reach) & (m > 0.0f);
const v8 ms = ok ? m : 1.0f;
const v8 tu = ok ? (fx ? Vy : (fy ? Vz : Vx)) : 0.0f;
const v8 tv = ok ? (fx ? Vz : (fy ? Vx : Vy)) : 0.0f;
const i8 face = (fx ? 0 : (fy ? 2 : 4)) + (va < 0.0f ? 1 : 0);
const float half = 0.5f * (float)n;
i8 col = __builtin_convertvector((tu / ms + 1.0f) * half, i8);
i8 row = __builtin_convertvector((tv / ms + 1.0f) * half, i8);
col = col < n - 1 ? col : n - 1;
row = row < n - 1 ? row : n - 1;
const i8 cell = cell0 + (face * n + row) * n + col;
__builtin_memcpy(&cells, &cell, 32);
for (int l = 0; l < 8; ++l) res |= ((lanes >> l) & 1) && ok[l] ? 1 << l : 0;
#else
for (int l = 0; l < 8; ++l) {
    if (!((lanes >> l) & 1)) continue;
    const float vx = ox[l] - p[0], vy = oy[l] - p[1], vz = oz[l] - p[2];
    const float ax = fabsf(vx), ay = fabsf(vy), az = fabsf(vz);
    const bool fx = ax >= ay && ax >= az, fy = !fx && ay >= az;
    const float m = fx ? ax : (fy ? ay : az);
    if (!((vx * vx + vy * vy) + vz * vz <= reach * reach) || !(m > 0.0f)) continue;
    const float va = fx ? vx : (fy ? vy : vz), tu = fx ? vy : (fy ? vz : vx), tv = fx ? vz : (fy ? vx : vy);
    const int face = (fx ? 0 : (fy ? 2 : 4)) + (va < 0.0f ? 1 : 0);
    const float half = 0.5f * (float)n;
    int col = (int)((tu / m + 1.0f) * half), row = (int)((tv / m + 1.0f) * half);
    col = col < n - 1 ? col : n - 1;
    row = row < n - 1 ? row : n - 1;
    cells[l] = cell0 + (face * n + row) * n + col;
    res |= 1 << l;
}
#endif
return res;
"""


@wp.func_native(_LIGHT_CELLS)
def light_cells(p: wp.vec3, reach: float, n: int, cell0: int, lanes: int, ox: PacketF, oy: PacketF, oz: PacketF,
                cells: wp.ref[PacketI]) -> int:
    """The lanes (of ``lanes``) within ``reach`` of a point light at p with a light buffer of n × n
    cells a face from cell ``cell0``, each one's cell in ``cells`` (see above)."""
    ...


_PLANE_HITS_PACKET = r"""
int res = 0;
@PACKET_RAYS@
const v8 denom = (n[0] * Dx + n[1] * Dy) + n[2] * Dz;
const v8 t = ((n[0] * (p0[0] - Ox) + n[1] * (p0[1] - Oy)) + n[2] * (p0[2] - Oz)) / denom;
const i8 hit = (denom != 0.0f) & (t > 0.0f) & (t < Tm);
for (int l = 0; l < 8; ++l) res |= ((lanes >> l) & 1) && hit[l] ? 1 << l : 0;
#else
for (int l = 0; l < 8; ++l) {
    if (!((lanes >> l) & 1)) continue;
    const float denom = (n[0] * dx[l] + n[1] * dy[l]) + n[2] * dz[l];
    if (denom == 0.0f) continue;
    const float t = ((n[0] * (p0[0] - ox[l]) + n[1] * (p0[1] - oy[l])) + n[2] * (p0[2] - oz[l])) / denom;
    if (t > 0.0f && t < t_max[l]) res |= 1 << l;
}
#endif
return res;
""".replace("@PACKET_RAYS@", _PACKET_RAYS)


@wp.func_native(_PLANE_HITS_PACKET)
def plane_hits_packet(p0: wp.vec3, n: wp.vec3, lanes: int, ox: PacketF, oy: PacketF, oz: PacketF, dx: PacketF,
                      dy: PacketF, dz: PacketF, t_max: PacketF) -> int:
    """The lanes (of the bit mask ``lanes``) whose ray (o, d) meets the plane through p0 of normal n
    in (0, t_max), as ``intersect_plane(o, d, p0, n, 0, t_max) >= 0`` says."""
    ...


_RECT_HITS_PACKET = r"""
int res = 0;
// intersect_rect's uniform parts: n = cross(e1, e2) and n·n
const float n0 = e1[1] * e2[2] - e1[2] * e2[1], n1 = e1[2] * e2[0] - e1[0] * e2[2], n2 = e1[0] * e2[1] - e1[1] * e2[0];
const float nn = (n0 * n0 + n1 * n1) + n2 * n2;
@PACKET_RAYS@
const v8 denom = (n0 * Dx + n1 * Dy) + n2 * Dz;
const v8 num = (n0 * (c[0] - Ox) + n1 * (c[1] - Oy)) + n2 * (c[2] - Oz);
// t > 0 needs num and denom of one sign: where no lane has that (no lane meets the plane ahead,
// as a shadow ray leaving a surface on the light's side of it), none meets the rectangle
i8 lane_on;
for (int l = 0; l < 8; ++l) lane_on[l] = (lanes >> l) & 1 ? -1 : 0;
if (!__builtin_reduce_or(lane_on & (((num > 0.0f) & (denom > 0.0f)) | ((num < 0.0f) & (denom < 0.0f))))) return 0;
const v8 t = num / denom;
i8 hit = (denom != 0.0f) & (t > 0.0f) & (t < Tm);
const v8 rx = (Ox + t * Dx) - c[0], ry = (Oy + t * Dy) - c[1], rz = (Oz + t * Dz) - c[2];
// cross(rel, e2) and cross(e1, rel), each dotted with n, over n·n
const v8 ax = ry * e2[2] - rz * e2[1], ay = rz * e2[0] - rx * e2[2], az = rx * e2[1] - ry * e2[0];
const v8 a = ((ax * n0 + ay * n1) + az * n2) / nn;
const v8 bx = e1[1] * rz - e1[2] * ry, by = e1[2] * rx - e1[0] * rz, bz = e1[0] * ry - e1[1] * rx;
const v8 b = ((bx * n0 + by * n1) + bz * n2) / nn;
hit &= (a >= 0.0f) & (a <= 1.0f) & (b >= 0.0f) & (b <= 1.0f);
for (int l = 0; l < 8; ++l) res |= ((lanes >> l) & 1) && hit[l] ? 1 << l : 0;
#else
for (int l = 0; l < 8; ++l) {
    if (!((lanes >> l) & 1)) continue;
    const float denom = (n0 * dx[l] + n1 * dy[l]) + n2 * dz[l];
    if (denom == 0.0f) continue;
    const float t = ((n0 * (c[0] - ox[l]) + n1 * (c[1] - oy[l])) + n2 * (c[2] - oz[l])) / denom;
    if (!(t > 0.0f && t < t_max[l])) continue;
    const float rx = (ox[l] + t * dx[l]) - c[0], ry = (oy[l] + t * dy[l]) - c[1], rz = (oz[l] + t * dz[l]) - c[2];
    const float ax = ry * e2[2] - rz * e2[1], ay = rz * e2[0] - rx * e2[2], az = rx * e2[1] - ry * e2[0];
    const float a = ((ax * n0 + ay * n1) + az * n2) / nn;
    const float bx = e1[1] * rz - e1[2] * ry, by = e1[2] * rx - e1[0] * rz, bz = e1[0] * ry - e1[1] * rx;
    const float b = ((bx * n0 + by * n1) + bz * n2) / nn;
    if (a >= 0.0f && a <= 1.0f && b >= 0.0f && b <= 1.0f) res |= 1 << l;
}
#endif
return res;
""".replace("@PACKET_RAYS@", _PACKET_RAYS)


@wp.func_native(_RECT_HITS_PACKET)
def rect_hits_packet(c: wp.vec3, e1: wp.vec3, e2: wp.vec3, lanes: int, ox: PacketF, oy: PacketF, oz: PacketF,
                     dx: PacketF, dy: PacketF, dz: PacketF, t_max: PacketF) -> int:
    """The lanes (of the bit mask ``lanes``) whose ray (o, d) meets the parallelogram c + a e1 + b e2
    in (0, t_max), as ``intersect_rect(o, d, c, e1, e2, 0, t_max) >= 0`` says."""
    ...

@wp.func
def intersect_rect(o: wp.vec3, d: wp.vec3, corner: wp.vec3, e1: wp.vec3, e2: wp.vec3,
                   t_min: float, t_max: float) -> float:
    """Parallelogram corner + a e1 + b e2, a, b in [0, 1]."""
    n = wp.cross(e1, e2)
    denom = wp.dot(n, d)
    if denom == 0.0:
        return MISS
    t = wp.dot(n, corner - o) / denom
    if not (t > t_min and t < t_max):
        return MISS
    rel = o + t * d - corner
    nn = wp.dot(n, n)
    a = wp.dot(wp.cross(rel, e2), n) / nn
    b = wp.dot(wp.cross(e1, rel), n) / nn
    # written to reject NaN: for a tiny rectangle n·n underflows to 0 and a = 0/0
    if not (a >= 0.0 and a <= 1.0 and b >= 0.0 and b <= 1.0):
        return MISS
    return t


@wp.func
def intersect_disk(o: wp.vec3, d: wp.vec3, c: wp.vec3, n: wp.vec3, r: float, t_min: float, t_max: float) -> float:
    t = intersect_plane(o, d, c, n, t_min, t_max)
    if t == MISS:
        return MISS
    rel = o + t * d - c
    if r <= 0.0 or not (wp.dot(rel, rel) <= r * r):
        return MISS  # a zero-radius disk is never hit, like a zero-radius sphere
    return t


@wp.func
def refine_on_sphere(p: wp.vec3, c: wp.vec3, r: float) -> wp.vec3:
    v = p - c
    len_v = wp.length(v)
    if len_v == 0.0:
        return p
    return c + v * (r / len_v)


@wp.func
def refine_on_plane(p: wp.vec3, p0: wp.vec3, n_unit: wp.vec3) -> wp.vec3:
    return p - n_unit * wp.dot(p - p0, n_unit)


@wp.func
def ray_box(o: wp.vec3, inv_d: wp.vec3, lo: wp.vec3, hi: wp.vec3, t_min: float, t_max: float) -> bool:
    """Whether the ray o + t·d (``inv_d`` = 1/d per component) meets the box [lo, hi] for some t
    in [t_min, t_max] (slab test; the far distance is widened by 3 ulps·3 as pbrt-v4 does, and
    callers pad their boxes, so rounding never culls a real hit)."""
    t0 = wp.cw_mul(lo - o, inv_d)
    t1 = wp.cw_mul(hi - o, inv_d)
    tn = wp.min(t0, t1)
    tf = wp.max(t0, t1)
    near = wp.max(wp.max(tn[0], tn[1]), wp.max(tn[2], t_min))
    far = wp.min(wp.min(tf[0], tf[1]), wp.min(tf[2], t_max))
    return near <= far * 1.0000004


# A packet's rays against one box at once, as clang vectors on the CPU: ``ray_box`` with
# inv_d = 1/d, the same operations in the same order (Warp's CPU fmin / fmax), so a
# lane passes exactly when the scalar test passes. On CUDA the same operations lane by lane.
_BOX_HITS_PACKET = r"""
int res = 0;
@PACKET_RAYS@
auto vmax = [](v8 a, v8 b) -> v8 { return a >= b ? a : (b == b ? b : a); };
auto vmin = [](v8 a, v8 b) -> v8 { return a <= b ? a : (b == b ? b : a); };
const v8 ix = 1.0f / Dx, iy = 1.0f / Dy, iz = 1.0f / Dz;
const v8 ax = (lo[0] - Ox) * ix, ay = (lo[1] - Oy) * iy, az = (lo[2] - Oz) * iz;
const v8 bx = (hi[0] - Ox) * ix, by = (hi[1] - Oy) * iy, bz = (hi[2] - Oz) * iz;
const v8 near = vmax(vmax(vmin(ax, bx), vmin(ay, by)), vmax(vmin(az, bz), (v8)(t_min)));
const v8 far = vmin(vmin(vmax(ax, bx), vmax(ay, by)), vmin(vmax(az, bz), Tm));
const i8 hit = near <= far * 1.0000004f;
for (int l = 0; l < 8; ++l) res |= ((lanes >> l) & 1) && hit[l] ? 1 << l : 0;
#else
for (int l = 0; l < 8; ++l) {
    if (!((lanes >> l) & 1)) continue;
    const float ix = 1.0f / dx[l], iy = 1.0f / dy[l], iz = 1.0f / dz[l];
    const float ax = (lo[0] - ox[l]) * ix, ay = (lo[1] - oy[l]) * iy, az = (lo[2] - oz[l]) * iz;
    const float bx = (hi[0] - ox[l]) * ix, by = (hi[1] - oy[l]) * iy, bz = (hi[2] - oz[l]) * iz;
    const float near = wp::max(wp::max(wp::min(ax, bx), wp::min(ay, by)), wp::max(wp::min(az, bz), t_min));
    const float far = wp::min(wp::min(wp::max(ax, bx), wp::max(ay, by)), wp::min(wp::max(az, bz), t_max[l]));
    if (near <= far * 1.0000004f) res |= 1 << l;
}
#endif
return res;
""".replace("@PACKET_RAYS@", _PACKET_RAYS)


@wp.func_native(_BOX_HITS_PACKET)
def box_hits_packet(lo: wp.vec3, hi: wp.vec3, lanes: int, ox: PacketF, oy: PacketF, oz: PacketF, dx: PacketF,
                    dy: PacketF, dz: PacketF, t_min: float, t_max: PacketF) -> int:
    """The lanes (of the bit mask ``lanes``) whose ray (o, d) meets the box [lo, hi] in [t_min, t_max],
    as ``ray_box(o, 1/d, lo, hi, t_min, t_max)`` says."""
    ...


# A packet's shadow rays from origins o to targets y, as ``shadow`` sets them up: the unit
# direction and the length (|y - o| - stop) of each lane in ``lanes`` whose target is farther
# than ``stop`` (its bit in the result; a nearer target is lit without a test).
_SHADOW_RAYS_PACKET = r"""
int res = 0;
#if defined(__clang__) && !defined(__CUDA_ARCH__)
typedef float v8 __attribute__((ext_vector_type(8)));
typedef int i8 __attribute__((ext_vector_type(8)));
v8 Ox, Oy, Oz, Yx, Yy, Yz;
__builtin_memcpy(&Ox, &ox, 32); __builtin_memcpy(&Oy, &oy, 32); __builtin_memcpy(&Oz, &oz, 32);
__builtin_memcpy(&Yx, &yx, 32); __builtin_memcpy(&Yy, &yy, 32); __builtin_memcpy(&Yz, &yz, 32);
const v8 tx = Yx - Ox, ty = Yy - Oy, tz = Yz - Oz;
const v8 dist = __builtin_elementwise_sqrt((tx * tx + ty * ty) + tz * tz);
const i8 test = ~(dist <= stop);
const v8 sx = tx / dist, sy = ty / dist, sz = tz / dist, st = dist - stop;
__builtin_memcpy(&out_dx, &sx, 32); __builtin_memcpy(&out_dy, &sy, 32); __builtin_memcpy(&out_dz, &sz, 32);
__builtin_memcpy(&out_t, &st, 32);
for (int l = 0; l < 8; ++l) res |= ((lanes >> l) & 1) && test[l] ? 1 << l : 0;
#else
for (int l = 0; l < 8; ++l) {
    if (!((lanes >> l) & 1)) continue;
    const float tx = yx[l] - ox[l], ty = yy[l] - oy[l], tz = yz[l] - oz[l];
    const float dist = sqrtf((tx * tx + ty * ty) + tz * tz);
    if (dist <= stop) continue;
    out_dx[l] = tx / dist; out_dy[l] = ty / dist; out_dz[l] = tz / dist; out_t[l] = dist - stop;
    res |= 1 << l;
}
#endif
return res;
"""


@wp.func_native(_SHADOW_RAYS_PACKET)
def shadow_rays_packet(lanes: int, ox: PacketF, oy: PacketF, oz: PacketF, yx: PacketF, yy: PacketF, yz: PacketF,
                       stop: float, out_dx: wp.ref[PacketF], out_dy: wp.ref[PacketF], out_dz: wp.ref[PacketF],
                       out_t: wp.ref[PacketF]) -> int:
    """See above."""
    ...


# --- the posed solids (boxes, capsules, cylinders), in their own frame ----------------------------
# Each ``*_roots`` gives the interval of the ray (o, d) inside the solid as (t_in, t_out, code_in,
# code_out), t_in > t_out when the ray misses it. Codes say which surface the ray crosses there:
# the slab axis (0, 1, 2) for a box, 1 for a cylinder's cap and 0 for its side.

SOLID_BIG = 3.0e38


@wp.func(inline=True)
def box_roots(o: wp.vec3, d: wp.vec3, h: wp.vec3) -> wp.vec4:
    """The box |x_k| <= h_k: slab by slab (a ray parallel to a slab is inside it everywhere or
    nowhere; no 0 · inf)."""
    tn = float(-SOLID_BIG)
    tf = float(SOLID_BIG)
    an = float(0.0)
    af = float(0.0)
    for k in range(3):
        if d[k] == 0.0:
            if wp.abs(o[k]) > h[k]:
                return wp.vec4(SOLID_BIG, -SOLID_BIG, 0.0, 0.0)
        else:
            inv = 1.0 / d[k]
            t0 = (-h[k] - o[k]) * inv
            t1 = (h[k] - o[k]) * inv
            lo = wp.min(t0, t1)
            hi = wp.max(t0, t1)
            if lo > tn:
                tn = lo
                an = float(k)
            if hi < tf:
                tf = hi
                af = float(k)
    return wp.vec4(tn, tf, an, af)


@wp.func(inline=True)
def tube_roots(o: wp.vec3, d: wp.vec3, r: float) -> wp.vec2:
    """The infinite solid cylinder x² + z² <= r², in the form of ``sphere_roots``: the chord from
    the ray's closest approach to the axis (no cancellation in the discriminant), the root nearer
    0 from the product of the roots. (SOLID_BIG, -SOLID_BIG) for a miss; a ray along the axis
    inside the cylinder is inside it everywhere."""
    a = d[0] * d[0] + d[2] * d[2]
    c = o[0] * o[0] + o[2] * o[2] - r * r
    if r <= 0.0:
        return wp.vec2(SOLID_BIG, -SOLID_BIG)
    if a == 0.0:
        if c > 0.0:
            return wp.vec2(SOLID_BIG, -SOLID_BIG)
        return wp.vec2(-SOLID_BIG, SOLID_BIG)
    tc = -(o[0] * d[0] + o[2] * d[2]) / a
    lx = o[0] + tc * d[0]
    lz = o[2] + tc * d[2]
    disc = r * r - (lx * lx + lz * lz)
    if disc < 0.0:
        return wp.vec2(SOLID_BIG, -SOLID_BIG)
    hc = wp.sqrt(disc / a)
    q = tc + wp.where(tc >= 0.0, hc, -hc)  # the root farther from 0
    other = float(0.0)
    if q != 0.0:
        other = (c / a) / q
    return wp.vec2(wp.min(q, other), wp.max(q, other))


@wp.func(inline=True)
def cylinder_roots(o: wp.vec3, d: wp.vec3, r: float, h: float) -> wp.vec4:
    """The closed cylinder x² + z² <= r², |y| <= h: the tube cut by the slab of the caps."""
    side = tube_roots(o, d, r)
    s0 = float(-SOLID_BIG)
    s1 = float(SOLID_BIG)
    if d[1] == 0.0:
        if wp.abs(o[1]) > h:
            return wp.vec4(SOLID_BIG, -SOLID_BIG, 0.0, 0.0)
    else:
        t0 = (-h - o[1]) / d[1]
        t1 = (h - o[1]) / d[1]
        s0 = wp.min(t0, t1)
        s1 = wp.max(t0, t1)
    tin = side[0]
    tout = side[1]
    cin = float(0.0)
    cout = float(0.0)
    if s0 > tin:
        tin = s0
        cin = 1.0
    if s1 < tout:
        tout = s1
        cout = 1.0
    return wp.vec4(tin, tout, cin, cout)


@wp.func(inline=True)
def capsule_roots(o: wp.vec3, d: wp.vec3, r: float, h: float) -> wp.vec4:
    """The capsule (points within r of the segment (0, ±h, 0)): a convex union of the open
    cylinder and two balls, so its interval is the hull of theirs."""
    body = cylinder_roots(o, d, r, h)
    tin = body[0]
    tout = body[1]
    if tin > tout:
        tin = SOLID_BIG
        tout = -SOLID_BIG
    for k in range(2):
        ends = sphere_roots(o, d, wp.vec3(0.0, h * (2.0 * float(k) - 1.0), 0.0), r)
        if ends[0] > -1.0e38:
            tin = wp.min(tin, ends[0])
            tout = wp.max(tout, ends[1])
    return wp.vec4(tin, tout, 0.0, 0.0)


@wp.func(inline=True)
def interval_hit(iv: wp.vec4, t_min: float, t_max: float) -> float:
    """The first boundary of the interval (iv[0], iv[1]) in the open range (t_min, t_max), or MISS."""
    if not (iv[0] <= iv[1]):
        return MISS
    if iv[0] > t_min and iv[0] < t_max:
        return iv[0]
    if iv[1] > t_min and iv[1] < t_max:
        return iv[1]
    return MISS
