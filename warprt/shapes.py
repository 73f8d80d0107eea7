"""The analytic shape kinds, one entry each: description class, tag, device table and record,
how a description becomes a record, and (for shapes that can emit) how to sample a point of
it as seen from a shading point.

Bounded kinds also give their bounds: from ``ANALYTIC_BVH_MIN`` bounded shapes on, the builder
puts them all in one BVH that ``trace`` walks instead of looping over each table.

An area light is emission on a shape: ``RectLight``, ``SphereLight`` and ``DiskLight`` give
their surface through ``.shape()``, the builder puts that surface in its kind's table with an
emitting material, and an ``AreaLightRec`` names (kind tag, row). Light code never looks at
the kind: ``sample_emitter`` below does. Intersection routines live in ``geometry``; the loops
over each kind's table in ``trace``. Meshes are instances of ``wp.Mesh`` assets, built by
``build`` (see ``meshes``), not rows of this table.
"""

from __future__ import annotations

import math
import textwrap
from dataclasses import dataclass
from typing import Callable

import numpy as np
import warp as wp

from .accel import PacketF
from .geometry import intersect_sphere, max_abs
from .records import (
    KIND_BOX, KIND_CAPSULE, KIND_CYLINDER, KIND_DISK, KIND_PLANE, KIND_RECT, KIND_SPHERE, DiskRec, PlaneRec, RectRec,
    SceneData, SolidRec, SphereRec,
)
from .sampling import (
    GridWarp, SphRect, frame_from_z, grid_warp_sample, grid_warp_setup, is_rectangle_edges, sphrect_sample,
    sphrect_setup, square_to_cone, square_to_disk,
)
from .scene.description import Box, Capsule, Cylinder, Disk, Plane, Rectangle, Sphere
from .scene.transform import quaternion_matrix


def _unit(v) -> tuple[float, float, float]:
    v = np.asarray(v, dtype=np.float64)
    return tuple(float(c) for c in v / np.linalg.norm(v))  # type: ignore[return-value]


def _sphere_row(s: Sphere, mat: int) -> dict:
    c0, c1, r = s.world()
    return dict(c0=c0, c1=c1, r=r, mat=mat)


def _plane_row(s: Plane, mat: int) -> dict:
    p, n = s.world()
    return dict(p=p, n=n, mat=mat)


def _rect_row(s: Rectangle, mat: int) -> dict:
    c, e1, e2 = s.world()
    return dict(c=c, e1=e1, e2=e2, n=_unit(np.cross(e1, e2)), mat=mat)


def _disk_row(s: Disk, mat: int) -> dict:
    return dict(c=s.center, n=_unit(s.normal), r=s.radius, mat=mat)


def _sphere_bounds(row: dict) -> tuple[np.ndarray, np.ndarray]:
    c0, c1, r = np.asarray(row["c0"], np.float64), np.asarray(row["c1"], np.float64), row["r"]
    return np.minimum(c0, c1) - r, np.maximum(c0, c1) + r  # swept over the motion


RECT_MAX_PIECES = 8  # a long thin rectangle is boxed in the BVH as up to this many pieces


def _rect_bounds(row: dict) -> tuple[np.ndarray, np.ndarray]:
    c, e1, e2 = (np.asarray(row[k], np.float64) for k in ("c", "e1", "e2"))
    corners = np.array([c, c + e1, c + e2, c + e1 + e2])
    return corners.min(axis=0), corners.max(axis=0)


def rect_pieces(row: dict, max_pieces: int = RECT_MAX_PIECES) -> list[tuple[np.ndarray, np.ndarray]]:
    """Boxes covering a rectangle in pieces along its longer edge, about as long as it is wide
    (at most ``max_pieces``): one box around a long bar tilted off the axes is mostly empty, and
    every ray through that emptiness would be tested against it. A ray may meet the rectangle
    through several of its pieces; the nearest-hit search does not mind (a hit replaces another
    only when strictly nearer), a transmittance walk would count the crossing once per piece, so
    the builder boxes transparent rectangles whole."""
    c, e1, e2 = (np.asarray(row[k], np.float64) for k in ("c", "e1", "e2"))
    l1, l2 = np.linalg.norm(e1), np.linalg.norm(e2)
    if l1 < l2:
        e1, e2, l1, l2 = e2, e1, l2, l1
    k = int(min(max_pieces, max(1, math.ceil(l1 / max(l2, 1e-30)))))
    edges = np.linspace(0.0, 1.0, k + 1)
    out = []
    for a0, a1 in zip(edges[:-1], edges[1:]):
        corners = np.array([c + a0 * e1, c + a1 * e1, c + a0 * e1 + e2, c + a1 * e1 + e2])
        out.append((corners.min(axis=0), corners.max(axis=0)))
    return out


def _disk_bounds(row: dict) -> tuple[np.ndarray, np.ndarray]:
    c, n = np.asarray(row["c"], np.float64), np.asarray(row["n"], np.float64)
    ext = row["r"] * np.sqrt(np.maximum(0.0, 1.0 - n * n))
    return c - ext, c + ext


def _solid_row(s, mat: int) -> dict:
    pos0, rot0, pos1, rot1, size = s.world()
    row = dict(pos0=pos0, rot0=rot0, pos1=pos1, rot1=rot1, size=size, mat=mat)
    lo, hi = _solid_bounds(BY_CLASS[type(s)].tag)(row)
    pad = (hi - lo).max() * 1e-6 + np.maximum(np.abs(lo), np.abs(hi)).max() * 1e-6 + 1e-30
    return dict(row, lo=tuple(lo - pad), hi=tuple(hi + pad))


def solid_extent(tag: int, size) -> np.ndarray:
    """Half extents of a solid's box in its own frame (``SolidRec.size`` of kind ``tag``)."""
    r, h = float(size[0]), float(size[1])
    if tag == KIND_BOX:
        return np.abs(np.asarray(size, np.float64))
    if tag == KIND_CAPSULE:
        return np.array([r, h + r, r])
    return np.array([r, h, r])


def _solid_bounds(tag: int):
    def bounds(row: dict) -> tuple[np.ndarray, np.ndarray]:
        ext = solid_extent(tag, row["size"])
        p0, p1 = np.asarray(row["pos0"], np.float64), np.asarray(row["pos1"], np.float64)
        if np.array_equal(p0, p1) and np.array_equal(row["rot0"], row["rot1"]):
            e = np.abs(quaternion_matrix(row["rot0"])) @ ext
            return p0 - e, p0 + e
        # moving: slerp keeps every point within |ext| of the centre, which moves linearly
        e = float(np.linalg.norm(ext))
        return np.minimum(p0, p1) - e, np.maximum(p0, p1) + e
    return bounds


@dataclass(frozen=True)
class ShapeKind:
    tag: int  # KIND_*: reported by ray queries and id AOVs, named by area lights
    cls: type  # the description class
    table: str  # the SceneData field holding the rows (its count is ``"n_" + table``)
    record: type  # the row's wp.struct
    row: Callable[[object, int], dict]  # description (world space) and material index -> record fields
    bounds: Callable[[dict], tuple] | None  # record fields -> (lower, upper) corners; None: unbounded


KINDS = (
    ShapeKind(KIND_SPHERE, Sphere, "spheres", SphereRec, _sphere_row, _sphere_bounds),
    ShapeKind(KIND_PLANE, Plane, "planes", PlaneRec, _plane_row, None),
    ShapeKind(KIND_RECT, Rectangle, "rects", RectRec, _rect_row, _rect_bounds),
    ShapeKind(KIND_DISK, Disk, "disks", DiskRec, _disk_row, _disk_bounds),
    ShapeKind(KIND_BOX, Box, "boxes", SolidRec, _solid_row, _solid_bounds(KIND_BOX)),
    ShapeKind(KIND_CAPSULE, Capsule, "capsules", SolidRec, _solid_row, _solid_bounds(KIND_CAPSULE)),
    ShapeKind(KIND_CYLINDER, Cylinder, "cylinders", SolidRec, _solid_row, _solid_bounds(KIND_CYLINDER)),
)
BY_CLASS = {k.cls: k for k in KINDS}
BY_TAG = {k.tag: k for k in KINDS}


# --- sampling an emitting shape -----------------------------------------------------------------

SPHRECT_NEAR = 1.0  # (|e1| + |e2|) / distance from which a rectangle light is sampled by solid angle
SPHRECT_NEAR_COSINE = 3.0  # the same with the cosine warp (which follows cosθ'/r² by area farther)


@wp.struct
class EmitterSample:
    ok: int  # 0: no sample (p inside an emitting sphere, behind a one-sided emitter, degenerate)
    y: wp.vec3  # the point on the emitter
    l: wp.vec3  # unit direction from p to y
    dist: float  # |y - p|
    inv_pdf: float  # 1 / (solid-angle density of l)
    mag: float  # magnitude bound of y's coordinates (a shadow ray stops short of y by its offset)


@wp.func(inline=True)
def sample_sphere_emitter(rec: SphereRec, p: wp.vec3, u: wp.vec2) -> EmitterSample:
    """Uniform in the cone of directions the sphere subtends from p."""
    e = EmitterSample()
    c = rec.c0
    r = rec.r
    to_c = c - p
    dc = wp.length(to_c)
    if dc <= r or r <= 0.0:
        return e
    s = r / dc
    omc = s * s / (1.0 + wp.sqrt(wp.max(0.0, 1.0 - s * s)))  # 1 - cos θmax
    l = frame_from_z(to_c / dc, square_to_cone(u, omc))
    t = intersect_sphere(p, l, c, r, 0.0, 3.0e38)
    if t < 0.0:
        t = wp.dot(to_c, l)  # grazing the silhouette: use the tangent point
    e.ok = 1
    e.dist = t
    e.l = l
    e.y = p + l * t
    e.inv_pdf = 2.0 * wp.pi * omc
    e.mag = max_abs(c) + r
    return e


@wp.func(inline=True)
def planar_emitter(y: wp.vec3, ln: wp.vec3, area: float, mag: float, p: wp.vec3) -> EmitterSample:
    """A point y drawn uniformly by area on a one-sided planar emitter of normal ln, seen from p."""
    e = EmitterSample()
    to_y = y - p
    dist = wp.length(to_y)
    if dist <= 0.0 or area <= 0.0:
        return e
    l = to_y / dist
    cos_l = -wp.dot(ln, l)
    if cos_l <= 0.0:
        return e  # the back of a one-sided emitter
    e.ok = 1
    e.y = y
    e.l = l
    e.dist = dist
    e.inv_pdf = area * cos_l / (dist * dist)
    e.mag = mag
    return e


COSINE_FLOOR = 0.01  # the least corner weight of the cosine warp, relative to the largest


@wp.func
def rect_cosine_weights(rec: RectRec, p: wp.vec3, n: wp.vec3, solid_angle: bool) -> wp.mat33:
    """Knots for the cosine warp: w[i, j] at the rectangle's point c + (i/2)·e1 + (j/2)·e2 (the
    corners are the corners of both sample parametrisations), weighted by what the estimate
    integrates: max(0, n·ω) in solid angle, max(0, n·ω)/r³ by area (cosθ'/r² = h/r³, h common).
    Raised to at least COSINE_FLOOR times the largest (the density must not vanish where n·ω > 0
    between knots); all 0 when the light is wholly below p's horizon."""
    w = wp.mat33()
    top = float(0.0)
    d0 = rec.c - p
    for i in range(3):
        for j in range(3):
            d = d0 + (0.5 * float(i)) * rec.e1 + (0.5 * float(j)) * rec.e2
            r = wp.length(d)
            v = wp.max(wp.dot(n, d) / r, 0.0)
            if not solid_angle:
                v = v / (r * r * r)
            w[i, j] = v
            top = wp.max(top, v)
    if not (top > 0.0) or not (top < 3.0e38):
        return wp.mat33()
    lo = COSINE_FLOOR * top
    for i in range(3):
        for j in range(3):
            w[i, j] = wp.max(w[i, j], lo)
    return w


@wp.struct
class EmitterPrep:
    """What a shading point p works out once for an emitter before drawing its samples: whether p
    can get light from it at all, and for a rectangle how its points are drawn (the cosine warp's
    set-up, the spherical rectangle's set-up when drawn by solid angle)."""

    ok: int  # 0: no light reaches p from it (behind a one-sided emitter, wholly below p's horizon)
    cosine: int  # the square warped by ``warp`` first
    solid: int  # then mapped by solid angle (``sphrect``), else by area
    warp: GridWarp
    sphrect: SphRect
    area: float
    mag: float


@wp.func
def prepare_rect_emitter(rec: RectRec, p: wp.vec3, n: wp.vec3, cosine: int) -> EmitterPrep:
    """A rectangle near p: uniform in the solid angle it subtends (spherical rectangles; the
    irradiance estimate then varies only with cosθ at p); a far one, a sheared parallelogram, or
    a solid angle too small to matter: uniform by area. With ``cosine`` != 0 the square is first
    warped so that points come in proportion to a bilinear fit of n·ω (times cosθ'/r² by area)
    through 3 × 3 knots (``rect_cosine_weights``; pbrt-v4's lights fit the corners alone): a
    point in full view then contributes nearly the same whatever the sample, and low-discrepancy
    samples keep their stratification in penumbrae. Every estimator is unbiased (the density never vanishes where
    n·ω > 0). Draws: ``sample_rect_prepared``."""
    e = EmitterPrep()
    if not (wp.dot(rec.n, p - rec.c) > 0.0):
        return e  # p behind (or in the plane of) a one-sided emitter: no light
    # near a rectangle (its size at least SPHRECT_NEAR times its distance) the area-sampling weight
    # cosθ'/r² varies across it and solid-angle sampling pays for its cost (~250 ns against
    # ~10 ns); farther, both weights are nearly constant and area sampling is as good. The cosine
    # warp fits cosθ'/r² at the corners too, so area sampling serves it up to SPHRECT_NEAR_COSINE
    centre = rec.c + 0.5 * (rec.e1 + rec.e2)
    near_at = SPHRECT_NEAR
    if cosine != 0:
        near_at = SPHRECT_NEAR_COSINE
    near = wp.length(rec.e1) + wp.length(rec.e2) >= near_at * wp.length(centre - p)
    solid = near and is_rectangle_edges(rec.e1, rec.e2)
    if cosine != 0:
        w = rect_cosine_weights(rec, p, n, solid)
        if not (w[0, 0] > 0.0):
            return e  # every point of the light below the horizon: n·ω <= 0 throughout
        e.warp = grid_warp_setup(w)
        e.cosine = 1
    if solid:
        e.sphrect = sphrect_setup(p, rec.c, rec.e1, rec.e2)
        e.solid = 1
    e.area = wp.length(wp.cross(rec.e1, rec.e2))
    e.mag = max_abs(rec.c) + max_abs(rec.e1) + max_abs(rec.e2)
    e.ok = 1
    return e


@wp.func(inline=True)
def sample_rect_prepared(rec: RectRec, prep: EmitterPrep, p: wp.vec3, u_in: wp.vec2) -> EmitterSample:
    """A point of the rectangle drawn as ``prepare_rect_emitter`` set up for p (``prep.ok`` is 1:
    callers skip a light whose set-up says no light reaches p)."""
    u = u_in
    warp_pdf = float(1.0)
    if prep.cosine != 0:
        g = grid_warp_sample(prep.warp, u_in)
        u = wp.vec2(g[0], g[1])
        warp_pdf = g[2]
    if prep.solid != 0:
        q = sphrect_sample(prep.sphrect, rec.c, rec.e1, rec.e2, u)
        if q[3] > 0.0:
            e = EmitterSample()
            y = wp.vec3(q[0], q[1], q[2])
            to_y = y - p
            dist = wp.length(to_y)
            if dist <= 0.0:
                return e
            l = to_y / dist
            if -wp.dot(rec.n, l) <= 0.0:
                return e  # grazing: the point rounded onto the emitter's back
            e.ok = 1
            e.y = y
            e.l = l
            e.dist = dist
            e.inv_pdf = q[3] / warp_pdf  # 1 / (1/Ω · the warp's density)
            e.mag = prep.mag
            return e
    y = rec.c + u[0] * rec.e1 + u[1] * rec.e2
    e = planar_emitter(y, rec.n, prep.area, prep.mag, p)
    e.inv_pdf = e.inv_pdf / warp_pdf
    return e


@wp.func
def sample_rect_emitter(rec: RectRec, p: wp.vec3, n: wp.vec3, cosine: int, u: wp.vec2) -> EmitterSample:
    """One draw of ``prepare_rect_emitter`` then ``sample_rect_prepared``."""
    prep = prepare_rect_emitter(rec, p, n, cosine)
    if prep.ok == 0:
        return EmitterSample()
    return sample_rect_prepared(rec, prep, p, u)


@wp.func(inline=True)
def sample_disk_emitter(rec: DiskRec, p: wp.vec3, u: wp.vec2) -> EmitterSample:
    dsk = square_to_disk(u) * rec.r
    y = rec.c + frame_from_z(rec.n, wp.vec3(dsk[0], dsk[1], 0.0))
    return planar_emitter(y, rec.n, wp.pi * rec.r * rec.r, max_abs(rec.c) + rec.r, p)



# Rectangle lights drawn for a packet's 8 shading points at once: what ``prepare_rect_emitter``
# and ``sample_rect_prepared`` compute for each lane, area draws with or without the cosine warp,
# as clang vectors on the CPU: the same operations in the same order (Warp's CPU fmax / fmin, no
# contraction: Warp's C++ compiler fuses nothing), so each lane's point, direction and 1/density
# are the scalar draw's bit for bit, for a fraction of the scalar draw's time per lane
# (``shading_packets`` in ``warprt.fast``). Like the scalar draws, the set-up (``rect_setup_packet``: the
# facing and near tests, the cosine warp's 9 knots and their sum, in ``RectKnots``) is made once
# per packet and light, then each of its draws (``rect_draw_packet``) takes a 2D sample per lane.
# Lanes the rectangle is drawn for by solid angle (near it, square edges: the spherical
# rectangle) come back flagged for the scalar draw, as every lane does on CUDA.
# the set-up's knots for 8 lanes: row 3i + j the knot at (i/2, j/2) of the warp's grid, row 9 their sum
RectKnots = wp.types.matrix(shape=(10, 8), dtype=wp.float32)

_RECT_PACKET_HEAD = r"""
typedef float v8 __attribute__((ext_vector_type(8)));
typedef int i8 __attribute__((ext_vector_type(8)));
// Warp's CPU fmax and fmin (builtin.h; clamp is fmin(fmax(lo, x), hi)), lane by lane
auto vmax = [](v8 a, v8 b) -> v8 { return a >= b ? a : (b == b ? b : a); };
auto vmin = [](v8 a, v8 b) -> v8 { return a <= b ? a : (b == b ? b : a); };
auto vsqrt = [](v8 x) -> v8 { return __builtin_elementwise_sqrt(x); };
const v8 zero = (v8)(0.0f), one = (v8)(1.0f);
v8 Px, Py, Pz;
__builtin_memcpy(&Px, &px, 32); __builtin_memcpy(&Py, &py, 32); __builtin_memcpy(&Pz, &pz, 32);
const float cx = c[0], cy = c[1], cz = c[2], ax = e1[0], ay = e1[1], az = e1[2], bx = e2[0], by = e2[1], bz = e2[2];
"""

_RECT_SETUP_PACKET = r"""
int res = 0;
#if defined(__clang__) && !defined(__CUDA_ARCH__)
@HEAD@
v8 Nx, Ny, Nz;
__builtin_memcpy(&Nx, &nx, 32); __builtin_memcpy(&Ny, &ny, 32); __builtin_memcpy(&Nz, &nz, 32);
// the lanes asked for whose p is in front of the one-sided emitter: dot(rec.n, p - rec.c) > 0
const v8 qx = Px - cx, qy = Py - cy, qz = Pz - cz;
i8 ok = (ln[0] * qx + ln[1] * qy + ln[2] * qz) > 0.0f;
i8 asked;
for (int l = 0; l < 8; ++l) asked[l] = (lanes >> l) & 1 ? -1 : 0;
ok &= asked;
// near: |e1| + |e2| >= near_at |centre - p|; there a rectangle with square edges is drawn by
// solid angle, which the scalar draw does
const float sx = ax + bx, sy = ay + by, sz = az + bz;
const float ctx = cx + 0.5f * sx, cty = cy + 0.5f * sy, ctz = cz + 0.5f * sz;
const float len1 = sqrtf(ax * ax + ay * ay + az * az), len2 = sqrtf(bx * bx + by * by + bz * bz);
const float near_at = cosine != 0 ? 3.0f : 1.0f;
const v8 dcx = ctx - Px, dcy = cty - Py, dcz = ctz - Pz;
const i8 near = (len1 + len2) >= near_at * vsqrt(dcx * dcx + dcy * dcy + dcz * dcz);
const i8 solid = near & (i8)(square != 0 ? -1 : 0);
for (int l = 0; l < 8; ++l) res |= ok[l] & solid[l] ? 1 << (8 + l) : 0;
ok &= ~solid;
bool any = false;
for (int l = 0; l < 8; ++l) any = any || ok[l];
if (any && cosine != 0) {
    // shapes.rect_cosine_weights (by area), then sampling.grid_warp_setup
    const v8 d0x = cx - Px, d0y = cy - Py, d0z = cz - Pz;
    v8 W[3][3];
    v8 top = zero;
    for (int i = 0; i < 3; ++i) {
        const float si = 0.5f * (float)i;
        for (int j = 0; j < 3; ++j) {
            const float sj = 0.5f * (float)j;
            const v8 dx = (d0x + si * ax) + sj * bx, dy = (d0y + si * ay) + sj * by, dz = (d0z + si * az) + sj * bz;
            const v8 r = vsqrt(dx * dx + dy * dy + dz * dz);
            v8 v = vmax((Nx * dx + Ny * dy + Nz * dz) / r, zero);
            v = v / ((r * r) * r);
            W[i][j] = v;
            top = vmax(top, v);
        }
    }
    ok &= (top > 0.0f) & (top < 3.0e38f);
    const v8 lo = 0.01f * top;  // COSINE_FLOOR
    for (int i = 0; i < 3; ++i)
        for (int j = 0; j < 3; ++j) W[i][j] = vmax(W[i][j], lo);
    ok &= W[0][0] > 0.0f;
    v8 total = zero + ((W[0][0] + 2.0f * W[0][1]) + W[0][2]) * 1.0f;
    total = total + ((W[1][0] + 2.0f * W[1][1]) + W[1][2]) * 2.0f;
    total = total + ((W[2][0] + 2.0f * W[2][1]) + W[2][2]) * 1.0f;
    for (int i = 0; i < 3; ++i)
        for (int j = 0; j < 3; ++j) __builtin_memcpy(&knots.data[3 * i + j][0], &W[i][j], 32);
    __builtin_memcpy(&knots.data[9][0], &total, 32);
}
for (int l = 0; l < 8; ++l) res |= ok[l] ? 1 << l : 0;
#else
res = lanes << 8;  // no clang vectors (CUDA): every lane to the scalar draw
#endif
return res;
""".replace("@HEAD@\n", _RECT_PACKET_HEAD.lstrip("\n"))

_RECT_DRAW_PACKET = r"""
int res = 0;
#if defined(__clang__) && !defined(__CUDA_ARCH__)
if (lanes != 0) {
@HEAD@
    v8 U0, U1;
    __builtin_memcpy(&U0, &ux, 32); __builtin_memcpy(&U1, &uy, 32);
    // sampling.sample_linear and sampling.sample_two_linear (both halves computed, then selected)
    auto sample_linear = [&](v8 u, v8 a, v8 b) -> v8 {
        const v8 x = (u * (a + b)) / (a + vsqrt(((1.0f - u) * a) * a + (u * b) * b));
        return x >= 0.0f ? vmin(x, one) : zero;
    };
    auto sample_two_linear = [&](v8 u, v8 a, v8 b, v8 c) -> v8 {
        const v8 m0 = a + b, m1 = b + c;
        const v8 t = u * (m0 + m1);
        const v8 r0 = 0.5f * sample_linear(vmin(t / m0, one), a, b);
        const v8 r1 = 0.5f + 0.5f * sample_linear(vmin(vmax(zero, (t - m0) / m1), one), b, c);
        return t < m0 ? r0 : r1;
    };
    i8 ok;
    for (int l = 0; l < 8; ++l) ok[l] = (lanes >> l) & 1 ? -1 : 0;
    v8 X = U0, Y = U1, pdf = one;
    if (cosine != 0) {
        // sampling.grid_warp_sample: y from the rows' masses, x along the row interpolated at y
        v8 W[3][3], total;
        for (int i = 0; i < 3; ++i)
            for (int j = 0; j < 3; ++j) __builtin_memcpy(&W[i][j], &knots.data[3 * i + j][0], 32);
        __builtin_memcpy(&total, &knots.data[9][0], 32);
        const v8 g0 = (W[0][0] + 2.0f * W[1][0]) + W[2][0];
        const v8 g1 = (W[0][1] + 2.0f * W[1][1]) + W[2][1];
        const v8 g2 = (W[0][2] + 2.0f * W[1][2]) + W[2][2];
        Y = sample_two_linear(U1, g0, g1, g2);
        const i8 low = Y < 0.5f;
        const v8 t0 = 2.0f * Y, t1 = 2.0f * Y - 1.0f;
        const v8 A = low ? (1.0f - t0) * W[0][0] + t0 * W[0][1] : (1.0f - t1) * W[0][1] + t1 * W[0][2];
        const v8 B = low ? (1.0f - t0) * W[1][0] + t0 * W[1][1] : (1.0f - t1) * W[1][1] + t1 * W[1][2];
        const v8 C = low ? (1.0f - t0) * W[2][0] + t0 * W[2][1] : (1.0f - t1) * W[2][1] + t1 * W[2][2];
        X = sample_two_linear(U0, A, B, C);
        const v8 f = X < 0.5f ? A + (B - A) * (2.0f * X) : B + (C - B) * (2.0f * X - 1.0f);
        pdf = (16.0f * f) / total;
    }
    // the point by area and what it gives p (shapes.planar_emitter), over the warp's density
    const v8 yx = (cx + X * ax) + Y * bx, yy = (cy + X * ay) + Y * by, yz = (cz + X * az) + Y * bz;
    const v8 tx = yx - Px, ty = yy - Py, tz = yz - Pz;
    const v8 dist = vsqrt(tx * tx + ty * ty + tz * tz);
    ok &= (dist > 0.0f) & (i8)(area > 0.0f ? -1 : 0);
    const v8 lx = tx / dist, ly = ty / dist, lz = tz / dist;
    const v8 cos_l = -(ln[0] * lx + ln[1] * ly + ln[2] * lz);
    ok &= cos_l > 0.0f;
    const v8 ip = ((area * cos_l) / (dist * dist)) / pdf;
    __builtin_memcpy(&out_y0, &yx, 32); __builtin_memcpy(&out_y1, &yy, 32); __builtin_memcpy(&out_y2, &yz, 32);
    __builtin_memcpy(&out_l0, &lx, 32); __builtin_memcpy(&out_l1, &ly, 32); __builtin_memcpy(&out_l2, &lz, 32);
    __builtin_memcpy(&out_ip, &ip, 32);
    for (int l = 0; l < 8; ++l) res |= ok[l] ? 1 << l : 0;
}
#endif
return res;
""".replace("@HEAD@\n", textwrap.indent(_RECT_PACKET_HEAD.lstrip("\n"), "    "))


@wp.func_native(_RECT_SETUP_PACKET)
def rect_setup_packet(c: wp.vec3, e1: wp.vec3, e2: wp.vec3, ln: wp.vec3, cosine: int, square: int, lanes: int,
                      px: PacketF, py: PacketF, pz: PacketF, nx: PacketF, ny: PacketF, nz: PacketF,
                      knots: wp.ref[RectKnots]) -> int:
    """For each lane in the bit mask ``lanes`` (shading point p, shading normal n) of the rectangle
    (corner c, edges e1, e2, unit normal ln, ``square``: its edges are square), ``prepare_rect_emitter``:
    the cosine warp's knots and their sum into ``knots``. Returns bit l set where lane l can be
    drawn (``rect_draw_packet``), bit 8 + l where the scalar draw must take lane l (see above)."""
    ...


@wp.func_native(_RECT_DRAW_PACKET)
def rect_draw_packet(c: wp.vec3, e1: wp.vec3, e2: wp.vec3, ln: wp.vec3, area: float, cosine: int, lanes: int,
                     knots: RectKnots, px: PacketF, py: PacketF, pz: PacketF, ux: PacketF, uy: PacketF,
                     out_y0: wp.ref[PacketF], out_y1: wp.ref[PacketF], out_y2: wp.ref[PacketF],
                     out_l0: wp.ref[PacketF], out_l1: wp.ref[PacketF], out_l2: wp.ref[PacketF],
                     out_ip: wp.ref[PacketF]) -> int:
    """``sample_rect_prepared`` for each lane in the bit mask ``lanes`` (the lanes
    ``rect_setup_packet`` set bit l for; shading point p, 2D sample u) from that set-up's
    ``knots``: the drawn point, the unit direction to it and 1/density. Returns bit l set where
    lane l has a sample."""
    ...


@wp.func
def prepare_emitter(scene: SceneData, kind: int, row: int, p: wp.vec3, n: wp.vec3, cosine: int) -> EmitterPrep:
    """What shading point p (shading normal n) works out once for the emitting shape (kind, row)
    before drawing its samples (``sample_emitter``); ``cosine``: RenderParams.light_sampling
    (rectangles drawn in proportion to n·ω)."""
    if kind == KIND_RECT:
        return prepare_rect_emitter(scene.rects[row], p, n, cosine)
    e = EmitterPrep()
    e.ok = 1
    return e


@wp.func(inline=True)
def sample_emitter(scene: SceneData, kind: int, row: int, prep: EmitterPrep, p: wp.vec3, u: wp.vec2) -> EmitterSample:
    """A point of the emitting shape (kind, row) for shading point p from the 2D sample u, drawn as
    ``prep = prepare_emitter(scene, kind, row, p, ...)`` says (called only when ``prep.ok`` is 1)."""
    if kind == KIND_SPHERE:
        return sample_sphere_emitter(scene.spheres[row], p, u)
    if kind == KIND_RECT:
        return sample_rect_prepared(scene.rects[row], prep, p, u)
    return sample_disk_emitter(scene.disks[row], p, u)
