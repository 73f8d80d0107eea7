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
