"""Rays that start inside objects, lights inside closed objects, and the recursion limits.

Failure modes, the naive method that shows each one, and what warprt does:

* **camera inside glass**: a camera ray meets the sphere from the inside, where the outward
  normal faces away from it. Snell's law applied as for an entering ray (normal as given, η =
  1/ior) sends every "transmitted" ray back into the sphere. warprt turns the normal towards the
  ray (``front = d·ng < 0``), swaps the indices (η = ior/1) and so gets, for a camera inside a
  glass sphere in a uniform background B (ambient Ia = 1):
  - clear glass (kt, ka, no Fresnel): ka·Ia + kt·B where the exit angle is below the critical
    angle (one crossing: kt, not kt²), and under total internal reflection the chord repeats at
    the same angle, so the pixel is the series ka·Ia·Σ_{k=0..D} kt^k truncated at max_depth D;
  - lossless Fresnel glass (kt = 1, exact Fresnel, ka = 0): the light escaping within D bounces,
    B·(1 − F^D), with F the reflectance at the exit angle (1 under TIR: black).
  Each reflected ray starts the documented offset 2^-17·(|c| + r) inside the surface, so the
  chord's sin θ shrinks by (1 − 2^-17) per bounce; the closed form follows that (it matters only
  near the critical angle, where F is steep).
* **a point light inside a closed object**: an opaque sphere or closed mesh around the light
  leaves everything outside, the object included, at exactly ka·Ia (no light term at all: the
  outer surface faces away from the light, and every shadow ray from outside crosses the
  object). Inside a transparent sphere or closed mesh the documented shadow rule applies: the
  shadow ray is multiplied by kt per surface crossed, here once, with no refraction (no caustics).
  A transparent mesh is walked crossing by crossing; restarting the walk at o + d·t from a far
  origin (a far floor point) found the same crossing again within the float32 error of o + d·t,
  so far floor pixels got kt² or kt³ instead of kt, some even no light at all (the walk stuck at
  one crossing); the walk now restarts from the crossing rebuilt on its triangle.
* **max depth / the ray stack**: a naive recursive tracer between two facing mirrors never stops
  (Python: RecursionError). warprt's iterative stack gives exactly the geometric series truncated
  at max_depth D (one ray per bounce, so D = 64 never overflows the 16 entries); with two
  children per hit (a mirror that also transmits) the stack holds d + 1 entries at depth d, so
  D ≤ 15 never overflows, and D ≥ 16 drops the reflected ray at depth 15: one dropped ray per
  pixel sample, counted in ``RenderResult.stack_overflows``, and the image is the closed form of
  the series cut there. ``min_weight``: a ray whose throughput (largest RGB component) is not
  above it is not traced, tested exactly at and just below a power of two.

Every render uses the all-features kernel through ``_util``; images are at most 32×32.
"""

from __future__ import annotations

import sys

import numpy as np
import pytest

import warprt
from reference_formulas import fresnel_exact

from ._util import SPAWN_REL, image, pixel_hits, render, unit

B = np.array([0.2, 0.5, 1.0])
IOR = 1.5


# --- camera inside a glass sphere --------------------------------------------------------------

DEPTH = 8


def inside_scene(material, eye, look_at, width=32, fov=50.0):
    return warprt.Scene(
        camera=warprt.Camera(eye=eye, look_at=look_at, fov=fov, width=width, height=width),
        shapes=(warprt.Sphere(center=(0, 0, 0), radius=1.0, material="glass"),), materials={"glass": material},
        ambient=1.0, background=tuple(B),
        render=warprt.RenderSettings(sampler="regular", max_depth=DEPTH, min_weight=0.0))


# the eye 0.9 from the centre, looking 40 degrees away from the outward direction: the exit angle
# θ has sin θ = 0.9·sqrt(1 - d_x²), above the critical 1/1.5 on the left of the image, below it on
# the right
OFF_EYE = (0.9, 0.0, 0.0)
OFF_LOOK = (0.9 - np.sin(np.radians(40.0)), 0.0, -np.cos(np.radians(40.0)))


def exit_geometry(scene):
    """float64 per pixel: cos of the angle between the camera ray and the outward normal where it
    leaves the unit sphere, and sin θ·ior / 1 (> 1: total internal reflection)."""
    o, d, h = pixel_hits(scene)
    assert h["hit"].all()
    b = np.sum(o * d, 1)
    t = -b + np.sqrt(b * b - (np.sum(o * o, 1) - 1.0))  # the far root: the eye is inside
    n = o + t[:, None] * d
    cos_i = np.sum(d * n, 1)
    return cos_i, IOR * np.sqrt(np.maximum(0.0, 1.0 - cos_i ** 2)), h


def test_naive_refraction_at_an_inner_hit_goes_back_inside():
    """Snell's law as for an entering ray (outward normal, η = 1/ior) at the inner hit: the
    'transmitted' direction points into the sphere for every pixel."""
    scene = inside_scene(warprt.Material(kd=0, ka=0, transparency=1.0), OFF_EYE, OFF_LOOK)
    o, d, h = pixel_hits(scene)
    b = np.sum(o * d, 1)
    t = -b + np.sqrt(b * b - (np.sum(o * o, 1) - 1.0))
    n = o + t[:, None] * d  # outward unit normal
    eta = 1.0 / IOR
    cos_i = -np.sum(d * n, 1)  # negative: the ray leaves through the surface
    k = 1.0 - eta * eta * (1.0 - cos_i ** 2)
    assert (k > 0).all()  # the naive formula does not even see the total internal reflection
    tdir = eta * d + (eta * cos_i - np.sqrt(k))[:, None] * n
    assert (np.sum(tdir * n, 1) < 0).all(), "the naive transmitted rays should point back inside"


def chord_chain(sin0, kt, ka, fresnel, depth=DEPTH):
    """float64 radiance of a camera ray that starts inside the unit sphere (kd = km = 0, no
    lights, ambient 1) and meets the surface with sin θ = sin0: at each inner hit ka·Ia times the
    throughput, then the refracted share escapes to B and the reflected share (kt under TIR, or
    F with Fresnel) goes on along a chord. Every inner hit of a sphere repeats the angle, except
    that each reflected ray starts the documented offset 2^-17·(|c| + r) = 2^-17 inside the
    surface, which shrinks the chord's impact parameter: sin θ_(k+1) = sin θ_k·(1 − 2^-17)."""
    w = np.ones_like(sin0)
    L = np.zeros(sin0.shape + (3,))
    s = np.array(sin0, np.float64)
    for k in range(depth + 1):
        L += (w * ka)[:, None]
        if k == depth:
            break
        tir = s * IOR >= 1.0
        if fresnel:
            F = fresnel_exact(np.sqrt(np.maximum(0.0, 1.0 - s * s)), IOR, 1.0)
            L += (w * (1.0 - F))[:, None] * B
            w = w * F
        else:
            L += np.where(tir, 0.0, w * kt)[:, None] * B
            w = np.where(tir, w * kt, 0.0)
        s = s * (1.0 - SPAWN_REL)
    return L


def test_camera_inside_clear_glass_sphere():
    """ka·Ia + kt·B outside the TIR region (one crossing: kt, not kt²), ka·Ia·Σ_{k≤D} kt^k inside
    it (measured agreement 2.3e-8). Tolerance 2e-6 absolute (float32 sums of at most D + 1
    terms); pixels within 1e-3 of the critical angle are left out (there the float32 angle, and
    the offset's drift of (1 − 2^-17)^D ≈ 1 − 6e-5, may decide TIR either way)."""
    kt, ka = 0.7, 0.1
    scene = inside_scene(warprt.Material(kd=0.0, ka=ka, transparency=kt, ior=IOR), OFF_EYE, OFF_LOOK)
    img = image(scene).reshape(-1, 3).astype(np.float64)
    cos_i, sin_ratio, _ = exit_geometry(scene)
    tir = sin_ratio > 1.0
    clear = np.abs(sin_ratio - 1.0) > 1e-3
    assert (tir & clear).sum() > 150 and (~tir & clear).sum() > 150, "both regions should be on screen"
    expected = chord_chain(sin_ratio / IOR, kt, ka, fresnel=False)
    series = ka * (1.0 - kt ** (DEPTH + 1)) / (1.0 - kt)
    np.testing.assert_allclose(expected[tir & clear], series, rtol=1e-12)  # no escape under TIR
    out = ~tir & clear
    np.testing.assert_allclose(expected[out], np.broadcast_to(ka + kt * B, (out.sum(), 3)), rtol=1e-12)
    err = np.abs(img - expected)[clear].max()
    assert err <= 2e-6, f"worst error {err:.3g}"
    assert np.isfinite(img).all()


@pytest.mark.parametrize("where", ["centre", "off-centre", "near-critical"])
def test_camera_inside_fresnel_glass_sphere(where):
    """Lossless glass (kt = 1, exact Fresnel, ka = 0): with reflectance F_k at the k-th inner hit
    the light escaping within D bounces is B·Σ_k (1 − F_k)·Π_{j<k} F_j, B·(1 − F^D) for a fixed
    angle; from the centre F = 0.04 (normal incidence) at every hit, under TIR nothing escapes.
    F is steep near the critical angle (a relative change of 1e-6 in sin θ moves the pixel by
    3.7e-4 at sin θ·ior = 0.9996), so the pixel must lie in the closed form's bracket for sin θ
    scaled by 1 ± 4e-6 (about 32 ulps: the float32 rounding of up to D chords, each with a
    normal and a reflected direction), plus 2e-5 absolute. Measured: within 3.1e-5 of the
    unbracketed closed form more than 1e-3 from the critical angle, 7.7e-4 at 0.99956 (the
    fixed-angle B·(1 − F^D), ignoring the offset's drift, is off by 1.1e-2 there)."""
    eye, look = {"centre": ((0, 0, 0), (0.2, 0.1, -1.0)), "off-centre": (OFF_EYE, OFF_LOOK),
                 "near-critical": ((0.95, 0, 0), (0.95 - np.sin(np.radians(42)), 0.0, -np.cos(np.radians(42))))}[where]
    scene = inside_scene(warprt.Material(kd=0.0, ka=0.0, transparency=1.0, ior=IOR, fresnel="exact"), eye, look)
    img = image(scene).reshape(-1, 3).astype(np.float64)
    cos_i, sin_ratio, _ = exit_geometry(scene)
    sin0 = sin_ratio / IOR
    if where == "centre":
        np.testing.assert_allclose(fresnel_exact(cos_i, IOR, 1.0), 0.04, atol=1e-12)
        np.testing.assert_allclose(img, np.broadcast_to(B * (1 - 0.04 ** DEPTH), img.shape), atol=2e-6)
    a, b = chord_chain(sin0 * (1 - 4e-6), 1.0, 0.0, True), chord_chain(sin0 * (1 + 4e-6), 1.0, 0.0, True)
    lo, hi = np.minimum(a, b) - 2e-5, np.maximum(a, b) + 2e-5
    out = np.maximum(lo - img, img - hi).max(axis=1)
    assert (out <= 0).all(), f"{(out > 0).sum()} pixels outside the bracket, worst by {out.max():.3g}"
    if where != "centre":
        assert (sin_ratio > 1.001).sum() > 50 and (sin_ratio < 0.999).sum() > 150
        assert (img[sin_ratio > 1.001] == 0).all()  # TIR: nothing escapes, exactly


# --- a point light inside a closed object ------------------------------------------------------

BOX_V = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], np.float64)
BOX_F = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
                  [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]])


def uv_sphere(n_lat=10, n_lon=16):
    """A closed triangulated unit sphere: two poles, n_lat - 1 rings, pole fans and quads."""
    v = [[0.0, 1.0, 0.0]]
    for i in range(1, n_lat):
        th = np.pi * i / n_lat
        for j in range(n_lon):
            ph = 2 * np.pi * j / n_lon
            v.append([np.sin(th) * np.cos(ph), np.cos(th), np.sin(th) * np.sin(ph)])
    v.append([0.0, -1.0, 0.0])
    ring = lambda i, j: 1 + (i - 1) * n_lon + j % n_lon  # noqa: E731
    f = [[0, ring(1, j + 1), ring(1, j)] for j in range(n_lon)]
    for i in range(1, n_lat - 1):
        for j in range(n_lon):
            f += [[ring(i, j), ring(i, j + 1), ring(i + 1, j + 1)], [ring(i, j), ring(i + 1, j + 1), ring(i + 1, j)]]
    last = len(v) - 1
    f += [[last, ring(n_lat - 1, j), ring(n_lat - 1, j + 1)] for j in range(n_lon)]
    return np.array(v), np.array(f)


CENTRE = (0.2, 0.8, -0.1)
KA_FLOOR, KA_OBJ, IA, KD_FLOOR = 0.25, 0.75, 0.5, 0.7


def enclosure(kind, material):
    if kind == "sphere":
        return warprt.Sphere(center=CENTRE, radius=0.6, material=material)
    if kind == "box-mesh":
        return warprt.Mesh(vertices=BOX_V, faces=BOX_F, material=material,
                           transform=warprt.Transform(translate=CENTRE, rotate=(20, 35, 10), scale=0.5))
    v, f = uv_sphere()
    return warprt.Mesh(vertices=v, faces=f, material=material,
                       transform=warprt.Transform(translate=CENTRE, rotate=(10, 0, 30), scale=0.6))


def light_inside_scene(kind, obj_material, width=32):
    return warprt.Scene(
        camera=warprt.Camera(eye=(0.0, 1.8, 3.5), look_at=(0.0, 0.4, 0.0), fov=55, width=width, height=width),
        shapes=(warprt.Plane(material="floor"), enclosure(kind, "obj")),
        materials={"floor": warprt.Material(kd=KD_FLOOR, ka=KA_FLOOR, ks=0.3, p=10), "obj": obj_material},
        lights=(warprt.PointLight(position=CENTRE, intensity=(1.0, 0.9, 0.8)),), ambient=IA,
        render=warprt.RenderSettings(sampler="regular"))


@pytest.mark.parametrize("kind", ["sphere", "box-mesh", "uv-sphere-mesh"])
def test_light_inside_an_opaque_closed_object_gives_ambient_only_exactly(kind):
    scene = light_inside_scene(kind, warprt.Material(kd=0.8, ka=KA_OBJ, ks=0.5, p=20))
    img = image(scene).reshape(-1, 3)
    _, _, h = pixel_hits(scene)
    floor, obj = h["shape"] == 0, h["shape"] == 1
    assert floor.sum() > 300 and obj.sum() > 40
    np.testing.assert_array_equal(img[floor], np.float32(KA_FLOOR) * np.float32(IA))
    np.testing.assert_array_equal(img[obj], np.float32(KA_OBJ) * np.float32(IA))
    np.testing.assert_array_equal(img[~h["hit"]], 0.0)


@pytest.mark.parametrize("kind", ["sphere", "box-mesh", "uv-sphere-mesh"])
def test_light_inside_a_transparent_closed_object_is_attenuated_once_by_kt(kind):
    """Documented rule: the shadow ray keeps kt per surface crossed, without refraction; from the
    floor to a light inside a closed object it crosses one surface: the floor is
    ka·Ia + kt·I·(kd·n·l + ks·(n·h)^p) (float64 closed form, 1e-5 relative)."""
    kt = np.array([0.6, 0.5, 0.4])
    scene = light_inside_scene(kind, warprt.Material(kd=0.0, ka=0.0, transparency=tuple(kt)))
    img = image(scene).reshape(-1, 3).astype(np.float64)
    o, d, h = pixel_hits(scene)
    floor = h["shape"] == 0
    assert floor.sum() > 300
    p = h["position"][floor].astype(np.float64)
    l = unit(np.asarray(CENTRE) - p)
    ndl = l[:, 1]
    ndh = unit(l - d[floor])[:, 1]
    I = np.array([1.0, 0.9, 0.8])
    expected = KA_FLOOR * IA + kt * I * (KD_FLOOR * ndl + 0.3 * ndh ** 10)[:, None]
    np.testing.assert_allclose(img[floor], expected, rtol=1e-5, atol=1e-6)
    twice = KA_FLOOR * IA + kt ** 2 * I * (KD_FLOOR * ndl + 0.3 * ndh ** 10)[:, None]
    assert np.abs(img[floor] - twice).max() > 0.05  # kt² (a sphere crossed twice) is far off


# --- hall of mirrors: max_depth, the ray stack, min_weight -------------------------------------

def test_shadow_through_a_transparent_sphere_keeps_kt_per_crossing():
    """The light outside, above a clear sphere: a floor point's shadow ray crosses the sphere's
    surface twice (kt²) or not at all (float64 ray-sphere test per pixel; pixels whose shadow ray
    passes within 1e-4 of the silhouette are left out). The floor is
    ka·Ia + kt^crossings·I·(kd·n·l + ks·(n·h)^p)."""
    kt = np.array([0.6, 0.5, 0.4])
    light = np.array([0.3, 2.6, 0.1])
    c, r = np.array([0.1, 1.0, 0.2]), 0.6
    scene = warprt.Scene(
        camera=warprt.Camera(eye=(0.0, 1.8, 3.5), look_at=(0.0, 0.4, 0.0), fov=55, width=32, height=32),
        shapes=(warprt.Plane(material="floor"), warprt.Sphere(center=tuple(c), radius=r, material="obj")),
        materials={"floor": warprt.Material(kd=KD_FLOOR, ka=KA_FLOOR, ks=0.3, p=10),
                   "obj": warprt.Material(kd=0.0, ka=0.0, transparency=tuple(kt))},
        lights=(warprt.PointLight(position=tuple(light), intensity=(1.0, 0.9, 0.8)),), ambient=IA,
        render=warprt.RenderSettings(sampler="regular"))
    img = image(scene).reshape(-1, 3).astype(np.float64)
    o, d, h = pixel_hits(scene)
    floor = h["shape"] == 0
    p = h["position"][floor].astype(np.float64)
    l = unit(light - p)
    # distance from the sphere's centre to each shadow segment's line (the segment spans the
    # sphere whenever its line does: floor below, light above it)
    f = c - p
    perp = np.linalg.norm(f - np.sum(f * l, 1)[:, None] * l, axis=1)
    crossings = np.where(perp < r, 2, 0)
    clear = np.abs(perp - r) > 1e-4
    assert (crossings[clear] == 2).sum() > 30 and (crossings[clear] == 0).sum() > 100
    ndl = l[:, 1]
    ndh = unit(l - d[floor])[:, 1]
    I = np.array([1.0, 0.9, 0.8])
    expected = KA_FLOOR * IA + kt[None, :] ** crossings[:, None] * I * (KD_FLOOR * ndl + 0.3 * ndh ** 10)[:, None]
    np.testing.assert_allclose(img[floor][clear], expected[clear], rtol=1e-5, atol=1e-6)


KA_M, KM = 0.2, 0.9


def hall_scene(material, max_depth, min_weight=0.0, width=12):
    """The camera between two facing infinite mirrors z = ±1, looking obliquely at one: every
    camera ray bounces between them until the recursion stops."""
    return warprt.Scene(
        camera=warprt.Camera(eye=(0, 0, 0), look_at=(0.3, 0.2, -1.0), fov=40, width=width, height=width),
        shapes=(warprt.Plane(point=(0, 0, -1), normal=(0, 0, 1), material="m"),
                warprt.Plane(point=(0, 0, 1), normal=(0, 0, -1), material="m")),
        materials={"m": material}, ambient=1.0, background=tuple(B),
        render=warprt.RenderSettings(sampler="regular", max_depth=max_depth, min_weight=min_weight))


def test_naive_recursion_without_a_depth_limit_overflows_the_stack():
    """A textbook recursive Whitted trace between two facing perfect mirrors (km = 1) with no
    depth limit and no throughput cutoff never terminates: Python's stack overflows."""
    def trace(o, d):
        t = (np.sign(d[2]) - o[2]) / d[2]  # the mirror z = ±1 the ray flies towards
        p = o + t * d
        return KA_M + 1.0 * trace(p, d * np.array([1.0, 1.0, -1.0]))

    limit = sys.getrecursionlimit()
    sys.setrecursionlimit(500)
    try:
        with pytest.raises(RecursionError):
            trace(np.zeros(3), unit([0.3, 0.2, -1.0]))
    finally:
        sys.setrecursionlimit(limit)


@pytest.mark.parametrize("depth", [0, 1, 5, 15, 16, 64])
def test_hall_of_mirrors_is_the_truncated_geometric_series(depth):
    """Pure mirrors (ka = 0.2, km = 0.9, kd = 0), ambient 1: every pixel is
    ka·Σ_{k=0..D} km^k = ka·(1 − km^(D+1))/(1 − km), D + 1 rays per pixel, never a stack
    overflow (one child per hit). Tolerance (D + 1)·2^-23 relative: float32 products and sums."""
    result = render(hall_scene(warprt.Material(kd=0.0, ka=KA_M, mirror=KM), depth))
    expected = KA_M * (1.0 - KM ** (depth + 1)) / (1.0 - KM)
    np.testing.assert_allclose(result.image, expected, rtol=(depth + 1) * 2.0 ** -23)
    assert result.stack_overflows == 0
    assert result.rays == 12 * 12 * (depth + 1)


def two_child_expected(depth, km, kt, ka):
    """Mirror km that also transmits kt (refracted rays leave the hall and see B): the local terms
    of the hits along the reflection chain plus the escaping refracted rays. The stack holds k
    refracted rays at the depth-k hit, so the reflected ray of the depth-15 hit does not fit."""
    last_local = min(depth, 15)
    last_refr = depth - 1 if depth <= 15 else 15
    local = ka * sum(km ** k for k in range(last_local + 1))
    refr = kt * sum(km ** k for k in range(last_refr + 1))
    return local + refr * B, int(depth > 15)


@pytest.mark.parametrize("depth", [5, 15, 16, 40, 64])
def test_stack_overflow_is_counted_and_the_image_is_the_cut_series(depth):
    """Two children per hit (km = 0.9, kt = 0.1, no Fresnel). D ≤ 15: no overflow and the full
    series; D ≥ 16: exactly one dropped ray per pixel sample (the reflected ray of the depth-15
    hit), reported in stack_overflows, and the image is the series cut at depth 15, finite.
    Tolerance 32·2^-23 relative (float32 sums of up to 32 terms)."""
    kt, spp = 0.1, 2
    result = render(hall_scene(warprt.Material(kd=0.0, ka=KA_M, mirror=KM, transparency=kt), depth), spp=spp)
    expected, dropped = two_child_expected(depth, KM, kt, KA_M)
    assert np.isfinite(result.image).all()
    np.testing.assert_allclose(result.image, np.broadcast_to(expected, result.image.shape), rtol=32 * 2.0 ** -23)
    assert result.stack_overflows == dropped * 12 * 12 * spp
    if depth > 15:  # the series with the full depth would be larger: energy is lost, as documented
        full = KA_M * (1 - KM ** (depth + 1)) / (1 - KM) + kt * B * (1 - KM ** depth) / (1 - KM)
        assert (full - expected).min() > 1e-3


@pytest.mark.parametrize("min_weight, last", [(0.5 ** 10, 9), (0.5 ** 10 * 0.999, 10), (1.0, 0), (0.0, 64)],
                         ids=["at-2^-10", "below-2^-10", "one", "zero"])
def test_min_weight_stops_rays_whose_largest_throughput_is_not_above_it(min_weight, last):
    """Coloured mirrors km = (0.5, 0.25, 0.125), D = 64: the ray after k bounces has throughput
    (0.5^k, 0.25^k, 0.125^k), exact in float32; its largest component 0.5^k decides. It is
    traced iff 0.5^k > min_weight, so the pixel is ka·Σ_{k=0..last} km^k per channel."""
    km = np.array([0.5, 0.25, 0.125])
    result = render(hall_scene(warprt.Material(kd=0.0, ka=KA_M, mirror=tuple(km)), 64, min_weight=min_weight))
    expected = KA_M * (1.0 - km ** (last + 1)) / (1.0 - km)
    np.testing.assert_allclose(result.image, np.broadcast_to(expected, result.image.shape),
                               rtol=(last + 1) * 2.0 ** -23)
    assert result.rays == 12 * 12 * (last + 1)
