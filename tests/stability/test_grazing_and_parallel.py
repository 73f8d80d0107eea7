"""Grazing angles, exactly parallel rays, the critical angle, and rays through mesh edges.

Failure modes, the naive method that shows each one, and what warprt does (u = 2^-24, the float32
unit roundoff; S bounds the magnitudes a computation involves):

* **grazing sphere hits** (silhouettes): the textbook quadratic b² − 4ac in float32 subtracts two
  numbers of size 4L² (L: distance to the sphere) to find one of size 4(r² − p²) (p: the ray's
  distance from the centre), so a small or distant sphere loses its silhouette: for r = 1e-3 at
  L = 10 it misjudges 44% of the rays 1% to 10% off the radius, and even exactly representable
  axis-aligned rays at r(1 ± 1e-3) from L = 1e3·r come out the same. warprt takes the
  discriminant from the perpendicular distance (Ray Tracing Gems ch. 7): every ray whose float64
  distance p differs from r by more than 4u·S is decided correctly (measured: wrong only within
  0.5u·S), t lies within the bound below (near tangency t is ill-conditioned: dt/dp → ∞), the
  hit point lies on the sphere within 8u·(|c| + r) and the normal is unit, at r = 1, 1e4 and
  1e-4 and for a 1e-3 sphere 1e4 radii away; axis-aligned rays at r(1 ∓ 2^-23) are decided to
  the last ulp, and an exactly tangent one hits at the tangent point.
* **grazing planar hits**: the published ``if abs(denom) > 1e-6`` parallel test drops every
  ray within 1e-6 rad of a plane (holes along the horizon). warprt tests ``denom == 0`` only:
  rays at 1e-1 … 1e-6 rad hit planes, rectangles, disks and a triangle. For an axis-aligned plane
  n·d is exact and t is within 4u relative; for a tilted surface n·d is a float32 dot product
  whose error is ~u while its value is sin α, so t is only good to 4u·(S + t)/|n·d| (measured
  at 1e-6 rad: 4% for a plane or disk, 30% for a rectangle or triangle 4e6 across, whose t is
  taken from a corner or vertex far away; inherent to evaluating n·d and n·(corner − o) in
  float32). The hit point is projected onto the surface, within 4u·S of it whatever t's error.
* **grazing light (Lambert)**: n·l = h/dist for a light h above the plane. From the unrefined
  float32 point o + t·d (its height is off by ~ulp(|o|)) n·l is off by 48% for h = 1e-6; warprt
  shades from the point projected onto the plane, so for an axis-aligned plane the pixel is
  kd·I·n·l within 1e-6 relative for h = 1e-2 … 1e-6, exactly 0 for a light in the plane or
  below it; for a tilted plane within the float32 bound of n·(L − p) (below).
* **exactly parallel rays** (d·n == 0 in float32): camera rows parallel to a plane, rectangle,
  disk or flat mesh render the background exactly (no hit at t = inf, no NaN), the rows just below
  show the surface; rays running inside a flat mesh grid along its edges, diagonals and through
  its vertices miss it, as do rays parallel just above it.
* **the critical angle**: naive Schlick from the dense side with the incident cosine gives
  F(θc) ≈ 0.04 and then jumps to 1 under total internal reflection (a bright ring); warprt uses
  the transmitted cosine, so F → 1 continuously. Within ±2e-4 and ±2e-6 rad of θc = asin(1/1.5):
  TIR exactly where 1.5·sin θ > 1 for every ray more than 1e-6 rad from θc (the float32 error
  of 1 − η²sin²θ is ~1e-7 rad), no ray loses its kt share inside the band, F (exact and
  Schlick) lies between the float64 values at θ ± 2e-7, and just below θc the exit direction
  (elevation β with cos θt = sin β) lands where Snell's law puts it.
* **grazing incidence** (1e-2 … 1e-6 rad from the surface): the refracted ray bends to
  sin θt = cos α/η and lands within 1e-6 of the float64 point; the Fresnel reflectance tends to 1
  (exact and Schlick, within 1e-6 of the closed form).
* **mesh edges and vertices**: Möller-Trumbore in float32 with strict inequalities (u > 0,
  v > 0, u + v < 1) leaks 19% of the rays aimed exactly at shared edges of a closed mesh (and
  every one on an axis-aligned grid; even inclusive float32 MT leaks 4%: it is not watertight).
  Warp's triangle test is watertight (Woop et al.), and rays at shared edges of a closed mesh in
  general position never leak (0 of 106k here, 0 of 288k more in other poses). Warp's ray-box
  test is not conservative, though (no rounding margin on the slabs), so the BVH can cull both
  faces at a point on their boxes' boundary: at vertices (always box corners) and at edges
  parallel to a coordinate axis (on box faces). Those leak at a small rate, bounded here (0.4%
  at the vertices of the icosphere in general position, up to 3.6% at the vertices of a flat
  grid; see ``test_leaks_at_vertices_and_axis_aligned_edges_stay_rare``); the strict "no leak at
  all" test is an xfail in tests/test_intersection.py.

Every render uses the all-features kernel through ``_util``; images are at most 48×48.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

import warprt

from ._util import SPAWN_REL, image, pixel_hits, unit

U = 2.0 ** -24  # float32 unit roundoff
IOR = 1.5
CRIT = math.asin(1.0 / IOR)  # the critical angle seen from the glass


def f32(a) -> np.ndarray:
    """float64 copy of the float32 rounding of ``a``: what the device stores."""
    return np.asarray(a, np.float64).astype(np.float32).astype(np.float64)


def rotation(axis, angle) -> np.ndarray:
    k = unit(axis)
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + math.sin(angle) * K + (1 - math.cos(angle)) * K @ K


# --- grazing hits on spheres -------------------------------------------------------------------

# (centre, radius, distance L of the ray origins): unit, large, small, and a small sphere far away
SPHERES = {"unit": ((0.3, -0.2, 0.5), 1.0, 10.0),
           "large": ((3e4, -2e4, 1e4), 1e4, 1e5),
           "small": ((3e-4, 1e-4, -2e-4), 1e-4, 1e-3),
           "far-small": ((1.0, 2.0, 3.0), 1e-3, 10.0)}
EPS = [-1e-1, -1e-2, -1e-3, -1e-4, -1e-5, -1e-6, -1e-7, 0.0, 1e-7, 1e-6, 1e-5, 1e-4, 1e-3, 1e-2]
K_SPHERE = 4.0


def grazing_sphere_rays(c, r, L, n, rng):
    """float32 rays starting L before their closest approach to the centre, at impact parameter
    r(1 + eps) for every eps in EPS, and the float64 facts about each float32 ray: distance
    from the centre p, the closest-approach parameter b, the discriminant r² − p², and S."""
    c = np.asarray(c, np.float64)
    eps = np.repeat(EPS, n)
    d = unit(rng.normal(size=(len(eps), 3)))
    side = unit(np.cross(d, rng.normal(size=d.shape)))
    o = (c + (r * (1 + eps))[:, None] * side - L * d).astype(np.float32)
    d = d.astype(np.float32)
    o64, d64 = o.astype(np.float64), unit(d.astype(np.float64))  # trace_rays normalises d
    f = o64 - c
    b = -np.sum(f * d64, 1)
    perp = np.linalg.norm(f + b[:, None] * d64, axis=1)
    S = np.abs(o64).max(1) + np.abs(c).max() + np.abs(b)
    return o, d, d64, b, perp, r * r - perp ** 2, S, eps


def naive_quadratic(o, d, c, r):
    """Hit test and near root of |o + t d - c|² = r² as b² − 4ac, all in float32."""
    o, d = np.asarray(o, np.float32), np.asarray(d, np.float32)
    d = d / np.linalg.norm(d, axis=1, keepdims=True).astype(np.float32)
    f = o - np.float32(c)
    a = np.sum(d * d, 1, dtype=np.float32)
    b = np.float32(2) * np.sum(f * d, 1, dtype=np.float32)
    cc = np.sum(f * f, 1, dtype=np.float32) - np.float32(r) * np.float32(r)
    disc = b * b - np.float32(4) * a * cc
    with np.errstate(invalid="ignore"):
        t = (-b - np.sqrt(disc)) / (np.float32(2) * a)
    return disc >= 0, t


def test_naive_float32_quadratic_misjudges_grazing_sphere_rays():
    """A sphere of radius 1e-3 seen from 10: of the rays that warprt must decide (|p − r| >
    4u·S: here 1% to 10% inside or outside the radius), b² − 4ac misjudges 44%; exactly
    representable rays along z at r(1 ± 1e-3) from L = 1e3·r get the same answer (|f|² − r²
    rounds away r² − p²)."""
    c, r, L = SPHERES["far-small"]
    o, d, _, _, perp, disc, S, eps = grazing_sphere_rays(c, r, L, 500, np.random.default_rng(20))
    decidable = np.abs(perp - r) > K_SPHERE * U * S  # what warprt must decide correctly
    assert decidable.sum() >= 1500
    hit, _ = naive_quadratic(o, d, c, r)
    wrong = (hit != (disc > 0))[decidable]
    assert wrong.mean() > 0.3, f"naive quadratic misjudged only {wrong.mean():.1%}"
    # axis-aligned, exact inputs: impact parameter 1 - 1e-3 (hits) and 1 + 1e-3 (misses), L = 1000
    o = np.float32([[1 - 1e-3, 0, -1000], [1 + 1e-3, 0, -1000]])
    hit, _ = naive_quadratic(o, np.float32([[0, 0, 1]] * 2), (0, 0, 0), 1.0)
    assert hit[0] == hit[1]


@pytest.mark.parametrize("case", list(SPHERES))
def test_grazing_sphere_rays_are_decided_and_placed_within_the_float32_bound(case):
    """2000 rays per eps in ±1e-1 … ±1e-7 and 0. Bounds (K = 4): hit/miss as float64 wherever
    |p − r| > K·u·S; t within K·u·S + min(√δ, δ/(2√disc)) with δ = 2r·K·u·S + 4u·r² (the
    float32 error of the discriminant, through the square root: at tangency t is only good to
    √(r·u·S); measured at most 0.35 of the bound); the hit point within 8u·(|c| + r) of the
    sphere (measured 2.2u), a unit finite normal whose n·d is the closed form −√disc/r within
    (δt + K·u·S)/r."""
    c, r, L = SPHERES[case]
    cv = np.asarray(c, np.float64)
    scene = warprt.Scene(shapes=(warprt.Sphere(center=c, radius=r),))
    o, d, d64, b, perp, disc, S, eps = grazing_sphere_rays(c, r, L, 2000, np.random.default_rng(21))
    h = warprt.trace_rays(scene, o, d)
    hit = h["hit"]
    decidable = np.abs(perp - r) > K_SPHERE * U * S
    wrong = decidable & (hit != (disc > 0))
    assert not wrong.any(), f"{wrong.sum()} decidable rays misjudged, eps {np.unique(eps[wrong])}"
    # eps = ±1e-2 at least are decidable everywhere (r·1e-2 > 4u·S even at 1e4 radii)
    assert (decidable & (disc > 0)).sum() >= 2000 and (decidable & (disc < 0)).sum() >= 2000
    assert np.isinf(h["t"][~hit]).all() and (h["shape"][~hit] == -1).all()
    # t against the closed form b - sqrt(disc) (at the tangent point b when disc <= 0)
    dpos = np.maximum(disc, 0.0)[hit]
    delta = 2 * r * K_SPHERE * U * S[hit] + 4 * U * r * r
    with np.errstate(divide="ignore"):
        dt = K_SPHERE * U * S[hit] + np.minimum(np.sqrt(delta), delta / (2 * np.sqrt(dpos)))
    err = np.abs(h["t"][hit] - (b[hit] - np.sqrt(dpos)))
    assert (err <= dt).all(), f"t off by {(err / dt).max():.2f} of the bound"
    # the point lies on the sphere, the normal is unit and radial
    p = h["position"][hit].astype(np.float64)
    off = np.abs(np.linalg.norm(p - cv, axis=1) - r)
    assert off.max() <= 8 * U * (np.abs(cv).max() + r), off.max() / (U * (np.abs(cv).max() + r))
    nrm = h["normal"][hit].astype(np.float64)
    assert np.isfinite(nrm).all()
    np.testing.assert_allclose(np.linalg.norm(nrm, axis=1), 1.0, atol=4e-7)
    ndotd = np.sum(nrm * d64[hit], 1)
    assert (np.abs(ndotd + np.sqrt(dpos) / r) <= (dt + K_SPHERE * U * S[hit]) / r + 1e-6).all()


@pytest.mark.parametrize("r", [1.0, 1e4, 1e-4], ids=["1", "1e4", "1e-4"])
def test_tangent_rays_along_an_axis_are_decided_to_one_ulp(r):
    """Rays along +z from (p, 0, −L), L = 10r, past a sphere at the origin: o − c and the
    perpendicular (p, 0, 0) are exact, so only r² and p² round (δ = 2u·r² on r² − p²). p one
    float32 ulp inside r hits, with t within 4u·L + min(√δ, δ/(2√(r² − p²))) of L − √(r² − p²);
    one ulp outside misses; p = r touches at t = L, the tangent point. The float32 quadratic
    cannot tell the inside and the outside ray apart."""
    r32 = float(np.float32(r))
    ps = np.array([np.nextafter(np.float32(r), np.float32(0)), np.float32(r),
                   np.nextafter(np.float32(r), np.float32(2 * r))])
    L = float(np.float32(10.0 * r32))
    o = np.stack([ps, np.zeros(3, np.float32), np.full(3, -L, np.float32)], 1)
    d = np.float32([[0, 0, 1]] * 3)
    h = warprt.trace_rays(warprt.Scene(shapes=(warprt.Sphere(center=(0, 0, 0), radius=r32),)), o, d)
    assert h["hit"].tolist() == [True, True, False]
    x = r32 ** 2 - ps[:2].astype(np.float64) ** 2  # r² − p²: 2r·ulp(r), and 0
    delta = 2 * U * r32 ** 2
    with np.errstate(divide="ignore"):
        tol = 4 * U * L + np.minimum(math.sqrt(delta), delta / (2 * np.sqrt(x)))
    assert (np.abs(h["t"][:2] - (L - np.sqrt(x))) <= tol).all()
    np.testing.assert_allclose(np.abs(h["normal"][1]), [1, 0, 0], atol=1e-6)  # radial at (r, 0, 0)
    naive_hit, _ = naive_quadratic(o, d, (0, 0, 0), r)
    assert naive_hit[0] == naive_hit[2]  # the naive form gives the hit and the miss the same answer


# --- grazing hits on planar shapes and a triangle ------------------------------------------------

ALPHAS = [1e-1, 1e-3, 1e-5, 1e-6]
TILT = (0.3, 1.0, -0.4)
K_PLANE = 4.0


def grazing_planar_scene(kind, alpha):
    """A surface through P with normal N (axis-aligned for "plane-axis", tilted otherwise), big
    enough for rays at ``alpha`` from heights up to 2 over P to cross it well inside; returns the
    scene, the float32-stored plane (point, unit normal) in float64, P, N, a tangent frame (a, b)
    and the coordinate magnitude of the shape's data."""
    N = unit((0, 1, 0) if kind == "plane-axis" else TILT)
    P = np.zeros(3) if kind == "plane-axis" else np.array([1.0, 2.0, -3.0])
    a = unit(np.cross(N, [1.0, 0.0, 0.0]))
    b = np.cross(N, a)
    R = 4.0 / alpha  # the crossings lie within 2/alpha + 3 of P
    if kind in ("plane-axis", "plane"):
        shape, point, normal = warprt.Plane(point=tuple(P), normal=tuple(N)), f32(P), f32(N)
        mag = np.abs(point).max()
    elif kind == "rectangle":
        corner, e1, e2 = P - R * a - R * b, 2 * R * b, 2 * R * a  # e1 x e2 along N
        shape = warprt.Rectangle(corner=tuple(corner), edge1=tuple(e1), edge2=tuple(e2))
        point, normal = f32(corner), np.cross(f32(e1), f32(e2))
        mag = np.abs(f32(corner)).max() + np.abs(f32(e1)).max() + np.abs(f32(e2)).max()
    elif kind == "disk":
        shape = warprt.Disk(center=tuple(P), normal=tuple(N), radius=R)
        point, normal, mag = f32(P), f32(N), np.abs(f32(P)).max() + R
    else:  # one triangle around the disk of radius R
        ang = np.radians([90.0, 210.0, 330.0])
        v = f32(P + 2 * R * (np.cos(ang)[:, None] * a + np.sin(ang)[:, None] * b))
        shape = warprt.Mesh(vertices=v, faces=[[0, 1, 2]])
        point, normal, mag = v[0], np.cross(v[1] - v[0], v[2] - v[0]), np.abs(v).max()
    return warprt.Scene(shapes=(shape,)), point, unit(normal), P, N, a, b, mag


def grazing_plane_rays(N, P, a, b, alpha, n, rng):
    phi = rng.uniform(0, 2 * np.pi, n)
    tang = np.cos(phi)[:, None] * a + np.sin(phi)[:, None] * b
    d = math.cos(alpha) * tang - math.sin(alpha) * N
    o = P + rng.uniform(0.5, 2.0, (n, 1)) * N + rng.uniform(-3, 3, (n, 1)) * a
    return o.astype(np.float32), d.astype(np.float32)


def test_naive_parallel_epsilon_drops_grazing_plane_hits():
    """``if abs(n·d) > 1e-6`` (scratchapixel's intersectPlane): rays within 1e-6 rad of the
    plane count as parallel and miss it, though they cross it at t = h/sin α (2e6 here)."""
    N, P = np.array([0.0, 1.0, 0.0]), np.zeros(3)
    o, d = grazing_plane_rays(N, P, np.array([1.0, 0, 0]), np.array([0, 0, 1.0]), 5e-7, 200,
                              np.random.default_rng(22))
    denom = d.astype(np.float64) @ N
    t = ((P - o) @ N) / denom
    assert (t > 0).all() and np.isfinite(t).all()
    assert not (np.abs(denom.astype(np.float32)) > np.float32(1e-6)).any()


@pytest.mark.parametrize("kind", ["plane-axis", "plane", "rectangle", "disk", "triangle"])
def test_grazing_rays_hit_planar_shapes_at_the_closed_form_t(kind):
    """300 rays per angle α = 1e-1 … 1e-6 rad from the surface, from heights 0.5 to 2: every
    ray hits; |t − t64| ≤ K·u·(S + t)/|n·d| (K = 4; S: the shape's and the origins' coordinate
    magnitudes) against the float64 t for the stored float32 surface, and ≤ 4u·t for the
    axis-aligned plane, where n·d is exact; the hit point lies on the surface within 4u·S, the
    normal is the surface normal."""
    rng = np.random.default_rng(23)
    for alpha in ALPHAS:
        scene, point, normal, P, N, a, b, mag = grazing_planar_scene(kind, alpha)
        o, d = grazing_plane_rays(N, P, a, b, alpha, 300, rng)
        o64, d64 = o.astype(np.float64), unit(d.astype(np.float64))
        denom = d64 @ normal
        t64 = ((point - o64) @ normal) / denom
        h = warprt.trace_rays(scene, o, d)
        assert h["hit"].all(), f"alpha {alpha:g}: {(~h['hit']).sum()} rays missed"
        S = np.maximum(mag, np.abs(o64).max(1))
        bound = K_PLANE * U * (S + t64) / np.abs(denom)
        if kind == "plane-axis":
            bound = np.minimum(bound, 4 * U * t64)
        err = np.abs(h["t"] - t64)
        assert (err <= bound).all(), f"alpha {alpha:g}: t off by {(err / bound).max():.2f} of the bound"
        p = h["position"].astype(np.float64)
        assert np.isfinite(p).all()
        height = np.abs((p - point) @ normal)
        assert (height <= 4 * U * np.maximum(mag, np.abs(p).max(1))).all(), f"alpha {alpha:g}: point off the surface"
        np.testing.assert_allclose(np.abs(h["normal"] @ normal), 1.0, atol=1e-6)


# --- grazing light: the Lambert term -------------------------------------------------------------

KD = 0.8


def grazing_light_scene(height, tilted=False):
    """A plane (y = 0, or tilted through (0.5, −0.25, 0.3)) seen from 2 above, lit by a point light
    3 away along the plane at ``height`` above it (falloff none, ka = 0: pixel = kd·I·n·l)."""
    N = unit(TILT if tilted else (0, 1, 0))
    P = np.array([0.5, -0.25, 0.3]) if tilted else np.zeros(3)
    a = unit(np.cross(N, [0.0, 0.0, 1.0]))
    b = np.cross(N, a)
    light = P + 3.0 * a + height * N
    scene = warprt.Scene(
        camera=warprt.Camera(eye=tuple(P + 2 * N + 2 * b), look_at=tuple(P), fov=50, width=24, height=24),
        shapes=(warprt.Plane(point=tuple(P), normal=tuple(N), material="m"),),
        materials={"m": warprt.Material(kd=KD, ka=0.0)}, lights=(warprt.PointLight(position=tuple(light)),),
        render=warprt.RenderSettings(sampler="regular"))
    return scene, f32(P), f32(N), f32(light)


def lambert_reference(scene, P, N, light):
    """Per pixel centre: n·l (float64) at the exact crossing of the float32 camera ray with the
    stored plane, the crossing, and the unrefined float32 point o + t·d from warprt's t."""
    o, d, h = pixel_hits(scene)
    assert h["hit"].all()
    pe = o + (((P - o) @ N) / (d @ N))[:, None] * d
    to_l = light - pe
    ndl = (to_l @ N) / np.linalg.norm(to_l, axis=1)
    naive = (o.astype(np.float32) + h["t"][:, None] * d.astype(np.float32)).astype(np.float64)
    return ndl, pe, naive


def test_naive_unrefined_hit_point_spoils_lambert_at_a_grazing_light():
    """Light 1e-6 above y = 0: the unrefined point's height error (~ulp of the eye's 2 units)
    makes n·l wrong by more than 5% on a third of the pixels."""
    scene, P, N, light = grazing_light_scene(1e-6)
    ndl, _, naive = lambert_reference(scene, P, N, light)
    to_l = light - naive
    ndl_naive = (to_l @ N) / np.linalg.norm(to_l, axis=1)
    rel = np.abs(ndl_naive - ndl) / ndl
    assert (rel > 0.05).mean() > 0.3, f"only {(rel > 0.05).mean():.0%} of the pixels off by 5%"


@pytest.mark.parametrize("height", [1e-2, 1e-4, 1e-6, 0.0, -1e-6], ids=["1e-2", "1e-4", "1e-6", "0", "-1e-6"])
def test_lambert_term_of_a_grazing_light_matches_the_closed_form(height):
    """y = 0 plane: the pixel is kd·I·n·l within 1e-6 relative (measured 2e-7) for n·l from 6e-3
    down to 2e-7: the point is projected onto the plane, so its height is exact; a light in
    the plane or below it gives exactly 0, never NaN."""
    scene, P, N, light = grazing_light_scene(height)
    img = image(scene)[..., 0].ravel().astype(np.float64)
    assert np.isfinite(img).all()
    if height <= 0.0:
        assert (img == 0.0).all()
        return
    ndl, _, _ = lambert_reference(scene, P, N, light)
    assert ndl.min() > 0.1 * height and ndl.max() < height
    np.testing.assert_allclose(img, KD * ndl, rtol=1e-6, atol=0)


@pytest.mark.parametrize("height", [1e-2, 1e-4], ids=["1e-2", "1e-4"])
def test_lambert_term_on_a_tilted_plane_stays_within_the_float32_bound(height):
    """Tilted plane: the height of a point over it, n·(L − p), is a float32 dot product of
    coordinates ~|L|, |p|, good to u·Σ|n_i|(|L_i| + |p_i|) and no better (the stored light and
    plane carry that much already). The pixel is kd·I·n·l within 4 of those bounds over dist,
    plus 1e-6 relative: 2e-5 relative at h = 1e-2, 3e-3 at 1e-4 (measured 0.4 of the bound)."""
    scene, P, N, light = grazing_light_scene(height, tilted=True)
    img = image(scene)[..., 0].ravel().astype(np.float64)
    ndl, pe, _ = lambert_reference(scene, P, N, light)
    dist = np.linalg.norm(light - pe, axis=1)
    bound = 4 * U * (np.abs(N) * (np.abs(light) + np.abs(pe))).sum(1) / dist + 1e-6 * ndl
    err = np.abs(img - KD * ndl)
    assert (err <= KD * bound).all(), f"off by {(err / (KD * bound)).max():.2f} of the bound"


# --- exactly parallel rays -------------------------------------------------------------------------


def flat_grid(n=8, half=2.0):
    """An n×n grid of squares on y = 0 (two triangles each, normal +y), power-of-two coordinates."""
    xs = np.linspace(-half, half, n + 1)
    v = np.array([[x, 0.0, z] for z in xs for x in xs])
    f = []
    for j in range(n):
        for i in range(n):
            a = j * (n + 1) + i
            f += [(a, a + n + 1, a + 1), (a + 1, a + n + 1, a + n + 2)]
    return v, np.array(f), xs


def test_rays_inside_or_parallel_to_a_flat_mesh_grid_miss_it():
    """Rays in the plane of an 8×8 grid (d_y == 0, o_y == 0): along its grid lines, along its
    diagonals, through its vertices, and in random directions; and the same rays 1e-7 above:
    no hit, t = inf, nothing NaN. Tilted by 1e-3 towards the grid from above, every one hits."""
    v, f, xs = flat_grid()
    scene = warprt.Scene(shapes=(warprt.Mesh(vertices=v, faces=f),))
    rng = np.random.default_rng(24)
    n = 400
    o = np.c_[rng.uniform(-3, 3, n), np.zeros(n), rng.uniform(-3, 3, n)]
    phi = rng.uniform(0, 2 * np.pi, n)
    d = np.c_[np.cos(phi), np.zeros(n), np.sin(phi)]
    o[:100, 0], d[:100] = rng.choice(xs, 100), (0, 0, 1)  # along the lines x = const
    o[100:200, 2], d[100:200] = rng.choice(xs, 100), (1, 0, 0)  # along z = const
    o[200:300, 0] = rng.choice(xs, 100) - o[200:300, 2]  # along the diagonals x + z = const
    d[200:300] = (1, 0, -1)  # (through the vertices too)
    for lift in (0.0, 1e-7):
        q = warprt.trace_rays(scene, o + (0, lift, 0), d)
        assert not q["hit"].any() and np.isinf(q["t"]).all() and (q["shape"] == -1).all()
    # the grid is there: the same rays from 1e-3 above (inside the grid), tilted towards it, hit
    start = np.c_[rng.uniform(-0.5, 0.5, n), np.full(n, 1e-3), rng.uniform(-0.5, 0.5, n)]
    q = warprt.trace_rays(scene, start, d + (0, -1e-3, 0))
    assert q["hit"].all()
    np.testing.assert_allclose(q["t"], np.linalg.norm(d + (0, -1e-3, 0), axis=1), rtol=1e-5)


PARALLEL_KINDS = ["plane", "rectangle", "disk", "mesh"]
KA_COLOUR, BACKGROUND = (0.0, 1.0, 0.0), (1.0, 0.0, 0.0)


def parallel_scene(kind, eye_height):
    """Camera looking along −z at ``eye_height`` over a surface on y = 0 (ambient-only green);
    with an odd height its middle row of pixel rays is exactly horizontal."""
    v, f, _ = flat_grid(half=3.0)
    shape = {"plane": warprt.Plane(material="m"),
             "rectangle": warprt.Rectangle(corner=(-3, 0, -3), edge1=(0, 0, 6), edge2=(6, 0, 0), material="m"),
             "disk": warprt.Disk(center=(0, 0, 0), normal=(0, 1, 0), radius=3.0, material="m"),
             "mesh": warprt.Mesh(vertices=v, faces=f, material="m")}[kind]
    return warprt.Scene(
        camera=warprt.Camera(eye=(0.0, eye_height, 4.0), look_at=(0.0, eye_height, 0.0), fov=40, width=23, height=23),
        shapes=(shape,), materials={"m": warprt.Material(kd=0.0, ka=KA_COLOUR)}, ambient=1.0,
        background=BACKGROUND, render=warprt.RenderSettings(sampler="regular"))


@pytest.mark.parametrize("kind", PARALLEL_KINDS)
def test_camera_rows_exactly_parallel_to_a_surface_render_the_background(kind):
    """Eye 0.5 above the surface: the middle row (d_y == 0 exactly) and everything above it is
    the background, rows below show the surface exactly where the float64 crossing lies inside
    it (1e-4 margin). Eye in the surface's plane: every ray is in the plane or starts on the
    surface (t = 0 is excluded), so the whole image is the background."""
    scene = parallel_scene(kind, 0.5)
    o, d, _ = pixel_hits(scene)
    dy = d[:, 1].reshape(23, 23)
    assert (dy[11] == 0.0).all() and (dy[:11] > 0).all() and (dy[12:] < 0).all()
    img = image(scene).reshape(-1, 3)
    assert np.isfinite(img).all()
    with np.errstate(divide="ignore"):
        t = np.where(d[:, 1] < 0, -o[:, 1] / d[:, 1], np.inf)
    x = o[:, 0] + np.where(np.isfinite(t), t, 0) * d[:, 0]
    z = o[:, 2] + np.where(np.isfinite(t), t, 0) * d[:, 2]
    if kind == "plane":
        inside, margin = np.isfinite(t), np.full(len(t), 1.0)
    elif kind == "disk":
        rho = np.hypot(x, z)
        inside, margin = np.isfinite(t) & (rho <= 3), np.abs(rho - 3)
    else:
        inside = np.isfinite(t) & (np.abs(x) <= 3) & (np.abs(z) <= 3)
        margin = np.minimum(np.abs(np.abs(x) - 3), np.abs(np.abs(z) - 3))
    clear = margin > 1e-4
    expected = np.where(inside[:, None], KA_COLOUR, BACKGROUND)
    np.testing.assert_array_equal(img[clear], expected[clear].astype(np.float32))
    middle = np.zeros((23, 23), bool)
    middle[11] = True
    np.testing.assert_array_equal(img[middle.ravel()], np.broadcast_to(np.float32(BACKGROUND), (23, 3)))
    assert inside[clear].sum() > 40  # the surface is on screen, down to the rows next to the horizon
    in_plane = image(parallel_scene(kind, 0.0))
    np.testing.assert_array_equal(in_plane, np.broadcast_to(np.float32(BACKGROUND), in_plane.shape))


# --- refraction at the critical angle and at grazing incidence -------------------------------------


def fresnel_reference(mode, theta_air):
    """Reflectance (float64) of the air-glass surface for the ray whose angle from the normal is
    ``theta_air`` on the air side (NaN: total internal reflection, reflectance 1); the same for
    light arriving from either side. Exact: Fresnel's equations in angle form, (sin(θa − θg) /
    sin(θa + θg))² and (tan(θa − θg) / tan(θa + θg))² averaged; Schlick: r0 + (1 − r0)(1 − cos θa)^5,
    the cosine taken on the air side whichever side the ray comes from."""
    theta_air = np.asarray(theta_air, np.float64)
    tir = np.isnan(theta_air)
    ta = np.where(tir, 0.5, theta_air)
    if mode == "schlick":
        r0 = ((IOR - 1.0) / (IOR + 1.0)) ** 2
        F = r0 + (1.0 - r0) * (1.0 - np.cos(ta)) ** 5
    else:
        tg = np.arcsin(np.sin(ta) / IOR)
        F = 0.5 * ((np.sin(ta - tg) / np.sin(ta + tg)) ** 2 + (np.tan(ta - tg) / np.tan(ta + tg)) ** 2)
    return np.where(tir, 1.0, F)


def air_angle(theta_glass):
    """Angle on the air side of a ray at ``theta_glass`` inside the glass (NaN under TIR)."""
    with np.errstate(invalid="ignore"):
        return np.arcsin(IOR * np.sin(theta_glass))


WALL_X, WALL_H, WALL_Y = 10.0, 0.1, 0.005  # the wall x = 10 and its light, 0.1 in front at height 0.005


def inside_glass_scene(centre, half, glass, width, height, wall=False):
    """Glass below y = 0 (a plane, normal +y); the camera 1 below the surface looks up at
    ``centre`` rad from the vertical, its rows spanning ±``half`` rad of that angle. The floor
    y = −10 is ambient-only green; the background red. With ``wall``, a diffuse wall
    x = 10 (y from 0 to 5) lit by a light at (9.9, 0.005, 0) replaces the floor."""
    direction = np.array([math.sin(centre), math.cos(centre), 0.0])
    eye = np.array([0.0, -1.0, 0.0])
    cam = warprt.Camera(eye=tuple(eye), look_at=tuple(eye + direction), up=(1, 0, 0),
                        fov=2 * math.degrees(math.atan(math.tan(half))), width=width, height=height)
    shapes = [warprt.Plane(point=(0, 0, 0), normal=(0, 1, 0), material="glass")]
    if wall:
        shapes.append(warprt.Rectangle(corner=(WALL_X, 0, -5), edge1=(0, 0, 10), edge2=(0, 5, 0), material="wall"))
        extra = dict(lights=(warprt.PointLight(position=(WALL_X - WALL_H, WALL_Y, 0.0)),), ambient=0.0,
                     background=(0.0, 0.0, 0.0))
    else:
        shapes.append(warprt.Plane(point=(0, -10, 0), normal=(0, 1, 0), material="floor"))
        extra = dict(ambient=1.0, background=(1.0, 0.0, 0.0))
    return warprt.Scene(camera=cam, shapes=tuple(shapes),
                        materials={"glass": glass, "floor": warprt.Material(kd=0.0, ka=(0, 1, 0)),
                                   "wall": warprt.Material(kd=1.0, ka=0.0)},
                        render=warprt.RenderSettings(sampler="regular"), **extra)


def incidence_angles(scene):
    """Angle of each pixel's float32 ray from the vertical (float64), and the rays."""
    o, d, _ = pixel_hits(scene)
    d = unit(d)
    return np.arccos(d[:, 1]), o, d


def test_naive_schlick_with_the_incident_cosine_jumps_at_the_critical_angle():
    """From inside glass, Schlick with cos θi gives 0.041 just below θc and 1 just above it; with
    the transmitted cosine (warprt, and the exact formula) F is within 0.12 of 1 there."""
    theta = CRIT + np.array([-1e-4, -1e-6, 1e-6])
    r0 = ((IOR - 1) / (IOR + 1)) ** 2
    naive = np.where(IOR * np.sin(theta) > 1, 1.0, r0 + (1 - r0) * (1 - np.cos(theta)) ** 5)
    assert naive[0] < 0.05 and naive[1] < 0.05 and naive[2] == 1.0
    for mode in ("exact", "schlick"):
        assert (fresnel_reference(mode, air_angle(theta)) > 0.88).all()


def test_total_internal_reflection_switches_exactly_at_the_critical_angle():
    """kt = 0.7, km = 0.2, no Fresnel, rows within ±2e-4 and ±2e-6 rad of θc: (kt + km)·floor
    under TIR (1.5·sin θ > 1), km·floor + kt·red below, exactly (1e-6), for every ray more than
    1e-6 rad from θc; inside that band one of the two, never less (kt is not lost)."""
    glass = warprt.Material(kd=0.0, ka=0.0, transparency=0.7, mirror=0.2, ior=IOR)
    floor, red = np.array([0.0, 1.0, 0.0]), np.array([1.0, 0.0, 0.0])
    tir_value, through_value = 0.9 * floor, 0.2 * floor + 0.7 * red
    near = 0
    for half in (2e-4, 2e-6):
        scene = inside_glass_scene(CRIT, half, glass, 8, 48)
        img = image(scene).reshape(-1, 3).astype(np.float64)
        theta, _, _ = incidence_angles(scene)
        dth = theta - CRIT
        is_tir = np.abs(img - tir_value).max(1) <= 1e-6
        is_through = np.abs(img - through_value).max(1) <= 1e-6
        assert (is_tir | is_through).all(), f"{(~is_tir & ~is_through).sum()} pixels lost energy"
        far = np.abs(dth) > 1e-6
        np.testing.assert_array_equal(is_tir[far], (IOR * np.sin(theta) > 1)[far])
        assert (far & (dth > 0)).sum() > 20 and (far & (dth < 0)).sum() > 20
        near += (~far).sum()
    assert near > 50  # the band itself is exercised


@pytest.mark.parametrize("mode", ["exact", "schlick"])
def test_fresnel_tends_to_one_at_the_critical_angle(mode):
    """kt = 1 with Fresnel: green (the reflection sees the floor) = F, red (the refraction sees
    the background) = 1 − F. Within ±2e-4 and ±2e-6 rad of θc, F lies between the float64
    values at θ ± 2e-7 (F is steep there: dF/dθ ~ 1/√(θc − θ)), is 1 under TIR and above 0.88
    everywhere, and the two shares sum to 1."""
    glass = warprt.Material(kd=0.0, ka=0.0, transparency=1.0, ior=IOR, fresnel=mode)
    for half in (2e-4, 2e-6):
        scene = inside_glass_scene(CRIT, half, glass, 4, 48)
        img = image(scene).reshape(-1, 3).astype(np.float64)
        theta, _, _ = incidence_angles(scene)
        lo = fresnel_reference(mode, air_angle(theta - 2e-7))  # F grows with θ up to θc
        hi = fresnel_reference(mode, air_angle(theta + 2e-7))
        F = img[:, 1]
        assert (F >= lo - 1e-6).all() and (F <= hi + 1e-6).all(), \
            f"{((F < lo - 1e-6) | (F > hi + 1e-6)).sum()} pixels outside the bracket"
        np.testing.assert_allclose(img[:, 0] + img[:, 1], 1.0, atol=1e-6)
        assert F.min() > 0.88
        tir = theta - CRIT > 2e-7
        assert tir.sum() > 20 and (F[tir] == 1.0).all()
        assert ((theta < CRIT - 2e-7) & (F < 0.999)).sum() > 20


def exit_height(theta, o):
    """Where the ray leaving the glass at θ (from the vertical) meets the wall x = WALL_X: the exit
    point x_e, the documented spawn offset 2^-17·|x_e| above it, then rise (X − x_e)·tan β with
    sin β = cos θt = √(1 − η² sin² θ) (float64)."""
    xe = o[:, 0] + (-o[:, 1]) * np.tan(theta)
    s = IOR * np.sin(theta)
    return SPAWN_REL * np.abs(xe) + (WALL_X - xe) * np.sqrt(np.maximum(0.0, 1.0 - s * s)) / s


def test_exit_direction_just_below_the_critical_angle_follows_snell():
    """Rays 1.2e-5 … 2.1e-4 and 6e-7 … 2.5e-6 rad below θc leave the glass almost along the
    surface (elevation 0.07° … 1.2°) and meet a lit wall 9 units away; the wall's radiance h/√(h² +
    (y − y_L)²) gives back the height y, which lies between the closed form at θ ± 2e-7 (1e-6
    decoding tolerance). The bracket is 8e-4 … 4e-3 wide; the heights are 0.01 … 0.2."""
    glass = warprt.Material(kd=0.0, ka=0.0, transparency=1.0, ior=IOR)
    for centre, half in ((CRIT - 1.1e-4, 1e-4), (CRIT - 1.5e-6, 1e-6)):
        scene = inside_glass_scene(centre, half, glass, 1, 48, wall=True)
        v = image(scene)[:, 0, 0].astype(np.float64)
        theta, o, _ = incidence_angles(scene)
        assert (theta < CRIT - 5e-7).all()
        y = WALL_Y + WALL_H * np.sqrt(1.0 / v ** 2 - 1.0)
        lo, hi = exit_height(theta + 2e-7, o), exit_height(theta - 2e-7, o)
        assert (y >= lo - 1e-6).all() and (y <= hi + 1e-6).all(), \
            f"heights {y[(y < lo - 1e-6) | (y > hi + 1e-6)][:3]} outside [{lo[:3]}, {hi[:3]}]"
        assert (exit_height(theta, o) > 0.01).all()


FLOOR_D, LIGHT_X, LIGHT_H = 1.0, 1.5, 0.5


def grazing_glass_scene(alpha, glass, lit_floor=True):
    """Glass below y = 0; the camera at height α looks along +x, its 16 rows at 0.5α … 1.5α below
    the horizontal, so the rays enter about 1 unit away. Under the glass a floor y = −1: diffuse
    and lit by a light 0.5 above it (lit_floor), or ambient-only green under a red sky."""
    eye = np.array([0.0, alpha, 0.0])
    cam = warprt.Camera(eye=tuple(eye), look_at=tuple(eye + (math.cos(alpha), -math.sin(alpha), 0.0)),
                        fov=2 * math.degrees(math.atan(math.tan(0.5 * alpha))), width=1, height=16)
    floor = warprt.Material(kd=1.0, ka=0.0) if lit_floor else warprt.Material(kd=0.0, ka=(0, 1, 0))
    extra = (dict(lights=(warprt.PointLight(position=(LIGHT_X, -FLOOR_D + LIGHT_H, 0.0)),)) if lit_floor
             else dict(ambient=1.0, background=(1.0, 0.0, 0.0)))
    # min_weight 0: near grazing the refracted share 1 − F (~6 sin α) is below the default 1e-4
    return warprt.Scene(camera=cam, shapes=(warprt.Plane(point=(0, 0, 0), normal=(0, 1, 0), material="glass"),
                                            warprt.Plane(point=(0, -FLOOR_D, 0), normal=(0, 1, 0), material="floor")),
                        materials={"glass": glass, "floor": floor},
                        render=warprt.RenderSettings(sampler="regular", min_weight=0.0), **extra)


@pytest.mark.parametrize("alpha", [1e-2, 1e-4, 1e-6], ids=["1e-2", "1e-4", "1e-6"])
def test_refraction_at_grazing_incidence_follows_snell(alpha):
    """kt = 1, no Fresnel: the pixel is the floor's radiance h/√(h² + ρ²) where the refracted ray
    lands, ρ from the light's foot. The landing point from the float32 ray in float64 (entry
    point, t = η d + (η c − √k) n, the refracted ray starting (|n|·|p|)·2^-17 below the surface) and
    the decoded ρ agree within 1e-6 (measured 3e-7); the ray's slope tends to tan θc as α → 0."""
    scene = grazing_glass_scene(alpha, warprt.Material(kd=0.0, ka=0.0, transparency=1.0, ior=IOR))
    v = image(scene)[:, 0, 0].astype(np.float64)
    o, d, _ = pixel_hits(scene)
    d = unit(d)
    sin_a = -d[:, 1]
    assert (sin_a > 0.4 * alpha).all() and (sin_a < 1.6 * alpha).all()
    entry = o + (o[:, 1] / sin_a)[:, None] * d
    entry[:, 1] = 0.0
    n, eta = np.array([0.0, 1.0, 0.0]), 1.0 / IOR
    k = 1.0 - eta ** 2 * (1.0 - sin_a ** 2)
    tdir = eta * d + (eta * sin_a - np.sqrt(k))[:, None] * n
    start = entry - (SPAWN_REL * np.abs(entry) @ np.abs(n))[:, None] * n  # (|n|·max(|p|, |p0|))·2^-17, p0 = 0
    land = start + ((-FLOOR_D - start[:, 1]) / tdir[:, 1])[:, None] * tdir
    rho = np.hypot(land[:, 0] - LIGHT_X, land[:, 2])
    rho_measured = LIGHT_H * np.sqrt(1.0 / v ** 2 - 1.0)
    np.testing.assert_allclose(rho_measured, rho, atol=1e-6)
    assert np.abs(-tdir[:, 0] / tdir[:, 1] - math.tan(CRIT)).max() < 2 * alpha  # the slope tends to tan θc


@pytest.mark.parametrize("mode", ["exact", "schlick"])
def test_fresnel_reflectance_tends_to_one_at_grazing_incidence(mode):
    """kt = 1 with Fresnel from outside at 1e-2 … 1e-6 rad from the surface: red (the reflection
    sees the sky) = F, green (the refraction sees the floor) = 1 − F, each within 1e-6 of the
    float64 closed form at the ray's angle; 1 − F ≤ 8·sin α → 0 (1 − F ≈ 5.8 sin α exact, 4.8 sin α
    Schlick)."""
    for alpha in (1e-2, 1e-4, 1e-6):
        glass = warprt.Material(kd=0.0, ka=0.0, transparency=1.0, ior=IOR, fresnel=mode)
        scene = grazing_glass_scene(alpha, glass, lit_floor=False)
        img = image(scene)[:, 0].astype(np.float64)
        _, d, _ = pixel_hits(scene)
        cos_i = -unit(d)[:, 1]
        F = fresnel_reference(mode, np.arccos(cos_i))
        np.testing.assert_allclose(img[:, 0], F, atol=1e-6)
        np.testing.assert_allclose(img[:, 1], 1.0 - F, atol=1e-6)
        assert (1.0 - F <= 8 * cos_i).all() and (img[:, 2] == 0).all()


# --- rays through mesh edges and vertices ------------------------------------------------------------

GENERAL = rotation([0.3, 0.8, -0.5], 0.7)  # puts a mesh in general position: no edge along an axis


def closed_mesh(name, general=True):
    """trimesh's icosphere (subdivision 2, radius 1) or box (2×2×2), axis-aligned as built or
    turned into general position; float32 vertices."""
    import trimesh

    m = trimesh.creation.icosphere(subdivisions=2) if name == "icosphere" else trimesh.creation.box(extents=(2, 2, 2))
    v, f = np.asarray(m.vertices, np.float64), np.asarray(m.faces, np.int64)
    return f32(v @ GENERAL.T if general else v), f


def shared_edges(v, f):
    """Every edge shared by two faces (vertex pair) and those two faces."""
    import trimesh

    m = trimesh.Trimesh(vertices=v, faces=f, process=False)
    return np.asarray(m.face_adjacency_edges), np.asarray(m.face_adjacency)


def edge_rays(v, f, rng, reps=1):
    """Rays at random points of every shared edge (2% … 98% along it, float64 on the float32
    edge) of a closed convex mesh: from random points inside, and from outside along directions
    that enter both faces there. For a convex mesh the first hit is the target itself."""
    edges, adjacent = shared_edges(v, f)
    tri = v[f]
    fn = unit(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]))
    origins, targets = [], []
    for _ in range(reps):
        w = rng.uniform(0.02, 0.98, (len(edges), 1))
        tg = w * v[edges[:, 0]] + (1 - w) * v[edges[:, 1]]
        origins.append(rng.uniform(-0.4, 0.4, tg.shape))
        targets.append(tg)
        d_out = -unit(tg + 0.7 * unit(rng.normal(size=tg.shape)))
        entering = (np.einsum("ekj,ej->ek", fn[adjacent], d_out) < -1e-3).all(axis=1)
        origins.append((tg - 3.0 * d_out)[entering])
        targets.append(tg[entering])
    o, tg = np.concatenate(origins), np.concatenate(targets)
    return o.astype(np.float32), unit(tg - o).astype(np.float32), tg


def naive_moller_trumbore(o, d, tris, strict):
    """Any hit of each ray among the triangles, Möller-Trumbore in float32."""
    o, d, tris = (np.asarray(x, np.float32) for x in (o, d, tris))
    a, e1, e2 = tris[:, 0], tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0]
    pv = np.cross(d[:, None], e2[None])
    det = np.sum(e1[None] * pv, 2)
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = np.float32(1.0) / det
        s = o[:, None] - a[None]
        u = np.sum(s * pv, 2) * inv
        q = np.cross(s, e1[None])
        vv = np.sum(d[:, None] * q, 2) * inv
        t = np.sum(e2[None] * q, 2) * inv
        if strict:
            inside = (u > 0) & (vv > 0) & (u + vv < 1)
        else:
            inside = (u >= 0) & (vv >= 0) & (u + vv <= 1)
    return ((det != 0) & inside & (t > 0)).any(axis=1)


def test_naive_strict_moller_trumbore_leaks_at_shared_edges():
    """Rays at shared edges of the icosphere in general position: strict float32 MT misses every
    face on > 10% of them (measured 19%), inclusive float32 MT on > 1% (measured 4.4%: the two
    faces compute their shared edge differently). On the axis-aligned grid, rays from dyadic
    points to dyadic points of its inner edges make u or v exactly 0: strict MT leaks > 90%
    (measured: all)."""
    v, f = closed_mesh("icosphere")
    o, d, _ = edge_rays(v, f, np.random.default_rng(25))
    strict = ~naive_moller_trumbore(o, d, v[f], strict=True)
    inclusive = ~naive_moller_trumbore(o, d, v[f], strict=False)
    assert strict.mean() > 0.1 and inclusive.mean() > 0.01, (strict.mean(), inclusive.mean())
    gv, gf, _ = flat_grid()
    edges, _ = shared_edges(gv, gf)
    rng = np.random.default_rng(26)
    w = rng.integers(1, 8, (len(edges), 1)) / 8.0
    tg = w * gv[edges[:, 0]] + (1 - w) * gv[edges[:, 1]]
    src = tg + np.c_[rng.integers(-8, 8, len(tg)) / 4, np.full(len(tg), 2.0), rng.integers(-8, 8, len(tg)) / 4]
    assert (~naive_moller_trumbore(src, tg - src, gv[gf], strict=True)).mean() > 0.9


@pytest.mark.parametrize("name", ["icosphere", "cube"])
def test_rays_at_shared_edges_of_a_closed_mesh_never_leak(name):
    """The icosphere (480 edges) and the cube (18 edges) in general position, rays at random points
    of every shared edge from inside and from outside (48k and 58k rays; 288k more with other
    rotations and seeds, measured once: no leak either): every ray hits, at the target's
    distance within 1e-5, with a finite unit normal."""
    v, f = closed_mesh(name)
    rng = np.random.default_rng(27)
    o, d, tg = edge_rays(v, f, rng, reps=50 if name == "icosphere" else 1600)
    h = warprt.trace_rays(warprt.Scene(shapes=(warprt.Mesh(vertices=v, faces=f),)), o, d)
    assert len(o) > 40000
    assert h["hit"].all(), f"{(~h['hit']).sum()} of {len(o)} rays leaked"
    t_ref = np.linalg.norm(tg - o.astype(np.float64), axis=1)
    np.testing.assert_allclose(h["t"], t_ref, atol=1e-5)
    assert np.isfinite(h["normal"]).all()
    np.testing.assert_allclose(np.linalg.norm(h["normal"], axis=1), 1.0, atol=1e-6)


# mesh, general position, target kind: the largest leak share allowed on CUDA, about twice the
# share measured with Warp's own query (fixed seeds; "measured" in parentheses). Warp's ray-box
# slab test (no rounding margin) can cull both faces of a point on their boxes' boundary: vertices
# are box corners, an edge along an axis lies on box faces. Such rays come from constructions
# like these, not from camera rays: a camera's rays cross a mesh edge exactly only by coincidence.
# On the CPU meshes are traced by warprt's own traversal (``accel.mesh_tree_ray``), whose slab
# test takes a margin of 4e-7: no ray leaks there (measured: 0 in every case), and none may.
LEAK_BOUNDS = [("icosphere", True, "vertex", 0.008),   # (0.37%)
               ("icosphere", False, "vertex", 0.012),  # (0.54%)
               ("icosphere", False, "edge", 0.001),    # (0.023%: the edges at constant y and z)
               ("cube", False, "edge", 0.02),          # (0.98%)
               ("cube", False, "vertex", 0.06),        # (2.8%)
               ("grid", False, "edge", 0.045),         # (2.2%: flat 8x8 grid, rays from both sides)
               ("grid", False, "vertex", 0.07)]        # (3.6%)


@pytest.mark.parametrize("name, general, target, bound", LEAK_BOUNDS,
                         ids=[f"{n}-{'general' if g else 'axis'}-{t}" for n, g, t, _ in LEAK_BOUNDS])
def test_leaks_at_vertices_and_axis_aligned_edges_stay_rare(name, general, target, bound):
    """Rays aimed exactly at vertices, or at points of edges lying along coordinate axes, never
    leak on the CPU and leak at a bounded rate on CUDA. A leaked ray misses the mesh or passes
    through to a far face: its t is not the target's distance within 1e-5 (the mesh is convex,
    or flat)."""
    rng = np.random.default_rng(28)
    if name == "grid":
        v, f, _ = flat_grid()
        edges, _ = shared_edges(v, f)
        inner = np.nonzero((np.abs(v[:, 0]) < 2) & (np.abs(v[:, 2]) < 2))[0]
        pts = []
        for _ in range(30 if target == "edge" else 100):
            if target == "edge":
                w = rng.uniform(0.02, 0.98, (len(edges), 1))
                pts.append(w * v[edges[:, 0]] + (1 - w) * v[edges[:, 1]])
            else:
                pts.append(v[inner])
        tg = np.concatenate(pts)
        lean = np.c_[rng.uniform(-1, 1, len(tg)), rng.uniform(0.2, 1, len(tg)), rng.uniform(-1, 1, len(tg))]
        lean[len(tg) // 2:, 1] *= -1  # half from below
        o = tg + unit(lean) * rng.uniform(1, 4, (len(tg), 1))
    else:
        v, f = closed_mesh(name, general)
        if target == "edge":
            o, _, tg = edge_rays(v, f, rng, reps=40 if name == "icosphere" else 400)
        else:
            tg = np.concatenate([v] * (60 if name == "icosphere" else 400))
            o = rng.uniform(-0.4, 0.4, tg.shape)
    o = np.asarray(o, np.float32)
    h = warprt.trace_rays(warprt.Scene(shapes=(warprt.Mesh(vertices=v, faces=f),)), o, unit(tg - o))
    assert len(o) > 3000
    t_ref = np.linalg.norm(tg - o.astype(np.float64), axis=1)
    leaked = np.abs(h["t"] - t_ref) > 1e-5  # inf for a miss
    if warprt._warp.resolve_device(None).is_cpu:
        bound = 0.0
    assert leaked.mean() <= bound, f"{leaked.mean():.3%} of the rays leaked (bound {bound:.2%})"
