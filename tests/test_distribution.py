"""Distribution ray tracing checked against closed forms.

Every render here uses the all-features kernel (``Features.full()``), so the module compiles one
kernel variant however many scenes it renders; specialised variants are compared with it in
tests/test_features.py.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

import warprt
from warprt import Features
from warprt.query import camera_rays

FULL = Features.full()


def render(scene, spp, seed=0, **kw):
    """Uniform sampling unless a test asks for adaptive: the closed forms and convergence rates
    here hold for every pixel at ``spp`` samples of its scene's sampler."""
    kw.setdefault("adaptive", False)
    return warprt.Renderer(scene, device="cpu", features=FULL).render(spp=spp, seed=seed, progress=False, **kw)


def polygon_irradiance(p: np.ndarray, n: np.ndarray, verts: list[np.ndarray], radiance: float) -> float:
    """Irradiance at p (normal n) from a uniform polygonal emitter fully above p's horizon:
    Lambert's formula E = Le/2 Σ θ_i n·(a_i × a_{i+1})/|a_i × a_{i+1}| (the form factor of a polygon)."""
    total = 0.0
    for i in range(len(verts)):
        a = verts[i] - p
        b = verts[(i + 1) % len(verts)] - p
        a, b = a / np.linalg.norm(a), b / np.linalg.norm(b)
        c = np.cross(a, b)
        total += math.acos(float(np.clip(np.dot(a, b), -1.0, 1.0))) * float(np.dot(n, c / np.linalg.norm(c)))
    return abs(total) * radiance / 2.0


def footprint_points(i: int, j: int, k: int = 6) -> np.ndarray:
    g = (np.arange(k) + 0.5) / k
    return np.array([[i + a, j + b] for a in g for b in g])


# --- area lights ------------------------------------------------------------------------------


@pytest.mark.parametrize("height, half, light_sampling, adaptive", [
    (2.0, 1.5, "uniform", False), (12.0, 0.6, "uniform", False), (2.0, 1.5, "cosine", False),
    (12.0, 0.6, "cosine", False), (2.0, 1.5, "cosine", True)],
    ids=["uniform, near: solid angle", "uniform, far: area", "cosine, near: area", "cosine, far: area",
         "cosine, near, adaptive sampling"])
def test_rectangle_light_irradiance_matches_polygon_formula_and_is_unbiased(height, half, light_sampling, adaptive):
    """Uniform draws: near the light (its size at least shapes.SPHRECT_NEAR times its distance)
    uniform in its solid angle, farther by area. Cosine draws (the default): by area with the
    warp, by solid angle with it from SPHRECT_NEAR_COSINE on (tests/test_cosine_lights.py checks
    that regime at the device level). All against the closed form; the cosine cases take two
    light samples per camera sample (half the spp), so that their average is checked too. With
    adaptive sampling each pixel's count comes from an independent pilot, so the image stays
    unbiased whatever the counts."""
    from warprt.shapes import SPHRECT_NEAR, SPHRECT_NEAR_COSINE

    corner, e1, e2 = np.array([0.3 - half, height, -0.6]), np.array([2 * half, 0.0, 0.0]), np.array([0.0, 0.0, 1.2])
    size = np.linalg.norm(e1) + np.linalg.norm(e2)
    # one regime for every visible ground point (from under the light to 2.5 from its foot)
    near_at = SPHRECT_NEAR if light_sampling == "uniform" else SPHRECT_NEAR_COSINE
    solid = [size >= near_at * math.hypot(height, r) for r in (0.0, 2.5)]
    assert solid[0] == solid[1] == (height < 5 and light_sampling == "uniform")
    le, kd = 3.0, 0.7
    w = h = 10
    scene = warprt.Scene(
        camera=warprt.Camera(eye=(0.3, 1.5, 2.5), look_at=(0.3, 0.0, 0.0), fov=50, width=w, height=h),
        shapes=(warprt.Plane(material="white"),), materials={"white": warprt.Material(kd=kd, ka=0.0)},
        lights=(warprt.RectLight(corner=tuple(corner), edge1=tuple(e1), edge2=tuple(e2), radiance=le,
                                 samples=1 if light_sampling == "uniform" else 2),),
        render=warprt.RenderSettings(sampler="independent", light_sampling=light_sampling))
    verts = [corner, corner + e1, corner + e1 + e2, corner + e2]
    expected = np.zeros((h, w))
    for j in range(h):
        for i in range(w):
            # the pixel integral by a 16 x 16 midpoint rule: its error must stay well below the
            # Monte Carlo error of the low-variance (solid-angle) estimate
            o, d = camera_rays(scene, footprint_points(i, j, 16))
            hit = o + (-o[:, 1] / d[:, 1])[:, None] * d
            expected[j, i] = np.mean([kd / math.pi * polygon_irradiance(q, np.array([0.0, 1.0, 0.0]), verts, le)
                                      for q in hit])
    runs = np.stack([render(scene, 256 // scene.lights[0].samples, seed=s, adaptive=adaptive).image[..., 0]
                     for s in range(16)])
    mean = runs.mean(axis=0)
    se = runs.std(axis=0, ddof=1) / math.sqrt(len(runs))
    z = (mean - expected) / np.maximum(se, 1e-12)
    # unbiased: the image-wide mean within 3 standard errors, and no pixel beyond 6: with se
    # estimated from 16 runs z follows Student's t with 15 degrees of freedom, P(|t| > 6) =
    # 2.4e-5 a pixel, 2.4e-3 over the 100 (6 runs and a bound of 5 gave 0.4% a pixel, 34% overall)
    total_se = math.sqrt(float((se ** 2).sum())) / se.size
    assert abs(float((mean - expected).mean())) < 3.0 * total_se
    assert np.abs(z).max() < 6.0
    # and accurate at this sample count: 16 x 256 light samples per pixel
    assert np.abs(mean / expected - 1.0).mean() < 0.01


def test_shrinking_sphere_light_converges_to_inverse_square_point_light():
    intensity = 2.0
    base = dict(camera=warprt.Camera(eye=(0, 1.0, 3.0), look_at=(0, 0, 0), width=12, height=10),
                shapes=(warprt.Plane(material="m"), warprt.Sphere(center=(0.4, 0.3, 0.2), radius=0.3, material="m")),
                materials={"m": warprt.Material(kd=0.6, ks=0.3, p=20, ka=0.0)})
    point = render(warprt.Scene(lights=(warprt.PointLight(position=(0.5, 2.0, 1.0), intensity=intensity,
                                                          falloff="inverse_square"),), **base), 4).image
    errors = []
    for radius in (0.1, 0.01, 0.001):
        light = warprt.SphereLight(center=(0.5, 2.0, 1.0), radius=radius, radiance=intensity / radius ** 2)
        img = render(warprt.Scene(lights=(light,), **base), 4).image
        mask = point > 1e-3
        errors.append(float(np.abs(img[mask] / point[mask] - 1.0).max()))
    assert errors[0] > errors[1] > errors[2] or errors[2] < 1e-4
    assert errors[2] < 2e-3, errors


def test_area_light_is_visible_to_camera_rays_with_its_radiance():
    scene = warprt.Scene(camera=warprt.Camera(eye=(0, 0, 3), look_at=(0, 0, 0), width=8, height=8, fov=20),
                         lights=(warprt.RectLight(corner=(-1, -1, 0), edge1=(2, 0, 0), edge2=(0, 2, 0),
                                                  radiance=(0.5, 1.5, 2.5)),))
    img = render(scene, 1).image
    np.testing.assert_array_equal(img, np.broadcast_to(np.float32([0.5, 1.5, 2.5]), img.shape))
    # seen from behind, a one-sided emitter is black
    back = render(scene.with_camera(eye=(0, 0, -3)), 1).image
    assert back.max() == 0.0


# --- antialiasing: a half-plane edge across pixels ---------------------------------------------


def _edge_scene(w: int, sampler: str) -> tuple[warprt.Scene, np.ndarray]:
    """A white emitter filling the half plane below a slanted line, seen head-on; the exact pixel
    value is the area fraction of the pixel under the line (computed in raster coordinates)."""
    slope, offset = 0.37, 0.5
    fov = 40.0
    half = math.tan(math.radians(fov) / 2)  # image-plane half size at D = 1, camera at z = 1
    # raster (x, y) -> world (X, Y) on the plane z = 0: X = (2x/w - 1) half, Y = (1 - 2y/w) half
    # the edge Y = slope X + c in world is a line in raster space; build the emitter polygon
    c = offset * half * 0.2
    big = 10.0
    corner = (-big, -big, 0.0)
    # emitter: parallelogram below the line Y = slope X + c, spanning X in [-big, big]
    e1 = (2 * big, 2 * big * slope, 0.0)
    e2 = (0.0, (slope * -big + c) + big, 0.0)
    light = warprt.RectLight(corner=corner, edge1=e1, edge2=e2, radiance=1.0)
    scene = warprt.Scene(camera=warprt.Camera(eye=(0, 0, 1), look_at=(0, 0, 0), fov=fov, width=w, height=w),
                         lights=(light,), render=warprt.RenderSettings(sampler=sampler))
    # exact coverage: integrate the indicator over each pixel analytically in x (fine grid in y)
    k = 400
    ys = (np.arange(k) + 0.5) / k
    exact = np.zeros((w, w))
    for j in range(w):
        Y = (1 - 2 * (j + ys) / w) * half  # world Y of sub-rows
        X_edge = (Y - c) / slope  # points with X > X_edge are under the line (slope > 0)
        x_edge = (X_edge / half + 1) * w / 2  # raster x of the edge on each sub-row
        for i in range(w):
            exact[j, i] = np.clip(i + 1 - x_edge, 0.0, 1.0).mean()
    return scene, exact


def test_half_plane_edge_coverage_equals_area_fraction():
    scene, exact = _edge_scene(16, "stratified")
    img = render(scene, 256).image[..., 0]
    edge = (exact > 0) & (exact < 1)
    assert edge.sum() >= 16
    np.testing.assert_array_equal(img[exact == 0], 0.0)
    np.testing.assert_array_equal(img[exact == 1], 1.0)
    assert np.abs(img[edge] - exact[edge]).max() < 0.03
    assert abs(float((img[edge] - exact[edge]).mean())) < 0.005


def _fit_slope(spps, errors) -> float:
    return float(np.polyfit(np.log(spps), np.log(errors), 1)[0])


def _edge_errors(sampler: str, spps, seeds=4) -> list[float]:
    scene, exact = _edge_scene(12, sampler)
    edge = (exact > 0) & (exact < 1)
    out = []
    for spp in spps:
        sq = [float(np.mean((render(scene, spp, seed=s).image[..., 0][edge] - exact[edge]) ** 2)) for s in range(seeds)]
        out.append(math.sqrt(np.mean(sq)))
    return out


def test_convergence_rates_on_an_edge():
    spps = [4, 16, 64, 256]
    independent = _fit_slope(spps, _edge_errors("independent", spps))
    stratified = _fit_slope(spps, _edge_errors("stratified", spps))
    sobol = _fit_slope(spps, _edge_errors("sobol", spps))
    assert -0.65 < independent < -0.35, independent
    assert stratified < -0.65, stratified
    assert sobol < -0.65, sobol
    assert stratified < independent - 0.15 and sobol < independent - 0.15


def _soft_shadow_scene(sampler: str, w: int = 10) -> warprt.Scene:
    """A square occluder between a square light and the floor, viewed close up on the corner of
    its penumbra (each pixel spans about 5% of the penumbra width)."""
    return warprt.Scene(
        camera=warprt.Camera(eye=(0, 2.0, 2.0), look_at=(0.6, 0, 0.6), fov=9, width=w, height=w),
        shapes=(warprt.Plane(material="m"), warprt.Rectangle(corner=(-0.4, 0.8, -0.4), edge1=(0, 0, 0.8),
                                                           edge2=(0.8, 0, 0), material="m")),
        materials={"m": warprt.Material(kd=0.8, ka=0.0)},
        lights=(warprt.RectLight(corner=(-0.6, 2.0, -0.6), edge1=(1.2, 0, 0), edge2=(0, 0, 1.2), radiance=2.0,
                                 samples=1),),  # (one shadow ray per camera sample: the rates are the sampler's)
        render=warprt.RenderSettings(sampler=sampler))


def test_convergence_rates_on_soft_shadows():
    """Stratifying the light samples pays where the light dimensions carry the variance. (The
    film x light cross term is not stratified by padding and converges at the Monte Carlo rate;
    with pixels as wide as the penumbra the slopes flatten towards -0.6, see docs/effects/soft-shadows.md.)"""
    reference = render(_soft_shadow_scene("sobol"), 16384).image
    spps = [4, 16, 64, 256]
    slopes = {}
    for sampler in ("independent", "stratified", "sobol"):
        scene = _soft_shadow_scene(sampler)
        errs = []
        for spp in spps:
            mse = [float(np.mean((render(scene, spp, seed=s).image - reference) ** 2)) for s in range(6)]
            errs.append(math.sqrt(np.mean(mse)))
        slopes[sampler] = _fit_slope(spps, errs)
    assert -0.6 < slopes["independent"] < -0.4, slopes
    assert slopes["stratified"] < -0.65, slopes
    assert slopes["sobol"] < -0.65, slopes


# --- depth of field -----------------------------------------------------------------------------


def test_depth_of_field_circle_of_confusion():
    """A tiny emitter off the focal plane spreads into a uniform disk of radius
    R = A D |z - f| / (z f) on the image plane, i.e. A H |z - f| / (2 z f tan(fov/2)) pixels."""
    aperture, focus, z, fov, size = 0.2, 2.0, 4.0, 20.0, 48
    radius = 0.02
    light = warprt.SphereLight(center=(0.0, 0.0, -z), radius=radius, radiance=100.0)
    cam = warprt.Camera(eye=(0, 0, 0), look_at=(0, 0, -1), fov=fov, width=size, height=size, aperture=aperture,
                        focus_distance=focus)
    scene = warprt.Scene(camera=cam, lights=(light,), render=warprt.RenderSettings(sampler="sobol"))
    img = render(scene, 1024).image[..., 0]
    expected_r = aperture * size * abs(z - focus) / (2 * z * focus * math.tan(math.radians(fov) / 2))
    ys, xs = np.mgrid[0:size, 0:size] + 0.5
    wsum = img.sum()
    cx, cy = (img * xs).sum() / wsum, (img * ys).sum() / wsum
    r2 = (img * ((xs - cx) ** 2 + (ys - cy) ** 2)).sum() / wsum
    # E[r^2] of the image = R^2/2 (uniform blur disk) + s^2/2 (the emitter's own disk, radius s
    # pixels when in focus) + 1/6 (the box filter of a pixel, 1/12 per axis)
    pixel = 2 * math.tan(math.radians(fov) / 2) / size
    s_px = radius / z / pixel
    measured_r = math.sqrt(2.0 * (r2 - s_px ** 2 / 2 - 1.0 / 6.0))
    assert abs(cx - size / 2) < 0.05 and abs(cy - size / 2) < 0.05
    assert abs(measured_r / expected_r - 1.0) < 0.03, (measured_r, expected_r)
    # the energy does not depend on focus: the same emitter in focus gives the same total
    focused = render(scene.with_camera(focus_distance=z), 256).image[..., 0]
    assert abs(focused.sum() / wsum - 1.0) < 0.01
    assert (img > 0).sum() > 10 * (focused > 0).sum()


# --- motion blur ---------------------------------------------------------------------------------


def test_motion_blur_time_averaged_coverage():
    """A sphere moving along x seen by a near-orthographic camera: the pixel value is the time
    fraction of the shutter during which the sphere covers the pixel, averaged over the pixel."""
    r, x0, x1, w, h = 0.5, -1.0, 1.0, 48, 8
    dist = 1000.0
    half_w = 2.0
    fov = 2 * math.degrees(math.atan(half_w * h / w / dist))
    scene = warprt.Scene(
        camera=warprt.Camera(eye=(0, 0, dist), look_at=(0, 0, 0), fov=fov, width=w, height=h),
        shapes=(warprt.Sphere(center=(x0, 0, 0), center_end=(x1, 0, 0), radius=r, material="flat"),),
        materials={"flat": warprt.Material(kd=0.0, ka=1.0)}, ambient=1.0,
        render=warprt.RenderSettings(sampler="sobol"))
    img = render(scene, 1024).image[..., 0]
    # closed form at a ray through (X, Y): covered while |c(t) - X| < sqrt(r^2 - Y^2), c(t) = x0 + t (x1 - x0)
    k = 24
    expected = np.zeros((h, w))
    for j in range(h):
        for i in range(w):
            g = (np.arange(k) + 0.5) / k
            X = (2 * (i + g[:, None]) / w - 1) * half_w
            Y = (1 - 2 * (j + g[None, :]) / h) * half_w * h / w
            half_chord = np.sqrt(np.maximum(r * r - Y * Y, 0.0))
            lo, hi = np.maximum(X - half_chord, x0), np.minimum(X + half_chord, x1)
            expected[j, i] = (np.maximum(hi - lo, 0.0) / (x1 - x0)).mean()
    assert np.abs(img - expected).max() < 0.02
    assert abs(float((img - expected).mean())) < 2e-3
    # the shutter limits the blur: a closed shutter [0, 0] shows the sphere at its start
    still = render(scene.with_camera(shutter=(0.0, 0.0)), 16).image[..., 0]
    assert still[h // 2, w // 4] > 0.9 and still[h // 2, w - 1] == 0.0  # x = -1 covered, x = 2 not


def test_moving_mesh_instance_blurs_like_the_moving_sphere_center():
    """A mesh moves through its instance transform (no BVH rebuild): a flat square translated
    across the shutter covers each pixel for the closed-form fraction of time."""
    w, h = 32, 4
    square = warprt.Mesh(vertices=[[-0.25, -1, 0], [0.25, -1, 0], [0.25, 1, 0], [-0.25, 1, 0]],
                         faces=[[0, 1, 2], [0, 2, 3]], material="flat",
                         transform=warprt.Transform(translate=(-1, 0, 0)), transform_end=warprt.Transform(translate=(1, 0, 0)))
    dist, half_w = 1000.0, 2.0
    fov = 2 * math.degrees(math.atan(half_w * h / w / dist))
    scene = warprt.Scene(camera=warprt.Camera(eye=(0, 0, dist), look_at=(0, 0, 0), fov=fov, width=w, height=h),
                         shapes=(square,), materials={"flat": warprt.Material(kd=0.0, ka=1.0)}, ambient=1.0,
                         render=warprt.RenderSettings(sampler="sobol"))
    img = render(scene, 512).image[..., 0]
    g = (np.arange(64) + 0.5) / 64
    expected = np.array([(np.clip(np.minimum((2 * (i + g) / w - 1) * half_w + 0.25, 1.0)
                                  - np.maximum((2 * (i + g) / w - 1) * half_w - 0.25, -1.0), 0, None) / 2.0).mean()
                         for i in range(w)])
    assert np.abs(img[h // 2] - expected).max() < 0.02


# --- glossy reflection and frosted refraction ------------------------------------------------------


def test_glossy_lobe_sees_a_disk_light_with_the_closed_form_fraction():
    """At normal incidence, a Phong lobe of exponent n puts 1 - cos^(n+1)(α) of its directions
    inside a cone of half angle α; a disk light of angular radius α around the mirror direction
    therefore shows as km·Le·(1 - cos^(n+1) α).

    The field of view is 0.05° so that every camera ray meets the mirror within 4e-4 rad of the
    normal: the tilt of the lobe's axis changes the fraction by 7e-6 (at 0.5° it was -6.8e-4,
    from a float64 quadrature of the lobe over the disk for each point of the pixels). Tolerance:
    the relative error of this render over 24 seeds has mean +6e-5 ± 6e-5 and standard deviation
    2.7e-4, so 4σ = 1.1e-3; a Phong normalisation off by one in the exponent (1/(n+2) for
    1/(n+1) in square_to_cos_power) moves the pixel by 1.05%."""
    n_exp, km, le = 50.0, 0.8, 1.0
    alpha = math.radians(12.0)
    mirror_dist = 2.0
    disk_r = mirror_dist * math.tan(alpha)
    scene = warprt.Scene(
        camera=warprt.Camera(eye=(0, 0, 0), look_at=(0, 0, -1), fov=0.05, width=2, height=2),
        shapes=(warprt.Rectangle(corner=(-5, -5, -mirror_dist), edge1=(10, 0, 0), edge2=(0, 10, 0), material="gloss"),),
        materials={"gloss": warprt.Material(kd=0.0, ka=0.0, mirror=km, glossy_exponent=n_exp)},
        lights=(warprt.DiskLight(center=(0, 0, 0), normal=(0, 0, -1), radius=disk_r, radiance=le),),
        render=warprt.RenderSettings(sampler="sobol", t_min=1e-4))
    img = render(scene, 4096).image[..., 0]
    expected = km * le * (1.0 - math.cos(alpha) ** (n_exp + 1.0))
    assert abs(float(img.astype(np.float64).mean()) / expected - 1.0) < 4 * 2.7e-4, (img.mean(), expected)


def test_glossy_and_frosted_conserve_a_uniform_background():
    """Every glossy or frosted sample ends in the background: at normal incidence no lobe
    direction is lost, so the pixel is exactly km·bg (mirror) or kt·bg (frosted plate)."""
    bg = (0.3, 0.6, 0.9)
    cam = warprt.Camera(eye=(0, 0, 0), look_at=(0, 0, -1), fov=1.0, width=2, height=2)
    glossy = warprt.Scene(camera=cam, background=bg,
                          shapes=(warprt.Rectangle(corner=(-5, -5, -2), edge1=(10, 0, 0), edge2=(0, 10, 0), material="g"),),
                          materials={"g": warprt.Material(kd=0.0, ka=0.0, mirror=0.7, glossy_exponent=200)})
    np.testing.assert_allclose(render(glossy, 64).image, np.broadcast_to(0.7 * np.float32(bg), (2, 2, 3)), rtol=1e-5)
    plate = (warprt.Rectangle(corner=(-5, -5, -2.0), edge1=(10, 0, 0), edge2=(0, 10, 0), material="frost"),
             warprt.Rectangle(corner=(-5, -5, -2.1), edge1=(0, 10, 0), edge2=(10, 0, 0), material="frost"))  # faces -z
    frosted = warprt.Scene(camera=cam, background=bg, shapes=plate,
                           materials={"frost": warprt.Material(kd=0.0, ka=0.0, transparency=1.0, ior=1.5,
                                                               frosted_exponent=2000)})
    img = render(frosted, 64).image
    np.testing.assert_allclose(img, np.broadcast_to(np.float32(bg), (2, 2, 3)), rtol=1e-5)


# --- determinism and progressive rendering ---------------------------------------------------------


def _busy_scene() -> warprt.Scene:
    return warprt.Scene(
        camera=warprt.Camera(eye=(0, 1, 4), look_at=(0, 0.4, 0), width=20, height=14, aperture=0.05),
        shapes=(warprt.Plane(material="floor"),
                warprt.Sphere(center=(-0.6, 0.4, 0), center_end=(-0.4, 0.4, 0), radius=0.4, material="glass"),
                warprt.Sphere(center=(0.6, 0.4, 0), radius=0.4, material="gloss")),
        materials={"floor": warprt.Material(kd=0.7),
                   "glass": warprt.Material(kd=0.0, transparency=1.0, fresnel="exact", frosted_exponent=300),
                   "gloss": warprt.Material(kd=0.2, mirror=0.6, glossy_exponent=100)},
        lights=(warprt.RectLight(corner=(-0.5, 2, -0.5), edge1=(1, 0, 0), edge2=(0, 0, 1), radiance=3, samples=2),
                warprt.PointLight(position=(2, 3, 2), intensity=0.4)),
        ambient=0.05, background=(0.3, 0.4, 0.6))


@pytest.mark.parametrize("sampler", ["independent", "stratified", "sobol"])
def test_bit_identical_for_any_workers_slices_and_passes(sampler):
    scene = _busy_scene().with_settings(sampler=sampler)
    a = render(scene, 8, seed=3, workers=1, slices=1).image
    b = render(scene, 8, seed=3, workers=2, slices=5).image
    c = render(scene, 8, seed=3, workers=2, slices=7, pass_spp=3).image
    assert a.tobytes() == b.tobytes() == c.tobytes()
    d = render(scene, 8, seed=4).image
    assert np.abs(a - d).mean() > 1e-4
    assert abs(float(a.mean() - d.mean())) < 0.05 * float(a.mean())


def _penumbra_scene(w=40, h=28):
    """A square occluder over a floor under a rectangle light: penumbrae and a fully lit floor."""
    return warprt.Scene(
        camera=warprt.Camera(eye=(0, 2.2, 3.2), look_at=(0, 0, 0), width=w, height=h, fov=45),
        shapes=(warprt.Plane(material="floor"),
                warprt.Rectangle(corner=(-0.4, 0.5, -0.4), edge1=(0.8, 0, 0), edge2=(0, 0, 0.8), material="floor")),
        materials={"floor": warprt.Material(kd=0.7, ka=0.0)},
        lights=(warprt.RectLight(corner=(-0.6, 1.6, -0.6), edge1=(1.2, 0, 0), edge2=(0, 0, 1.2), radiance=3.0,
                                 samples=1),),  # (the same shadow rays per sample, adaptive or not)
        render=warprt.RenderSettings(sampler="sobol"))


def test_adaptive_sampling_spends_the_budget_where_the_noise_is():
    """At the same budget (32 spp on average, its pilot of 16 included) the adaptive image is
    closer to a 1024-spp reference than the uniform one: relative MSE over 4 seeds, measured
    0.31× of the uniform render's (its mean count is the budget, its fully lit floor keeps spp / 2)."""
    from warprt.testing import relative_mse

    scene = _penumbra_scene()
    r = warprt.Renderer(scene, device="cpu", features=FULL)
    ref = r.render(spp=1024, seed=99, progress=False, adaptive=False).image
    uni = np.mean([relative_mse(r.render(spp=32, seed=s, progress=False, adaptive=False).image, ref)
                   for s in range(4)])
    res = [r.render(spp=32, seed=s, progress=False, adaptive=True) for s in range(4)]
    ada = np.mean([relative_mse(x.image, ref) for x in res])
    print(f"\nrelative MSE at 32 spp: uniform {uni:.3g}, adaptive {ada:.3g} ({ada / uni:.2f}x)")
    assert all(x.spp == 32 for x in res)
    assert ada < 0.5 * uni


def _film_with_stats(w, h, seed, n0):
    """A CPU film holding the sums of n0 grey samples a pixel: random means, a few pixels far
    brighter or noisier than the rest (so that counts differ)."""
    from warprt.film import Film

    rng = np.random.default_rng(seed)
    f = Film(w, h, "cpu")
    odd = rng.random(w * h) < 0.02
    mean = np.where(odd & (n0 == 1), 5.0, rng.uniform(0.1, 1.0, w * h))
    var = np.where(odd, 0.5, 0.01) ** 2 if n0 > 1 else np.zeros(w * h)
    f.data.accum.assign(np.repeat((mean * n0)[:, None], 3, axis=1).astype(np.float32))
    f.data.accum_sq.assign(((var * (n0 - 1) / n0 + mean ** 2) * n0).astype(np.float32))
    return f


def test_adaptive_shares_round_to_integers_keeping_their_sum_largest_parts_first():
    """The rounding of adaptive sampling's shares (``film._round_keeping_sum``, a histogram of the
    fractional parts, then the one bucket ordered exactly) against a full sort: the floors, plus
    one for the round(Σ x − Σ floor x) largest fractional parts, ties to the lower index; on
    random shares, shares with many equal parts (every part in one bucket, or parts that fall on
    bucket edges), integers, and budgets of one extra sample."""
    from warprt.film import ROUND_BUCKETS, _round_keeping_sum

    rng = np.random.default_rng(11)
    edges = np.arange(ROUND_BUCKETS) / (ROUND_BUCKETS - 1)
    cases = [np.minimum(4 + 4 * rng.exponential(1.0, 65536), 64.0), rng.random(5000) * 30,
             np.full(4097, 2.5), np.round(rng.random(20000) * 9, 2), rng.integers(0, 9, 3000).astype(float),
             rng.integers(0, 5, 9000) + rng.choice(edges[::97], 9000), np.array([0.25, 0.5, 0.75, 0.5, 0.5]),
             np.array([1e-9, 0.5 + 1e-9, 0.5, 0.5]), np.array([2.0, 3.0]), np.array([0.3, 0.3, 0.4])]
    for x in cases:
        base = np.floor(x)
        extra = int(round(float(x.sum()) - float(base.sum())))
        want = base.copy()
        want[np.lexsort((np.arange(x.size), -(x - base)))[:extra]] += 1.0  # largest part first, then lower index
        got = _round_keeping_sum(x)
        np.testing.assert_array_equal(got, want.astype(np.int32))
        assert got.sum() == round(float(x.sum()))
        assert np.all(np.abs(got - x) < 1.0)


# the other checkerboard colour in a pixel's 5 × 5 window, written out: the 4 edge neighbours and
# the 8 a knight's move away
_NEAR_4 = ((-1, 0), (1, 0), (0, -1), (0, 1))
_FAR_8 = ((-2, -1), (-2, 1), (-1, -2), (-1, 2), (1, -2), (1, 2), (2, -1), (2, 1))
_U = 2.0 ** -24  # float32's unit roundoff
# float32's error in a deviation²: at most this many roundings of its terms' size (the scale below).
# Counted: a luminance 3 products, 2 sums and a scaling (7, with the weights' own); a variance its
# square, a subtraction and 2 scalings (18 of sq/n0 + y²); the weighted neighbour sums 12 adds,
# 2 weighings and a division (a further 14); the contrast's differences and squares (some 17 of
# its terms) and the last sums; with one sample, the mean's square (about 40 of s2 + m²).
_ROUNDINGS = 48


def _deviations_by_the_rule(acc, sq, w, h, n0):
    """``adaptive_counts``' documented deviations², pixel by pixel, in float64 from the film's
    float32 sums, and each one's scale (the same terms with every difference taken as a sum of
    magnitudes), of which float32's error is a small multiple."""
    from warprt.film import ADAPTIVE_CONTRAST, ADAPTIVE_NEAR_WEIGHT, ADAPTIVE_NEAR_WEIGHT_1, ADAPTIVE_RIDGE

    acc, sq = acc.astype(np.float64), sq.astype(np.float64)
    y = (0.2126 * acc[:, 0] + 0.7152 * acc[:, 1] + 0.0722 * acc[:, 2]) / n0
    if n0 >= 2:
        v = np.maximum(sq / n0 - y * y, 0.0) * n0 / (n0 - 1)
        v_scale = (sq / n0 + y * y) * n0 / (n0 - 1)
    else:
        v = v_scale = y * y
    Y = y.reshape(h, w)
    near_w = ADAPTIVE_NEAR_WEIGHT if n0 >= 2 else ADAPTIVE_NEAR_WEIGHT_1
    d2, scale = np.zeros(h * w), np.zeros(h * w)
    for r in range(h):
        for c in range(w):
            sv = sy = sv_scale = wt = 0.0
            for offsets, weight in ((_NEAR_4, near_w), (_FAR_8, 1.0)):
                for a, b in offsets:
                    if 0 <= r + a < h and 0 <= c + b < w:
                        k = (r + a) * w + c + b
                        sv, sy, wt = sv + weight * v[k], sy + weight * y[k], wt + weight
                        sv_scale += weight * v_scale[k]
            wt = max(wt, 1.0)
            if n0 == 1:  # the weighted spread of the neighbours' values about their weighted mean
                m = sy / wt
                d2[r * w + c] = max(sv / wt - m * m, 0.0)
                scale[r * w + c] = sv / wt + m * m
                continue
            con = con_scale = 0.0
            across, down = 0 < c < w - 1, 0 < r < h - 1
            if across:
                con += ADAPTIVE_CONTRAST / 4 * (Y[r, c + 1] - Y[r, c - 1]) ** 2
                con_scale += ADAPTIVE_CONTRAST / 4 * (abs(Y[r, c + 1]) + abs(Y[r, c - 1])) ** 2
            if down:
                con += ADAPTIVE_CONTRAST / 4 * (Y[r + 1, c] - Y[r - 1, c]) ** 2
                con_scale += ADAPTIVE_CONTRAST / 4 * (abs(Y[r + 1, c]) + abs(Y[r - 1, c])) ** 2
            if across and down:
                four = (Y[r, c - 1], Y[r, c + 1], Y[r - 1, c], Y[r + 1, c])
                con += ADAPTIVE_RIDGE / 16 * (four[0] + four[1] - four[2] - four[3]) ** 2
                con_scale += ADAPTIVE_RIDGE / 16 * sum(abs(x) for x in four) ** 2
            d2[r * w + c] = (1 - ADAPTIVE_CONTRAST) * sv / wt + con
            scale[r * w + c] = (1 - ADAPTIVE_CONTRAST) * sv_scale / wt + con_scale
    return d2, scale


def capped_shares(d: np.ndarray, n_min: int, spp: int, cap: float):
    """Adaptive sampling's shares in float64 by their definition: n_min + the budget (spp −
    n_min) × M in proportion to d, the largest k held at ``cap`` and the budget they leave shared
    the same way among the others, k the least whose next share stays at or under the cap (by a
    sort; the library iterates). (shares, k, budget left to the others, their Σ d)."""
    m = d.size
    budget = float(spp - n_min) * m
    order = np.argsort(-d, kind="stable")
    rest = np.cumsum(d[order][::-1])[::-1]  # Σ d over the k-th largest on
    for k in range(m):
        left, free = budget - k * (cap - n_min), float(rest[k])
        if free <= 0.0 or n_min + left * float(d[order[k]]) / free <= cap:
            break
    share = np.full(m, float(n_min)) if free <= 0.0 else np.minimum(n_min + left * d / free, cap)
    share[order[:k]] = cap
    return share, k, left, free


def test_adaptive_counts_follow_their_rule_pixel_for_pixel():
    """``adaptive_counts`` (float32 deviations, float64 shares) against its documented rule
    computed pixel by pixel in float64 from the same sums: films of 1 × 1 to 37 × 23 pixels (every
    pixel within 2 of an edge, or not), pilots of 1, 2 and 4 samples, noisy sums, equal sums
    (every share alike), sums all zero (no deviation: the budget as it is) and a few bright
    pixels among dark ones (shares capped at ADAPTIVE_MAX_FACTOR × spp). Each deviation² is
    within float32's rounding of the rule's (``_ROUNDINGS`` of its terms' size). Each colour's
    counts are the rule's shares rounded keeping their sum, largest fractional parts first, up to
    the error in a share that the deviations' rounding allows (``tol``): every count within 1 of
    its share, the counts' errors (count − share) all within an interval of length 1, their sum
    round(Σ shares); and pixel for pixel the rule's own rounding (a full sort) wherever no part
    rounded the other way lies within the two parts' tolerances (all but a few ties)."""
    from warprt.film import ADAPTIVE_MAX_FACTOR, ADAPTIVE_MIN_SHARE, _LUMA, Film, _deviations, adaptive_counts

    rng = np.random.default_rng(7)
    worst, pinned, loose, capped, capped_colours = 0.0, 0, 0, 0, 0
    for w, h in [(1, 1), (2, 3), (5, 5), (4, 7), (6, 9), (17, 9), (37, 23)]:
        for n0, spp in [(1, 2), (2, 4), (4, 8), (4, 64)]:
            for kind in ("noise", "equal", "zero", "sparse"):
                what = f"{w}x{h}, pilot {n0}, {spp} spp, {kind}"
                acc = rng.random((w * h, 3), dtype=np.float32) * rng.exponential(2.0, (w * h, 1)).astype(np.float32)
                if kind == "equal":
                    acc[:] = 0.5
                elif kind == "zero":
                    acc[:] = 0.0
                elif kind == "sparse":
                    acc[rng.random(w * h) < 0.95] = 0.0
                y = acc @ _LUMA
                spread = rng.uniform(1.0, 3.0, w * h) if kind in ("noise", "sparse") else 1.5
                f = Film(w, h, "cpu")
                f.data.accum.assign(acc * n0)
                f.data.accum_sq.assign((y * y * spread * n0).astype(np.float32))
                d2, scale = _deviations_by_the_rule(f.data.accum.numpy(), f.data.accum_sq.numpy(), w, h, n0)
                bound = _ROUNDINGS * _U * scale
                got_d = _deviations(f, n0).astype(np.float64)
                assert np.all(np.abs(got_d ** 2 - d2) <= bound), what
                worst = max(worst, float(np.max(np.abs(got_d ** 2 - d2) / np.maximum(_U * scale, 1e-300))))
                got = adaptive_counts(f, n0, spp)
                assert got.dtype == np.int32 and got.shape == (w * h,)
                n_min = max(1, n0, spp // ADAPTIVE_MIN_SHARE)
                d = np.sqrt(d2)
                with np.errstate(divide="ignore", invalid="ignore"):
                    dd = np.minimum(np.sqrt(bound), np.where(d > 0, bound / d, np.inf))  # |float32 d − d|
                colour = (np.add.outer(np.arange(h), np.arange(w)) & 1).reshape(-1)
                for mine in (colour == 0, colour == 1):
                    m, total, slack = int(mine.sum()), float(d[mine].sum()), float(dd[mine].sum())
                    if m == 0:
                        continue
                    if total == 0.0 and slack == 0.0:  # (no deviation at all: every count the budget)
                        np.testing.assert_array_equal(got[mine], spp, err_msg=what)
                        continue
                    if total <= slack:  # (deviations within float32's rounding of 0: shares are noise)
                        assert kind in ("equal", "zero") or w * h == 1, what
                        continue
                    budget = float(spp - n_min) * m
                    # the largest k shares held at the cap and the rest of the budget shared in
                    # proportion among the others: the least k whose next share stays under it
                    share, k, left, free = capped_shares(d[mine], n_min, spp, ADAPTIVE_MAX_FACTOR * spp)
                    order = np.argsort(-d[mine], kind="stable")
                    if k:
                        capped_colours += 1
                    tol = left * (dd[mine] / (free - slack) + d[mine] * slack / (free * (free - slack))) + 1e-9
                    tol[order[:k]] = 1e-9
                    # the budget is spent whole: the counts add up to spp a pixel
                    assert abs(float(got[mine].sum()) - spp * m) <= 0.5 + float(tol.sum()), what
                    err = got[mine] - share
                    assert np.all(np.abs(err) < 1.0 + tol), what
                    assert float(np.max(err - tol)) <= float(np.min(err + tol)) + 1.0, what  # largest parts first
                    assert abs(float(got[mine].sum()) - float(share.sum())) <= 0.5 + float(tol.sum()), what
                    # the rule's own rounding: the floors, plus one for the largest fractional
                    # parts (a full sort, ties to the lower index); a count may differ from it only
                    # where its part and one rounded the other way are within their tolerances
                    base = np.floor(share)
                    part = share - base
                    up = np.zeros(m, bool)
                    up[np.lexsort((np.arange(m), -part))[:int(round(float(share.sum() - base.sum())))]] = True
                    close = np.zeros(m, bool)
                    if up.any() and not up.all():
                        close = np.where(up, part - tol <= np.max((part + tol)[~up]),
                                         part + tol >= np.min((part - tol)[up]))
                    np.testing.assert_array_equal(got[mine][~close], (base + up)[~close], err_msg=what)
                    pinned += int(np.count_nonzero(~close))
                    loose += int(np.count_nonzero(close))
                if kind == "noise" and w * h >= 25:
                    assert got.max() > got.min()  # (shared unevenly: the rounding and the caps at work)
                capped += int(np.count_nonzero(got == ADAPTIVE_MAX_FACTOR * spp))
    print(f"\nworst deviation² error {worst:.2f} roundings of its scale; {pinned} counts pinned, {loose} loose, "
          f"{capped} capped")
    # (loose: 48 of 12131, the sparse films' equal parts, which a share's rounding could order either way)
    assert pinned > 10000 and loose < 0.01 * pinned and capped > 0 and capped_colours > 0


@pytest.mark.parametrize("edge_at", [8, 1, 15], ids=["inside", "next to the left border", "next to the right"])
def test_adaptive_counts_follow_a_noise_free_edge_to_its_own_pixels(edge_at):
    """A pilot with no noise at all (every sample of a pixel alike) and one sharp vertical edge,
    dark (0.1) left of column ``edge_at`` and bright (0.9) from it on: the mean variance is 0
    everywhere, so only the contrast across a pixel (ADAPTIVE_CONTRAST / 4 of the squared
    difference of its left and right neighbours, Δ = 0.8) and the ridge (ADAPTIVE_RIDGE / 16 of
    (left + right − above − below)², also Δ² there: its own column's pixels above and below are
    on its side) can tell where samples are needed: the two columns whose left and right
    neighbours lie on either side of the edge, the ridge only in rows with both neighbours. In
    closed form each colour's share of the budget spp × M (M pixels a colour) goes to those
    pixels in proportion to Δ·sqrt(contrast + ridge) or Δ·sqrt(contrast) (top and bottom rows),
    at most ADAPTIVE_MAX_FACTOR × spp (a capped share's excess shared among the others), then
    rounded keeping the sum; every other pixel keeps its pilot."""
    from warprt.film import ADAPTIVE_CONTRAST, ADAPTIVE_MAX_FACTOR, ADAPTIVE_RIDGE, Film, adaptive_counts

    w, h, n0, spp = 16, 8, 4, 8
    y = np.where(np.arange(w) >= edge_at, 0.9, 0.1)[None, :].repeat(h, 0).reshape(-1).astype(np.float32)
    f = Film(w, h, "cpu")
    f.data.accum.assign(np.repeat((y * n0)[:, None], 3, axis=1).astype(np.float32))  # grey: luminance y
    f.data.accum_sq.assign((y * y * n0).astype(np.float32))  # (no variance)
    cols = np.arange(w)[None, :].repeat(h, 0).reshape(-1)
    rows = np.arange(h)[:, None].repeat(w, 1).reshape(-1)
    edge = ((cols == edge_at - 1) | (cols == edge_at)) & (cols >= 1) & (cols <= w - 2)
    if edge_at == 1:  # (column 0 has no left neighbour: only column 1 sees the edge)
        assert edge.sum() == h
    dev = np.where(edge, 0.8 * np.sqrt(ADAPTIVE_CONTRAST / 4 + np.where((rows >= 1) & (rows <= h - 2),
                                                                       ADAPTIVE_RIDGE / 16, 0.0)), 0.0)
    colour = (np.add.outer(np.arange(h), np.arange(w)) & 1).reshape(-1)
    share = np.full(w * h, float(n0))
    for c in (0, 1):
        mine = colour == c
        share[mine] = capped_shares(dev[mine], n0, spp, ADAPTIVE_MAX_FACTOR * spp)[0]
    got = adaptive_counts(f, n0, spp)
    np.testing.assert_array_equal(got[~edge], n0)
    assert np.all(np.abs(got - share) < 1.0), (got[edge], share[edge])
    assert got.sum() == round(share.sum())
    if edge_at == 8:  # (no pixel at the cap: the budget spent exactly)
        assert got.sum() == spp * w * h and got[edge].min() > 2 * spp


def test_adaptive_counts_find_a_noise_free_thin_line():
    """A one-pixel bright line (0.9) across a dark pilot (0.1), no noise: its own pixels have
    bright left and right neighbours and dark ones above and below, so no contrast across them but
    the ridge, ADAPTIVE_RIDGE / 16 × (2 × 0.8)²; the rows next to it see the contrast (0.8² ×
    ADAPTIVE_CONTRAST / 4) and a quarter of that ridge. The line's row gets the counts those
    deviations give in closed form (in proportion to their roots), more than its neighbours' rows
    (without the ridge it would keep its pilot), and every other row its pilot."""
    from warprt.film import ADAPTIVE_CONTRAST, ADAPTIVE_RIDGE, Film, adaptive_counts

    w, h, n0, spp, line = 12, 9, 4, 8, 4
    rows = np.arange(h)[:, None].repeat(w, 1).reshape(-1)
    cols = np.arange(w)[None, :].repeat(h, 0).reshape(-1)
    y = np.where(rows == line, 0.9, 0.1).astype(np.float32)
    f = Film(w, h, "cpu")
    f.data.accum.assign(np.repeat((y * n0)[:, None], 3, axis=1).astype(np.float32))
    f.data.accum_sq.assign((y * y * n0).astype(np.float32))
    inner = (cols >= 1) & (cols <= w - 2)  # (the ridge needs left and right neighbours)
    d_line = np.where(inner, 2 * 0.8 * np.sqrt(ADAPTIVE_RIDGE / 16), 0.0)
    d_next = 0.8 * np.sqrt(ADAPTIVE_CONTRAST / 4 + np.where(inner, ADAPTIVE_RIDGE / 16, 0.0))  # (0.8², not (2 × 0.8)²)
    dev = np.where(rows == line, d_line, np.where(np.abs(rows - line) == 1, d_next, 0.0))
    colour = (np.add.outer(np.arange(h), np.arange(w)) & 1).reshape(-1)
    share = np.full(w * h, float(n0))
    for c in (0, 1):
        mine = colour == c
        share[mine] = n0 + (spp - n0) * mine.sum() * dev[mine] / dev[mine].sum()
    got = adaptive_counts(f, n0, spp)
    assert np.all(np.abs(got - share) < 1.0), (got.reshape(h, w), share.reshape(h, w))
    assert got.sum() == spp * w * h
    on, next_to = got[(rows == line) & inner], got[(np.abs(rows - line) == 1) & inner]
    assert on.min() > next_to.max()
    np.testing.assert_array_equal(got[np.abs(rows - line) > 1], n0)


def test_adaptive_deviations_one_sample_pilot_weights_and_larger_pilots():
    """A 5 × 5 film's centre pixel, its 4 edge neighbours alike (a) and its 8 farther neighbours of
    the other colour alike (b): with a one-sample pilot its deviation is the weighted spread of
    their values, the near ones weighing ADAPTIVE_NEAR_WEIGHT_1 (6); with a pilot of 4, whose
    near and far neighbours have variances va and vb (and the same means, so neither contrast nor
    ridge), the root of (1 - ADAPTIVE_CONTRAST) of their weighted mean variance, the near ones
    weighing ADAPTIVE_NEAR_WEIGHT (12). In closed form, to float32's rounding."""
    from warprt.film import ADAPTIVE_CONTRAST, ADAPTIVE_NEIGHBOURS, Film, _deviations

    near = ((1, 2), (3, 2), (2, 1), (2, 3))
    far = [(2 + a, 2 + b) for a, b in ADAPTIVE_NEIGHBOURS if abs(a) + abs(b) != 1]
    for n0, (a, b), (va, vb) in ((1, (0.7, 0.2), (0.0, 0.0)), (4, (0.5, 0.5), (0.09, 0.01))):
        y = np.full((5, 5), 0.5, np.float32)
        v = np.zeros((5, 5), np.float32)
        for r, c in near:
            y[r, c], v[r, c] = a, va
        for r, c in far:
            y[r, c], v[r, c] = b, vb
        f = Film(5, 5, "cpu")
        f.data.accum.assign(np.repeat((y.reshape(-1) * n0)[:, None], 3, axis=1).astype(np.float32))
        sq = (v * (n0 - 1) / n0 + y * y) * n0 if n0 > 1 else y * y
        f.data.accum_sq.assign(sq.reshape(-1).astype(np.float32))
        got = float(_deviations(f, n0)[12])
        if n0 == 1:
            m = (6.0 * 4 * a + 8 * b) / 32.0
            want = np.sqrt((6.0 * 4 * a * a + 8 * b * b) / 32.0 - m * m)
        else:
            want = np.sqrt((1 - ADAPTIVE_CONTRAST) * (12.0 * 4 * va + 8 * vb) / 56.0)
        assert got == pytest.approx(want, rel=1e-5), (n0, got, want)


@pytest.mark.parametrize("n0, spp", [(4, 16), (1, 2)], ids=["pilot of 4", "pilot of 1"])
def test_adaptive_counts_never_read_the_pixels_own_samples(n0, spp):
    """A pixel's count, and those of every pixel of its checkerboard colour, must not change when
    its own pilot samples do (that independence is what lets the image keep the pilot unbiased);
    the other colour's counts must (its samples are what they are made from). With a pilot of
    one sample a pixel (2 spp) the counts come from the spread of the neighbours' values."""
    from warprt.film import adaptive_counts

    w, h = 24, 19
    f = _film_with_stats(w, h, 3, n0)
    base = adaptive_counts(f, n0, spp)
    # the budget kept to the sample (rounded per colour), and spent unevenly (the noisy pixels'
    # neighbours get over 1.5 times the mean: 28 of 16 at most here, the film's random means adding
    # contrast everywhere)
    assert base.min() >= n0 and abs(base.sum() - spp * w * h) <= 1 and base.max() > 1.5 * spp
    colour = (np.add.outer(np.arange(h), np.arange(w)) & 1).reshape(-1)
    acc = f.data.accum.numpy().copy()  # (on the CPU numpy() is a view of the film)
    sq = f.data.accum_sq.numpy().copy()
    for x in (0, w + 1, (h // 2) * w + w // 2, w * h - 1):  # corners and the middle
        a2, sq2 = acc.copy(), sq.copy()
        a2[x] = acc[x] * 20.0 + 5.0  # this pixel's pilot now looks very bright and very noisy
        sq2[x] = sq[x] * 2000.0 + 100.0 * n0
        f.data.accum.assign(a2)
        f.data.accum_sq.assign(sq2)
        counts = adaptive_counts(f, n0, spp)
        same = colour == colour[x]
        assert np.array_equal(counts[same], base[same]), f"pixel {x}: its own colour's counts moved"
        assert not np.array_equal(counts[~same], base[~same]), f"pixel {x}: its neighbours did not react"


def _hole_scene(w=16, h=12):
    """A floor lit by a rectangle light through a 0.1 × 0.1 hole in an opaque plate: a light
    sample gets through about 2% of the time, so most pixels' pilots see nothing at all."""
    y, s, big = 1.0, 0.05, 3.0
    plates = (warprt.Rectangle(corner=(-big, y, -big), edge1=(0, 0, 2 * big), edge2=(big - s, 0, 0), material="m"),
              warprt.Rectangle(corner=(s, y, -big), edge1=(0, 0, 2 * big), edge2=(big - s, 0, 0), material="m"),
              warprt.Rectangle(corner=(-s, y, -big), edge1=(0, 0, big - s), edge2=(2 * s, 0, 0), material="m"),
              warprt.Rectangle(corner=(-s, y, s), edge1=(0, 0, big - s), edge2=(2 * s, 0, 0), material="m"))
    return warprt.Scene(
        camera=warprt.Camera(eye=(0, 0.9, 0.01), look_at=(0, 0, 0), width=w, height=h, fov=60),
        shapes=(warprt.Plane(material="m"),) + plates, materials={"m": warprt.Material(kd=0.7, ka=0.0)},
        lights=(warprt.RectLight(corner=(-0.5, 2.0, -0.5), edge1=(1.0, 0, 0), edge2=(0, 0, 1.0), radiance=3.0),),
        render=warprt.RenderSettings(sampler="independent"))


@pytest.mark.parametrize("spp", [16, 2], ids=["16 spp", "2 spp: a pilot of one sample"])
def test_adaptive_sampling_keeps_its_pilot_and_stays_unbiased_on_rare_light(spp):
    """Where a pixel's light is a rare event, counts decided by the pixel's own pilot would bias a
    mean that keeps the pilot (measured: 0.34× the true brightness, z = -16: a lucky pilot buys
    many samples that dilute its hit, an unlucky one few). Counts from the neighbours keep it
    unbiased: the adaptive image mean over 24 seeds matches 24 uniform renders' within 4 standard
    errors (measured ratio 1.02, z = 0.4 with 16 of each at 16 spp)."""
    scene = _hole_scene()
    r = warprt.Renderer(scene, device="cpu", features=FULL)
    runs = 24
    res = [r.render(spp=spp, seed=s, progress=False, adaptive=True) for s in range(runs)]
    ad = np.array([x.image[..., 0].mean() for x in res])
    un = np.array([r.render(spp=spp, seed=1000 + s, progress=False, adaptive=False).image[..., 0].mean()
                   for s in range(runs)])
    assert all(x.spp == spp for x in res)
    z = (ad.mean() - un.mean()) / math.sqrt(ad.var(ddof=1) / runs + un.var(ddof=1) / runs)
    print(f"\nadaptive {ad.mean():.5g}, uniform {un.mean():.5g}, z = {z:.2f}")
    assert abs(z) < 4.0


def test_adaptive_sampling_is_bit_identical_for_any_workers_and_slices():
    scene = _penumbra_scene(24, 16)
    a = render(scene, 16, seed=5, workers=1, slices=1, adaptive=True).image
    b = render(scene, 16, seed=5, workers=2, slices=5, adaptive=True).image
    c = render(scene, 16, seed=5, workers=2, slices=3, pass_spp=3, adaptive=True).image
    assert a.tobytes() == b.tobytes() == c.tobytes()
    assert a.tobytes() != render(scene, 16, seed=5).image.tobytes()  # it did adapt
    dev = warprt.Renderer(scene, device="cpu", features=FULL).render(spp=16, seed=5, adaptive=True, as_warp=True,
                                                                       progress=False).image
    assert dev.numpy().tobytes() == a.tobytes()


def test_adaptive_sampling_takes_a_budget_not_a_time_or_an_error():
    scene = _penumbra_scene(8, 6)
    for opt in (dict(time_budget=1.0), dict(target_error=0.01)):
        with pytest.raises(warprt.RenderError, match="adaptive"):
            render(scene, 16, adaptive=True, **opt)
    # below ADAPTIVE_MIN_SPP the budget is too small to share: a uniform render, bit for bit; from
    # it on the counts differ (4 spp: a pilot of 2 samples a pixel)
    from warprt.render import ADAPTIVE_MIN_SPP

    below, at = ADAPTIVE_MIN_SPP - 1, ADAPTIVE_MIN_SPP
    assert render(scene, below, seed=1, adaptive=True).image.tobytes() == render(scene, below, seed=1).image.tobytes()
    assert render(scene, at, seed=1, adaptive=True).image.tobytes() != render(scene, at, seed=1).image.tobytes()


def test_time_budget_stops_early_and_reports_the_spp_reached():
    scene = _busy_scene()
    result = render(scene, 100000, time_budget=0.5)
    assert 1 <= result.spp < 100000
    assert np.isfinite(result.image).all()
    # the partial image is an unbiased estimate: its mean agrees with a finished render's
    full = render(scene, 64)
    assert abs(float(result.image.mean() / full.image.mean()) - 1.0) < 0.05


def test_target_error_stops_when_the_estimate_is_reached():
    scene = _busy_scene()
    result = render(scene, 4096, target_error=0.02, pass_spp=4)
    assert result.spp < 4096
    assert result.relative_error is not None and result.relative_error <= 0.02
