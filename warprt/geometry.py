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
