"""Rendered pixels against closed forms of the lecture's shading model, computed in numpy.

Every image is rendered with one sample per pixel and the "regular" sampler, so each pixel's
single camera ray passes through the pixel centre, exactly the ray ``warprt.camera_rays`` gives.
The references take those rays (the camera itself is checked in test_camera.py), intersect them
with the scene analytically in float64 and evaluate

    L = ka·Ia + Σ_i T_i · I_i · (kd·max(0, n·l) + ks·max(0, n·h)^p),   h = normalize(l + v)

plus the mirror / refraction / Fresnel weights. Pixels whose float64 reference lies within 1e-3
(relative) of a decision boundary (a sphere's silhouette, a shadow edge, the critical angle) are
left out of the comparisons, and the tests check that most pixels remain.

Tolerances (float32 kernels reach ~1e-6 here; each bound is loose enough for rounding and for
the documented 2^-17 spawn offset, tight enough to catch a wrong formula: a missing cosine, a
wrong falloff or half-vector, ka and kd swapped, a wrong index of refraction):
local shading 1e-4 relative + 1e-6 absolute (pixels near the terminator), 2e-4 with a Phong
exponent of 60; shadowed pixels exactly ka·Ia; mirror 5e-4 relative + 2e-5 (the reflected ray
starts 2^-17·|p| off the mirror); slab landing points 2e-3 scene units for shifts of 0.19-0.71;
total internal reflection 1e-6 absolute; Fresnel reflectances 1e-5 absolute.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

import warprt
from reference_formulas import fresnel_exact, fresnel_schlick

RTOL, ATOL = 1e-4, 1e-6
GLASS = warprt.Features(secondary=True, refraction=True)  # one kernel for every mirror/glass scene here
REGULAR = warprt.RenderSettings(sampler="regular", spp=1)


def unit(a):
    a = np.asarray(a, np.float64)
    return a / np.linalg.norm(a, axis=-1, keepdims=True)


def render(scene, features=None):
    r = warprt.Renderer(scene, device="cpu", features=features)
    out = r.render(spp=1, progress=False)
    assert out.stack_overflows == 0
    return out.image.astype(np.float64)


def rays(scene):
    o, d = warprt.camera_rays(scene)
    return o.astype(np.float64), d.astype(np.float64)


def sphere_hit(o, d, c, r):
    """Nearest positive root (inf for none) and the silhouette margin |disc|/r^2."""
    f = o - np.asarray(c, np.float64)
    b = np.sum(f * d, axis=1)
    perp = f - b[:, None] * d
    disc = r * r - np.sum(perp * perp, axis=1)
    sq = np.sqrt(np.maximum(disc, 0.0))
    t0, t1 = -b - sq, -b + sq
    t = np.where(t0 > 0, t0, np.where(t1 > 0, t1, np.inf))
    return np.where(disc >= 0, t, np.inf), np.abs(disc) / (r * r)


def plane_hit(o, d, p0, n):
    n = unit(n)
    denom = d @ n
    with np.errstate(divide="ignore", invalid="ignore"):
        t = ((np.asarray(p0, np.float64) - o) @ n) / denom
    return np.where((denom != 0) & (t > 0), t, np.inf)


def blinn_phong_ref(p, n, v, light_pos, intensity, kd, ks, p_exp, falloff="none"):
    """I (kd max(0, n.l) + ks max(0, n.h)^p) per point, (N, 3); no shadows."""
    to_l = np.asarray(light_pos, np.float64) - p
    dist = np.linalg.norm(to_l, axis=1, keepdims=True)
    l = to_l / dist
    ndotl = np.sum(n * l, axis=1, keepdims=True)
    h = unit(l + v)
    ndoth = np.maximum(np.sum(n * h, axis=1, keepdims=True), 0.0)
    f = np.asarray(kd) * np.maximum(ndotl, 0.0) + np.asarray(ks) * ndoth ** p_exp
    f = np.where(ndotl > 0, f, 0.0)
    intensity = np.asarray(intensity, np.float64)
    if falloff == "inverse_square":
        intensity = intensity / dist ** 2
    return intensity * f


def assert_close(img, ref, mask, rtol=RTOL, atol=ATOL):
    a, b = img.reshape(-1, 3)[mask], ref.reshape(-1, 3)[mask]
    err = np.abs(a - b) - (atol + rtol * np.abs(b))
    worst = np.unravel_index(np.argmax(err), err.shape)
    assert err.max() <= 0, f"pixel {worst}: got {a[worst[0]]}, expected {b[worst[0]]}"


# --- local shading ----------------------------------------------------------------------------


@pytest.mark.parametrize("falloff", ["none", "inverse_square"])
def test_diffuse_sphere_with_ambient_and_one_point_light(falloff):
    c, radius = np.array([0.2, -0.1, -0.3]), 1.0
    light, intensity = np.array([3.0, 4.0, 5.0]), np.array([0.9, 0.8, 0.7])
    if falloff == "inverse_square":
        intensity = intensity * 40.0
    kd, ka, ia, bg = np.array([0.7, 0.5, 0.3]), np.array([0.2, 0.3, 0.4]), np.array([0.1, 0.2, 0.3]), (0.05, 0.1, 0.15)
    scene = warprt.Scene(
        camera=warprt.Camera(eye=(0.5, 0.8, 4.0), look_at=(0, 0, 0), fov=40, width=40, height=32),
        shapes=(warprt.Sphere(center=tuple(c), radius=radius, material="m"),),
        materials={"m": warprt.Material(kd=tuple(kd), ka=tuple(ka))},
        lights=(warprt.PointLight(position=tuple(light), intensity=tuple(intensity), falloff=falloff),),
        ambient=tuple(ia), background=bg, render=REGULAR)
    img = render(scene)
    o, d = rays(scene)
    t, margin = sphere_hit(o, d, c, radius)
    hit = np.isfinite(t)
    p = o + np.where(hit, t, 0)[:, None] * d
    n = (p - c) / radius
    ref = np.where(hit[:, None], ka * ia + blinn_phong_ref(p, n, -d, light, intensity, kd, 0.0, 1.0, falloff),
                   np.asarray(bg))
    clear = margin > 1e-3
    assert 250 < (hit & clear).sum() and clear.mean() > 0.95
    lit = hit & (np.sum(n * unit(light - p), axis=1) > 0.05)
    assert lit.sum() > 150  # the Lambert term is really exercised
    assert_close(img, ref, clear)
    # a wrong falloff would not pass: the two falloffs differ by far more than the tolerance here
    other = blinn_phong_ref(p, n, -d, light, intensity, kd, 0.0, 1.0,
                            "none" if falloff == "inverse_square" else "inverse_square")
    assert np.abs(other - blinn_phong_ref(p, n, -d, light, intensity, kd, 0.0, 1.0, falloff))[lit].max() > 0.05


def test_blinn_phong_highlight_position_and_value():
    c, radius = np.array([0.0, 0.0, 0.0]), 1.0
    light, intensity = np.array([-2.0, 3.0, 4.0]), np.array([1.0, 0.9, 0.8])
    ks, p_exp = np.array([0.6, 0.7, 0.8]), 60.0
    scene = warprt.Scene(
        camera=warprt.Camera(eye=(0.3, 0.2, 4.0), look_at=(0, 0, 0), fov=35, width=48, height=40),
        shapes=(warprt.Sphere(center=tuple(c), radius=radius, material="shiny"),),
        materials={"shiny": warprt.Material(kd=0.0, ks=tuple(ks), p=p_exp)},
        lights=(warprt.PointLight(position=tuple(light), intensity=tuple(intensity)),), render=REGULAR)
    img = render(scene)
    o, d = rays(scene)
    t, margin = sphere_hit(o, d, c, radius)
    hit = np.isfinite(t)
    p = o + np.where(hit, t, 0)[:, None] * d
    n = (p - c) / radius
    ref = np.where(hit[:, None], blinn_phong_ref(p, n, -d, light, intensity, 0.0, ks, p_exp), 0.0)
    clear = margin > 1e-3
    assert_close(img, ref, clear, rtol=2e-4)  # n.h^60 amplifies float32 rounding of n.h sixtyfold
    # the brightest pixel is the one where n.h is largest
    l = unit(light - p)
    ndoth = np.where(hit & (np.sum(n * l, axis=1) > 0), np.sum(n * unit(l - d), axis=1), -1.0)
    best = int(np.argmax(ndoth))
    assert int(np.argmax(img.reshape(-1, 3)[:, 0])) == best
    j, i = divmod(best, 48)
    assert 2 < i < 45 and 2 < j < 37, "the highlight should be well inside the image"
    np.testing.assert_allclose(img[j, i], intensity * ks * ndoth[best] ** p_exp, rtol=2e-4)
    assert img[j, i, 0] > 10 * np.median(img[..., 0][img[..., 0] > 0])  # a real highlight


def floor_and_ball(scene, c, radius):
    """The camera rays of a floor (y = 0) and ball scene: (o, d, ball t, ball silhouette margin,
    floor t, the pixels that clearly see the floor, their floor points), float64."""
    o, d = rays(scene)
    t_ball, m_ball = sphere_hit(o, d, c, radius)
    t_floor = plane_hit(o, d, (0, 0, 0), (0, 1, 0))
    floor = np.isfinite(t_floor) & (t_floor < t_ball) & (m_ball > 1e-3)
    return o, d, t_ball, m_ball, t_floor, floor, o + np.where(floor, t_floor, 0)[:, None] * d


def test_shadow_of_an_opaque_sphere_is_exactly_ambient():
    ka, ia = np.float32(0.5), np.float32(0.2)
    kd_floor, kd_ball = np.array([0.6, 0.6, 0.6]), np.array([0.3, 0.5, 0.7])
    c, radius = np.array([0.0, 1.0, 0.0]), 0.5
    light, intensity = np.array([0.3, 3.0, 0.2]), np.array([1.0, 1.0, 1.0])
    scene = warprt.Scene(
        camera=warprt.Camera(eye=(0.0, 4.0, 4.0), look_at=(0, 0, 0), fov=45, width=40, height=40),
        shapes=(warprt.Plane(point=(0, 0, 0), normal=(0, 1, 0), material="floor"),
                warprt.Sphere(center=tuple(c), radius=radius, material="ball")),
        materials={"floor": warprt.Material(kd=tuple(kd_floor), ka=float(ka)),
                   "ball": warprt.Material(kd=tuple(kd_ball))},
        lights=(warprt.PointLight(position=tuple(light), intensity=tuple(intensity)),),
        ambient=float(ia), render=REGULAR)
    img = render(scene).reshape(-1, 3)
    o, d, t_ball, m_ball, t_floor, floor, p = floor_and_ball(scene, c, radius)
    # shadow rays from the floor to the light, against the sphere (float64)
    to_l = light - p
    dist = np.linalg.norm(to_l, axis=1)
    t_sh, m_sh = sphere_hit(p, to_l / dist[:, None], c, radius)
    shadowed = floor & (t_sh < dist) & (m_sh > 1e-3)
    lit = floor & ~np.isfinite(t_sh) & (m_sh > 1e-3)
    assert shadowed.sum() > 30 and lit.sum() > 500
    # exactly ka * Ia in float32, in every channel
    assert np.all(img[shadowed] == np.float32(ka * ia)), np.unique(img[shadowed])
    ref = ka * ia + blinn_phong_ref(p, np.array([0.0, 1.0, 0.0]), -d, light, intensity, kd_floor, 0.0, 1.0)
    assert_close(img.reshape(40, 40, 3), ref, lit)
    # the ball itself: lit and unlit sides follow the closed form (nothing shadows it)
    ball = np.isfinite(t_ball) & (t_ball < t_floor) & (m_ball > 1e-3)
    pb = o + np.where(ball, t_ball, 0)[:, None] * d
    ref_b = kd_ball * ia + blinn_phong_ref(  # ka defaults to kd
        pb, (pb - c) / radius, -d, light, intensity, kd_ball, 0.0, 1.0)
    assert_close(img.reshape(40, 40, 3), ref_b, ball)


def test_directional_light_shades_and_shadows_with_the_closed_form():
    """A directional light: l = -direction everywhere, no falloff, shadow rays to infinity (a
    sphere far above the light's reach of a point light still shadows)."""
    ka, ia = np.float32(0.5), np.float32(0.2)
    kd_floor, kd_ball, ks_ball, p_ball = np.array([0.6, 0.5, 0.4]), np.array([0.3, 0.5, 0.7]), 0.4, 20.0
    c, radius = np.array([0.0, 1.0, 0.0]), 0.5
    direction, intensity = unit([0.4, -1.0, -0.3]), np.array([0.9, 1.0, 1.1])
    scene = warprt.Scene(
        camera=warprt.Camera(eye=(0.0, 4.0, 4.0), look_at=(0, 0, 0), fov=45, width=40, height=40),
        shapes=(warprt.Plane(point=(0, 0, 0), normal=(0, 1, 0), material="floor"),
                warprt.Sphere(center=tuple(c), radius=radius, material="ball")),
        materials={"floor": warprt.Material(kd=tuple(kd_floor), ka=float(ka)),
                   "ball": warprt.Material(kd=tuple(kd_ball), ks=ks_ball, p=p_ball)},
        lights=(warprt.DirectionalLight(direction=tuple(3.0 * direction), intensity=tuple(intensity)),),
        ambient=float(ia), render=REGULAR)
    img = render(scene).reshape(-1, 3)
    o, d, t_ball, m_ball, t_floor, floor, p = floor_and_ball(scene, c, radius)
    l = -direction
    t_sh, m_sh = sphere_hit(p, np.broadcast_to(l, p.shape), c, radius)
    shadowed = floor & np.isfinite(t_sh) & (m_sh > 1e-3)
    lit = floor & ~np.isfinite(t_sh) & (m_sh > 1e-3)
    assert shadowed.sum() > 30 and lit.sum() > 500
    assert np.all(img[shadowed] == np.float32(ka * ia)), np.unique(img[shadowed])
    ref = ka * ia + np.asarray(intensity) * kd_floor * max(l[1], 0.0)
    assert_close(img.reshape(40, 40, 3), np.broadcast_to(ref, (1600, 3)).reshape(40, 40, 3), lit)
    ball = np.isfinite(t_ball) & (t_ball < t_floor) & (m_ball > 1e-3)
    pb = o + np.where(ball, t_ball, 0)[:, None] * d
    ref_b = kd_ball * ia + blinn_phong_ref(pb, (pb - c) / radius, -d, pb + 1e6 * l, intensity, kd_ball, ks_ball,
                                           p_ball)
    assert_close(img.reshape(40, 40, 3), ref_b, ball, rtol=2e-4)


def lit_plane(scale, shift):
    """A plane lit at a grazing angle, scaled and moved: (image, closed form, ka Ia), per pixel.
    With falloff "none" the radiance does not depend on the scene's scale or position."""
    kd, ka, ia, intensity = 0.8, 0.1, 0.1, np.full(3, 0.9)

    def pt(x):
        return tuple(float(np.float32(c * scale + shift)) for c in x)

    eye, look, light, p0 = pt((0, 2, 2)), pt((0, 0, -1)), pt((2.5, 0.75, -2.0)), pt((0, 0, 0))
    scene = warprt.Scene(
        camera=warprt.Camera(eye=eye, look_at=look, fov=40, width=32, height=24),
        shapes=(warprt.Plane(point=p0, normal=(0, 1, 0), material="floor"),),
        materials={"floor": warprt.Material(kd=kd, ka=ka)},
        lights=(warprt.PointLight(position=light, intensity=tuple(intensity)),), ambient=ia, render=REGULAR)
    img = render(scene)
    o, d = rays(scene)
    t = plane_hit(o, d, p0, (0, 1, 0))
    assert np.isfinite(t).all()  # the camera sees the plane in every pixel
    p = o + t[:, None] * d
    p[:, 1] = p0[1]
    ref = ka * ia + blinn_phong_ref(p, np.array([0.0, 1.0, 0.0]), -d, light, intensity, kd, 0.0, 1.0)
    assert ref.min() > ka * ia + 0.05  # the light reaches every point the camera sees
    return img, ref, ka * ia


SCALES = [(1.0, 0.0), (1e-3, 0.0), (1e4, 0.0), (1.0, 1e4)]


@pytest.mark.parametrize("scale, shift", SCALES)
def test_lit_plane_has_no_acne_at_any_scale(scale, shift):
    """Every pixel that sees the lit plane is lit: no shadow ray hits the plane it starts on."""
    img, ref, ambient = lit_plane(scale, shift)
    flat = img.reshape(-1, 3)
    assert np.all(flat > ambient + 0.5 * (ref - ambient)), "shadow acne: some plane pixels are not lit"


@pytest.mark.parametrize("scale, shift", SCALES)
def test_lit_plane_equals_the_closed_form_at_any_scale(scale, shift):
    img, ref, _ = lit_plane(scale, shift)
    # float32 positions far from the origin carry ~|p| 6e-8 of error; the light is 0.75 scale above
    rtol = RTOL + 4 * (abs(shift) * 6e-8) / (0.75 * scale)
    assert_close(img, ref, np.ones(len(ref), bool), rtol=rtol)


# --- mirror -----------------------------------------------------------------------------------


def test_mirror_plane_shows_the_view_from_the_mirrored_camera():
    """A perfect mirror (km = 1, kd = 0) on y = 0: each pixel that sees the mirror equals the pixel
    of the camera reflected in y = 0 (eye, look_at and up mirrored), looking at the scene without
    the mirror. Reflection swaps handedness, so the mirrored camera's image is flipped left-right."""
    W, H = 40, 30
    ball_c, ball_r = np.array([0.3, 0.8, -0.5]), 0.6
    objects = (warprt.Sphere(center=tuple(ball_c), radius=ball_r, material="ball"),
               warprt.Sphere(center=(-1.2, 0.5, 0.4), radius=0.4, material="ball2"))
    common = dict(materials={"ball": warprt.Material(kd=(0.8, 0.3, 0.2), ks=0.3, p=20),
                             "ball2": warprt.Material(kd=(0.1, 0.6, 0.3)),
                             "mirror": warprt.Material(kd=0.0, mirror=1.0)},
                  lights=(warprt.PointLight(position=(2, 4, 3), intensity=1.0),),
                  ambient=0.05, background=(0.1, 0.2, 0.4), render=REGULAR)
    cam = warprt.Camera(eye=(0.5, 2.5, 4.0), look_at=(0, 0, 0), up=(0, 1, 0), fov=50, width=W, height=H)
    mirrored = warprt.Camera(eye=(0.5, -2.5, 4.0), look_at=(0, 0, 0), up=(0, -1, 0), fov=50, width=W, height=H)
    scene = warprt.Scene(camera=cam, shapes=(warprt.Plane(material="mirror"),) + objects, **common)
    virtual = warprt.Scene(camera=mirrored, shapes=objects, **common)
    img = render(scene, GLASS)
    ref = render(virtual)[:, ::-1]
    o, d = rays(scene)
    sees_mirror = warprt.trace_rays(scene, o, d)["shape"] == 0
    # leave out pixels whose mirrored ray grazes a sphere's silhouette
    ov, dv = rays(virtual)
    clear = np.ones(W * H, bool)
    for s in objects:
        _, m = sphere_hit(ov, dv, s.center, s.radius)
        clear &= m > 1e-3
    clear = clear.reshape(H, W)[:, ::-1].reshape(-1)
    mask = sees_mirror & clear
    assert mask.sum() > 0.5 * W * H
    # the reflection shows both balls and the background
    vals = ref.reshape(-1, 3)[mask]
    assert (np.abs(vals - (0.1, 0.2, 0.4)).max(axis=1) < 1e-6).sum() > 20
    assert (np.abs(vals - (0.1, 0.2, 0.4)).max(axis=1) > 1e-2).sum() > 40
    # the reflected ray starts 2^-17 |p| (~1.5e-5) off the mirror, so it meets a ball ~1e-5 away
    # from where the mirrored camera's ray does: up to ~1e-4 relative near a ball's terminator
    assert_close(img, ref, mask, rtol=5e-4, atol=2e-5)
    # and it is not the unflipped image (the test can tell left from right)
    assert np.abs(img.reshape(-1, 3)[mask] - render(virtual).reshape(-1, 3)[mask]).max() > 0.1


# --- refraction -------------------------------------------------------------------------------


def test_glass_slab_shifts_rays_by_the_closed_form_lateral_offset():
    """Camera rays in the xz plane cross a glass slab (ior 1.5, thickness 1, faces z = 0 and
    z = -1, kt = 1) and land on a diffuse target plane z = -3 lit by a point light 1 above it.
    The target's radiance h / sqrt(rho^2 + h^2) encodes where each ray lands; decoding it gives the
    landing point, which must be the straight ray's, shifted by the lateral offset
    Δ = d sin(θ - θt) / cos θt perpendicular to the ray (exit parallel to entry)."""
    W, thick, ior, h = 24, 1.0, 1.5, 1.0
    theta_c = math.radians(40.0)
    eye = np.array([0.0, 0.0, 2.0])
    look = eye + np.array([math.sin(theta_c), 0.0, -math.cos(theta_c)])
    half = math.radians(14.0)
    fov = 2 * math.degrees(math.atan(math.tan(half) / W))  # horizontal half-angle 14 degrees, one row
    light = np.array([1.0, 0.0, -3.0 + h])
    scene = warprt.Scene(
        camera=warprt.Camera(eye=tuple(eye), look_at=tuple(look), fov=fov, width=W, height=1),
        shapes=(warprt.Rectangle(corner=(-1, -2, 0), edge1=(8, 0, 0), edge2=(0, 4, 0), material="glass"),
                warprt.Rectangle(corner=(-1, -2, -thick), edge1=(0, 4, 0), edge2=(8, 0, 0), material="glass"),
                warprt.Plane(point=(0, 0, -3), normal=(0, 0, 1), material="target")),
        materials={"glass": warprt.Material(kd=0.0, transparency=1.0, ior=ior),
                   "target": warprt.Material(kd=1.0, ka=0.0)},
        lights=(warprt.PointLight(position=tuple(light), intensity=1.0),), render=REGULAR)
    img = render(scene, GLASS)[0, :, 0]
    _, d = rays(scene)
    assert np.abs(d[:, 1]).max() < 1e-6  # every ray in the xz plane
    theta = np.arctan2(d[:, 0], -d[:, 2])
    assert math.radians(25) < theta.min() and theta.max() < math.radians(55)
    theta_t = np.arcsin(np.sin(theta) / ior)
    delta = thick * np.sin(theta - theta_t) / np.cos(theta_t)
    x_straight = eye[0] + 5.0 * np.tan(theta)  # the unrefracted ray at z = -3
    x_expected = x_straight - delta / np.cos(theta)  # shifted by Δ perpendicular to the ray
    # decode the landing point from the radiance (x > light x everywhere)
    x_measured = light[0] + h * np.sqrt(1.0 / img ** 2 - 1.0)
    assert np.all(x_expected > light[0] + 0.5)
    np.testing.assert_allclose(x_measured, x_expected, atol=2e-3)
    assert np.all(np.abs(x_straight - x_expected) > 0.15)  # the shift is 75x the tolerance
    delta_measured = (x_straight - x_measured) * np.cos(theta)
    np.testing.assert_allclose(delta_measured, delta, atol=2e-3)


def glass_half_space(camera, glass, floor_colour, background, **kw):
    """Glass below y = 0 (outward normal +y); an ambient-only floor at y = -10 that shows
    ``floor_colour`` exactly; ``background`` above."""
    return warprt.Scene(
        camera=camera,
        shapes=(warprt.Plane(point=(0, 0, 0), normal=(0, 1, 0), material="glass"),
                warprt.Plane(point=(0, -10, 0), normal=(0, 1, 0), material="floor")),
        materials={"glass": glass, "floor": warprt.Material(kd=0.0, ka=floor_colour)},
        ambient=1.0, background=background, render=REGULAR, **kw)


def fan_camera(eye, centre_deg, half_deg, width, down):
    """A one-row camera at ``eye`` whose pixel rays fan out in the xy plane around the direction
    at ``centre_deg`` from the vertical (down: from -y, else from +y)."""
    a = math.radians(centre_deg)
    direction = np.array([math.sin(a), -math.cos(a) if down else math.cos(a), 0.0])
    fov = 2 * math.degrees(math.atan(math.tan(math.radians(half_deg)) / width))
    return warprt.Camera(eye=eye, look_at=tuple(np.asarray(eye) + direction), up=(0, 0, 1), fov=fov,
                         width=width, height=1)


def test_total_internal_reflection_beyond_the_critical_angle():
    """Seen from inside glass (ior 1.5, kt = 0.7, km = 0.2, no Fresnel): beyond the critical angle
    asin(1/1.5) the pixel is the reflected colour times kt + km; below it, km of the reflection
    plus kt of the background seen through the surface."""
    kt, km, ior = 0.7, 0.2, 1.5
    floor_c, bg = np.array([0.0, 0.8, 0.0]), np.array([0.5, 0.0, 0.0])
    cam = fan_camera((0, -1, 0), 42.0, 20.0, 40, down=False)
    scene = glass_half_space(cam, warprt.Material(kd=0.0, transparency=kt, mirror=km, ior=ior),
                             tuple(floor_c), tuple(bg))
    img = render(scene, GLASS)[0]
    _, d = rays(scene)
    theta = np.degrees(np.arccos(d[:, 1]))
    crit = math.degrees(math.asin(1 / ior))
    tir = theta > crit + 0.05
    below = theta < crit - 0.05
    assert tir.sum() > 10 and below.sum() > 10
    np.testing.assert_allclose(img[tir], np.broadcast_to((kt + km) * floor_c, (tir.sum(), 3)), atol=1e-6)
    np.testing.assert_allclose(img[below], np.broadcast_to(km * floor_c + kt * bg, (below.sum(), 3)), atol=1e-6)


@pytest.mark.parametrize("mode", ["exact", "schlick"])
@pytest.mark.parametrize("side", ["outside", "inside"])
def test_fresnel_split_matches_the_formula(mode, side):
    """kt = 1, km = 0, Fresnel on: a pixel is F times what the reflected ray sees plus 1 - F times
    what the refracted ray sees. Red (background, above the surface) and green (the floor, below
    it) separate the two, so each pixel reads F directly."""
    ior = 1.5
    red, green = np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0])
    if side == "outside":
        cam = fan_camera((0, 1, 0), 45.0, 44.0, 48, down=True)
    else:
        cam = fan_camera((0, -1, 0), 30.0, 29.0, 48, down=False)
    glass = warprt.Material(kd=0.0, transparency=1.0, ior=ior, fresnel=mode)
    scene = glass_half_space(cam, glass, tuple(green), tuple(red))
    img = render(scene, GLASS)[0]
    _, d = rays(scene)
    cos_i = np.abs(d[:, 1])
    ref_fn = fresnel_exact if mode == "exact" else fresnel_schlick
    if side == "outside":
        F = ref_fn(cos_i, 1.0, ior)
        reflected, refracted = img[:, 0], img[:, 1]  # reflection sees the sky, refraction the floor
        keep = np.ones_like(F, bool)
    else:
        F = ref_fn(cos_i, ior, 1.0)
        reflected, refracted = img[:, 1], img[:, 0]
        crit = math.asin(1 / ior)
        keep = np.abs(np.arccos(cos_i) - crit) > math.radians(0.2)  # F is not smooth at the critical angle
        assert (F[keep] == 1.0).sum() > 5 and (F[keep] < 0.5).sum() > 10
    assert F.max() - F.min() > 0.3  # a wide range of angles
    np.testing.assert_allclose(reflected[keep], F[keep], atol=1e-5)
    np.testing.assert_allclose(refracted[keep], 1.0 - F[keep], atol=1e-5)
    np.testing.assert_allclose(img[:, 2], 0.0, atol=0)
    if mode == "exact":
        # the formulas differ by much more than the tolerance: the test tells them apart
        other = fresnel_schlick(cos_i, *((1.0, ior) if side == "outside" else (ior, 1.0)))
        assert np.abs(other - F)[keep].max() > 1e-3
