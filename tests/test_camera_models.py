"""The camera models against OpenCV's own projections (``cv2.projectPoints``,
``cv2.fisheye.projectPoints``, ``cv2.undistortPoints``) and the orthographic closed form.

Conventions checked: ``fx, fy, cx, cy`` mean what they mean in OpenCV (pixel i's centre at i), so
warprt's raster position (pixel centres at i + 0.5) is OpenCV's pixel + 0.5; camera space in
OpenCV (x right, y down, z forward) is warprt's (u, -v, -w).

Round trips: raster point → ``camera_rays`` (float32, on the device) → a point on the ray →
``cv2.projectPoints`` (float64) must give the raster point back, and a world point → ``project``
(float32) must land where cv2 puts it. The tolerance is the float32 error of correct code,
measured: the round trip's error is that of a ray direction rounded to float32 (a relative
error of a few ε32 = 2^-24 per component), magnified by the distortion's local scale. So each
point's tolerance is ``ROUND_TRIP_ULPS`` ε32 times the pixel shift a unit relative change of
the direction causes there (``_pixel_scale``: fx·(1 + r²)·|J|, J the distortion's Jacobian).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import warp as wp

import warprt
from warprt import camera as cm
from warprt._warp import MODULE_OPTIONS

cv2 = pytest.importorskip("cv2")

EPS32 = float(np.finfo(np.float32).eps) / 2  # 2^-24, float32's unit roundoff
# measured on correct code (the four calibrations below, raster points every 1/4 pixel, and 2000
# projected points each): at most 3.9 roundoffs of the pixel scale, 99% below 2.1; the bound is 8
ROUND_TRIP_ULPS = 8.0

W, H = 64, 48
K_OPENCV = dict(fx=52.0, fy=53.5, cx=31.3, cy=24.6)
DISTORTIONS = {
    "barrel 5": (-0.28, 0.07, 0.0012, -0.0009, -0.008),
    "pincushion 4": (0.12, 0.02, -0.002, 0.001),
    "rational 8": (0.3, -0.1, 0.001, 0.002, 0.01, 0.45, -0.05, 0.02),
    "thin prism 12": (-0.2, 0.05, 0.001, -0.001, 0.0, 0.01, 0.0, 0.0, 0.004, -0.001, -0.003, 0.0008),
}
EYE, LOOK, UP = (0.4, 1.2, 3.0), (-0.3, 0.1, -1.0), (0.1, 1.0, 0.2)


def _camera(**kw) -> warprt.Camera:
    return warprt.Camera(eye=EYE, look_at=LOOK, up=UP, width=W, height=H, **kw)


def _cv_pose(cam: warprt.Camera):
    """OpenCV's rvec, tvec for a warprt camera: world → camera is R (x - eye), R's rows u, -v, -w."""
    u, v, w = cam.basis(0.0)
    R = np.stack([u, -v, -w])
    rvec, _ = cv2.Rodrigues(R)
    return rvec, -R @ np.asarray(cam.eye, np.float64), R


def _raster_grid(step: float = 1.0, margin: float = 0.0) -> np.ndarray:
    """Raster points over the whole image (pixel centres, corners and edges among them)."""
    xs = np.arange(margin, W - margin + 1e-9, step)
    ys = np.arange(margin, H - margin + 1e-9, step)
    return np.array([(x, y) for y in ys for x in xs], np.float64)


def _project_cv(cam, pts_world, dist, fisheye=False):
    rvec, tvec, _ = _cv_pose(cam)
    K = cam.camera_matrix()
    if fisheye:
        got, _ = cv2.fisheye.projectPoints(pts_world.reshape(-1, 1, 3), rvec, tvec, K, np.asarray(dist, np.float64))
    else:
        got, _ = cv2.projectPoints(pts_world.reshape(-1, 1, 3), rvec, tvec, K, np.asarray(dist, np.float64))
    return got.reshape(-1, 2) + 0.5  # OpenCV pixel → warprt raster


def _undistort_cv(pixels, K, dist):
    """OpenCV's undistortion of OpenCV pixels (N, 2) to normalised points, iterated to float64's
    precision (its default stops after 5 fixed-point steps)."""
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 500, 1e-16)
    return cv2.undistortPointsIter(np.asarray(pixels, np.float64).reshape(-1, 1, 2), K, np.asarray(dist, np.float64),
                                   None, None, crit).reshape(-1, 2)


def _pixel_scale(cam, raster, dist, fisheye=False, und=None, h=1e-6):
    """The pixel shift per unit relative change of the ray direction at each raster point:
    |d pixel / d (x_n, y_n)| · (1 + r²) for the opencv model (a direction's relative error moves
    the normalised point by about (1 + r²) times it; ``und``: the normalised points, else
    OpenCV's undistortion of the raster points), |d pixel / d θ| for the fisheye."""
    K = cam.camera_matrix()
    if fisheye:
        return np.full(len(raster), max(cam.fx, cam.fy) * 4.0)
    scale = []
    for (x, y) in (_undistort_cv(raster - 0.5, K, dist) if und is None else und):
        pts = np.array([[x, y, 1.0], [x + h, y, 1.0], [x, y + h, 1.0]])
        p, _ = cv2.projectPoints(pts.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), K, np.asarray(dist, np.float64))
        p = p.reshape(-1, 2)
        J = np.stack([(p[1] - p[0]) / h, (p[2] - p[0]) / h], axis=1)
        scale.append(np.linalg.norm(J, 2) * (1.0 + x * x + y * y))
    return np.array(scale)


# --- opencv: pixel → ray → cv2 and world → project → cv2 -------------------------------------


@pytest.mark.parametrize("name", list(DISTORTIONS))
def test_opencv_rays_round_trip_through_cv2_project_points(name):
    """Every raster point of the image (corners and edges too) gives a ray whose points cv2
    projects back onto it, to the measured float32 tolerance; none is refused in these
    calibrations (their monotonic range covers the image)."""
    dist = DISTORTIONS[name]
    cam = _camera(model="opencv", distortion=dist, **K_OPENCV)
    raster = _raster_grid(0.5)
    o, d = warprt.camera_rays(warprt.Scene(camera=cam), points=raster)
    assert (np.linalg.norm(d, axis=1) > 0.999).all(), "a raster point inside the valid range got no ray"
    pts = o.astype(np.float64) + 2.7 * d.astype(np.float64)
    back = _project_cv(cam, pts, dist)
    err = np.abs(back - raster).max(axis=1)
    tol = ROUND_TRIP_ULPS * EPS32 * _pixel_scale(cam, raster, dist)
    worst = int(np.argmax(err / tol))
    assert (err <= tol).all(), (f"raster {raster[worst]}: back at {back[worst]}, error {err[worst]:.3g} px > "
                                f"{tol[worst]:.3g}")
    # the check can fail: cv2 without the distortion puts the points elsewhere
    plain = _project_cv(cam, pts, np.zeros(5))
    assert np.abs(plain - raster).max() > 100 * tol.max()


def _project_kernel():
    @wp.kernel(module="unique", enable_backward=False, module_options=MODULE_OPTIONS)
    def k(cam: cm.CameraData, p: wp.array(dtype=wp.vec3), t: float, out: wp.array(dtype=wp.vec2)):
        i = wp.tid()
        out[i] = cm.project(cam, p[i], t)
    return k


_PROJECT = []


def _project(cam: warprt.Camera, pts: np.ndarray) -> np.ndarray:
    if not _PROJECT:
        _PROJECT.append(_project_kernel())
    out = wp.zeros(len(pts), dtype=wp.vec2, device="cpu")
    wp.launch(_PROJECT[0], dim=len(pts), device="cpu",
              inputs=[cm.camera_data(cam), wp.array(pts.astype(np.float32), dtype=wp.vec3, device="cpu"), 0.0, out])
    return out.numpy().astype(np.float64)


def _world_points(cam, n, rng, spread):
    """n world points in front of the camera, their normalised coordinates within ±spread."""
    _, _, R = _cv_pose(cam)
    xy = rng.uniform(-spread, spread, (n, 2))
    z = rng.uniform(0.5, 6.0, n)
    pc = np.stack([xy[:, 0] * z, xy[:, 1] * z, z], axis=1)
    return (R.T @ pc.T).T + np.asarray(cam.eye)


@pytest.mark.parametrize("name", list(DISTORTIONS))
def test_opencv_project_equals_cv2_project_points(name):
    """``camera.project`` (the forward model, used by the motion AOV) of world points in view
    equals cv2.projectPoints to float32 precision (the points rounded to float32, as the
    device holds them)."""
    dist = DISTORTIONS[name]
    cam = _camera(model="opencv", distortion=dist, **K_OPENCV)
    rng = np.random.default_rng(7)
    pts = _world_points(cam, 400, rng, 0.6).astype(np.float32).astype(np.float64)
    got = _project(cam, pts)
    want = _project_cv(cam, pts, dist)
    err = np.abs(got - want).max(axis=1)
    tol = ROUND_TRIP_ULPS * EPS32 * _pixel_scale(cam, want, dist)
    assert (err <= tol).all(), float((err / tol).max())


def test_intrinsics_pinhole_round_trips_and_matches_cv2():
    """A pinhole from intrinsics (fx ≠ fy, principal point off centre): rays and projections
    against cv2 without distortion; pixel (i, j)'s centre ray is OpenCV's ray through (i, j)."""
    cam = _camera(**K_OPENCV)
    raster = _raster_grid(1.0)
    o, d = warprt.camera_rays(warprt.Scene(camera=cam), points=raster)
    back = _project_cv(cam, o.astype(np.float64) + 1.9 * d.astype(np.float64), np.zeros(5))
    tol = ROUND_TRIP_ULPS * EPS32 * _pixel_scale(cam, raster, np.zeros(5))
    assert (np.abs(back - raster).max(axis=1) <= tol).all()
    # the centre of pixel (i, j) is OpenCV's (i, j): its ray is along K^-1 (i, j, 1) in camera space
    _, _, R = _cv_pose(cam)
    centre = warprt.camera_rays(warprt.Scene(camera=cam), points=[[5.5, 7.5]])[1][0]
    want = R.T @ np.linalg.solve(cam.camera_matrix(), [5.0, 7.0, 1.0])
    np.testing.assert_allclose(centre, want / np.linalg.norm(want), atol=8 * EPS32)
    pts = _world_points(cam, 200, np.random.default_rng(3), 0.6)
    got = _project(cam, pts.astype(np.float32).astype(np.float64))
    want = _project_cv(cam, pts.astype(np.float32).astype(np.float64), np.zeros(5))
    assert np.abs(got - want).max() <= ROUND_TRIP_ULPS * EPS32 * cam.fx * 2.0


def test_fov_camera_is_the_intrinsics_camera_it_names():
    """A camera from a field of view is the pinhole with fx = fy = H / (2 tan(fov/2)) and the
    principal point at the image centre ((W - 1) / 2 in OpenCV's pixels): the same rays."""
    fov = 50.0
    a = _camera(fov=fov)
    f = H / (2 * math.tan(math.radians(fov) / 2))
    b = _camera(fx=f, fy=f, cx=(W - 1) / 2, cy=(H - 1) / 2)
    np.testing.assert_allclose(a.intrinsics(), b.intrinsics())
    da = warprt.camera_rays(warprt.Scene(camera=a))[1]
    db = warprt.camera_rays(warprt.Scene(camera=b))[1]
    np.testing.assert_allclose(da, db, atol=4 * EPS32)


# --- the monotonic range: where undistortion stops, no ray -------------------------------------


def test_beyond_the_monotonic_range_no_ray_and_the_render_shows_background():
    """k1 = -0.6 alone: the radial map r (1 + k1 r²) grows up to r_max = 1/√(-3 k1) and folds
    back after; distorted radii beyond r_max (1 + k1 r_max²) have no preimage. Raster points
    inside that circle (by a margin of 1e-4 in radius) all get rays that round-trip; those
    outside get the direction (0, 0, 0); a render shows them as background (alpha 0, no depth)."""
    k1 = -0.6
    r_max = 1 / math.sqrt(-3 * k1)
    d_max = r_max * (1 + k1 * r_max**2)
    assert cm.distortion_limit("opencv", [k1, 0, 0, 0]) == pytest.approx((r_max, d_max), rel=1e-9)
    cam = _camera(model="opencv", distortion=(k1, 0.0, 0.0, 0.0), fx=40.0, fy=40.0, cx=31.5, cy=23.5)
    raster = _raster_grid(0.5)
    rd = np.hypot((raster[:, 0] - 32.0) / 40.0, (raster[:, 1] - 24.0) / 40.0)
    assert (rd < d_max * 0.97).sum() > 100 and (rd > d_max * 1.03).sum() > 100  # both kinds in view
    o, d = warprt.camera_rays(warprt.Scene(camera=cam), points=raster)
    valid = np.linalg.norm(d, axis=1) > 0.5
    inside, outside = rd < d_max * (1 - 1e-4), rd > d_max * (1 + 1e-4)
    assert valid[inside].all() and not valid[outside].any()
    # the valid ones near the fold still round-trip (Newton's method converges up to it)
    keep = valid & inside
    back = _project_cv(cam, (o + 2.0 * d)[keep].astype(np.float64), (k1, 0, 0, 0))
    assert np.abs(back - raster[keep]).max() < 1e-2  # (at the fold itself |J| → 0: loose)
    # a render: the pixels whose centres have no ray are background, the others see the wall
    scene = warprt.Scene(camera=cam, shapes=(warprt.Plane(point=(0, 0, -30), normal=tuple(-np.array(cam.basis()[2]))),),
                         lights=(), ambient=(1.0, 1.0, 1.0), background=(0.25, 0.5, 1.0)).with_settings(sampler="regular")
    jj, ii = np.mgrid[0:H, 0:W]
    rdc = np.hypot((ii + 0.5 - 32.0) / 40.0, (jj + 0.5 - 24.0) / 40.0)
    for packets in (True, False):  # (camera packets mark a miss by the lane's reach, one by one by the ray's)
        result = warprt.Renderer(scene, features=warprt.Features.full(), packets=packets).render(
            spp=1, aovs=["coverage"], progress=False)
        cov = result.aovs["coverage"]
        assert (cov[rdc > d_max * 1.001] == 0).all() and (cov[rdc < d_max * 0.999] == 1).all()
        out = result.image[rdc > d_max * 1.001]
        np.testing.assert_allclose(out, np.broadcast_to([0.25, 0.5, 1.0], out.shape), rtol=1e-6)


def test_a_pincushion_that_folds_back_keeps_its_rays_up_to_its_limit():
    """k1 = 1, k2 = -0.5: the radial map grows up to r_max = 1.21 and folds back there, at a
    distorted radius d_max = 1.69 beyond r_max, so raster points between the two lie beyond the
    monotonic range's undistorted radius yet have a ray (the one inside it). Every raster point up
    to d_max (1 - 1e-4) gets it, and it round-trips through cv2 to the float32 tolerance; none
    beyond d_max (1 + 1e-4) has one."""
    dist = (1.0, -0.5, 0.0, 0.0)
    r_max, d_max = cm.distortion_limit("opencv", dist)
    assert d_max > 1.3 * r_max
    f = 20.0
    cam = _camera(model="opencv", distortion=dist, fx=f, fy=f, cx=31.5, cy=23.5)
    rng = np.random.default_rng(9)
    rd = d_max * np.sqrt(rng.uniform(0, 1, 4000)) * (1 - 1e-4)
    ang = rng.uniform(0, 2 * np.pi, len(rd))
    raster = np.stack([32 + f * rd * np.cos(ang), 24 + f * rd * np.sin(ang)], 1)
    assert (rd > r_max).mean() > 0.3
    o, d = warprt.camera_rays(warprt.Scene(camera=cam), points=raster)
    assert (np.linalg.norm(d, axis=1) > 0.999).all()
    back = _project_cv(cam, (o + 2.0 * d).astype(np.float64), dist)
    _, _, R = _cv_pose(cam)
    pc = (R @ d.astype(np.float64).T).T
    tol = ROUND_TRIP_ULPS * EPS32 * _pixel_scale(cam, raster, dist, und=pc[:, :2] / pc[:, 2:])
    assert (np.abs(back - raster).max(axis=1) <= tol).all()
    outside = np.stack([32 + f * d_max * (1 + 1e-4) * np.cos(ang), 24 + f * d_max * (1 + 1e-4) * np.sin(ang)], 1)
    assert (np.linalg.norm(warprt.camera_rays(warprt.Scene(camera=cam), points=outside)[1], axis=1) == 0).all()


def test_monotonic_range_against_closed_forms_and_a_dense_scan():
    """``distortion_limit``: r / (1 + k4 r²) peaks at r = 1/√k4 with 1/(2√k4) (the rational
    denominator alone); 1 - r² in the denominator (k4 = -1) is a pole at r = 1 where the map
    grows without bound; a model monotonic everywhere has no limit; and for the full 12-term
    calibrations the limit is where a dense scan of the float64 map first stops growing."""
    k4 = 2.5
    assert cm.distortion_limit("opencv", [0, 0, 0, 0, 0, k4, 0, 0]) == pytest.approx((1 / math.sqrt(k4),
                                                                                     0.5 / math.sqrt(k4)), rel=1e-9)
    r_max, d_max = cm.distortion_limit("opencv", [0, 0, 0, 0, 0, -1.0, 0, 0])
    assert r_max == pytest.approx(1.0, rel=1e-9) and d_max > 1e6
    assert cm.distortion_limit("opencv", [0.1, 0.01, 0, 0]) == (cm.NO_LIMIT, cm.NO_LIMIT)
    for coeffs in ((0.3, -0.4, 0.0, 0.0, 0.05, 0.45, -0.05, 0.02), (0.2, -0.3, 0.001, 0.0, 0.02, 0.1, 0.2, -0.01),
                   (-0.35, 0.12, 0.002, -0.001, -0.02, 0.0, 0.01, 0.0, 0.004, -0.001, -0.003, 0.0008)):
        c = np.zeros(12)
        c[:len(coeffs)] = coeffs
        k1, k2, _, _, k3, k4, k5, k6 = c[:8]
        r = np.linspace(0, 6, 3_000_001)
        g = r * (1 + k1 * r**2 + k2 * r**4 + k3 * r**6) / (1 + k4 * r**2 + k5 * r**4 + k6 * r**6)
        first = int(np.argmax(np.diff(g) <= 0))
        assert first > 0
        assert cm.distortion_limit("opencv", coeffs)[0] == pytest.approx(r[first], abs=4e-6)


def test_a_pixel_without_a_ray_meets_no_shape_of_any_kind():
    """The direction (0, 0, 0) of a pixel without a ray is a miss for every intersector (spheres,
    planes, rectangles, disks, boxes, capsules, cylinders, meshes), even with the eye inside or on
    them, in packets and one by one: those pixels are background; the others all hit (the eye is
    inside a sphere)."""
    import trimesh

    cam = _camera(model="opencv", distortion=(-0.6, 0.0, 0.0, 0.0), fx=40.0, fy=40.0, cx=31.5, cy=23.5)
    eye = np.asarray(cam.eye)
    tm = trimesh.creation.box((1.0, 1.0, 1.0))
    shapes = (warprt.Sphere(center=tuple(eye + 0.3), radius=40.0), warprt.Plane(point=tuple(eye), normal=(0, 1, 0)),
              warprt.Rectangle(corner=tuple(eye - 0.5), edge1=(1, 0, 0), edge2=(0, 1, 0)),
              warprt.Disk(center=tuple(eye), normal=(0, 0, 1), radius=0.5),
              warprt.Box(center=tuple(eye), size=(1, 1, 1)), warprt.Capsule(start=tuple(eye - 0.2), end=tuple(eye + 0.2)),
              warprt.Cylinder(start=tuple(eye - 0.2), end=tuple(eye + 0.2), radius=0.3),
              warprt.Mesh(vertices=np.asarray(tm.vertices) + eye, faces=np.asarray(tm.faces)))
    scene = warprt.Scene(camera=cam, shapes=shapes, lights=(), ambient=(1.0, 1.0, 1.0),
                         background=(0.25, 0.5, 1.0)).with_settings(sampler="regular")
    r_max, d_max = cm.distortion_limit("opencv", [-0.6, 0, 0, 0])
    jj, ii = np.mgrid[0:H, 0:W]
    rdc = np.hypot((ii + 0.5 - 32.0) / 40.0, (jj + 0.5 - 24.0) / 40.0)
    for packets in (True, False):
        result = warprt.Renderer(scene, features=warprt.Features.full(), packets=packets).render(
            spp=1, aovs=["coverage"], progress=False)
        cov = result.aovs["coverage"]
        assert (cov[rdc > d_max * 1.001] == 0).all() and (cov[rdc < d_max * 0.999] == 1).all()
        out = result.image[rdc > d_max * 1.001]
        np.testing.assert_array_equal(out, np.broadcast_to(np.float32([0.25, 0.5, 1.0]), out.shape))


# --- fisheye ----------------------------------------------------------------------------------

FISHEYE = dict(fx=18.0, fy=18.5, cx=31.7, cy=23.2)
FISHEYE_K = (0.08, -0.02, 0.004, -0.0003)


def test_fisheye_rays_round_trip_through_cv2_fisheye_project_points():
    """OpenCV's fisheye model: raster points within 90° of the axis (cv2.fisheye goes through
    x / z and stops there) round-trip through cv2.fisheye.projectPoints; beyond 90° (up to the
    model's limit) through the closed form θd = θ (1 + k1 θ² + k2 θ⁴ + k3 θ⁶ + k4 θ⁸)."""
    cam = _camera(model="fisheye", distortion=FISHEYE_K, **FISHEYE)
    raster = _raster_grid(0.5)
    o, d = warprt.camera_rays(warprt.Scene(camera=cam), points=raster)
    assert (np.linalg.norm(d, axis=1) > 0.999).all()
    _, _, R = _cv_pose(cam)
    pc = (R @ d.astype(np.float64).T).T  # camera space
    theta = np.arctan2(np.hypot(pc[:, 0], pc[:, 1]), pc[:, 2])
    front = theta < math.radians(85)
    assert front.sum() > 500 and (~front).sum() > 500  # both in view: the image spans > 180°
    back = _project_cv(cam, (o + 3.0 * d)[front].astype(np.float64), FISHEYE_K, fisheye=True)
    tol = ROUND_TRIP_ULPS * EPS32 * _pixel_scale(cam, raster[front], FISHEYE_K, fisheye=True)
    assert (np.abs(back - raster[front]).max(axis=1) <= tol).all()
    k1, k2, k3, k4 = FISHEYE_K
    t = theta[~front]
    td = t * (1 + k1 * t**2 + k2 * t**4 + k3 * t**6 + k4 * t**8)
    rho = np.hypot(pc[~front, 0], pc[~front, 1])
    closed = np.stack([cam.fx * td * pc[~front, 0] / rho + cam.cx, cam.fy * td * pc[~front, 1] / rho + cam.cy], 1) + 0.5
    tol = ROUND_TRIP_ULPS * EPS32 * _pixel_scale(cam, raster[~front], FISHEYE_K, fisheye=True)
    assert (np.abs(closed - raster[~front]).max(axis=1) <= tol).all()


def test_fisheye_project_equals_cv2_fisheye_project_points():
    cam = _camera(model="fisheye", distortion=FISHEYE_K, **FISHEYE)
    pts = _world_points(cam, 400, np.random.default_rng(5), 3.0).astype(np.float32).astype(np.float64)
    got = _project(cam, pts)
    want = _project_cv(cam, pts, FISHEYE_K, fisheye=True)
    tol = ROUND_TRIP_ULPS * EPS32 * _pixel_scale(cam, want, FISHEYE_K, fisheye=True)
    assert (np.abs(got - want).max(axis=1) <= tol).all()


def test_fisheye_limit_past_its_monotonic_angle_no_ray():
    """k1 = -0.2 alone: θ (1 + k1 θ²) grows up to θ_max = 1/√(-3 k1) (74.5°): raster points
    whose distorted radius exceeds θ_max (1 + k1 θ_max²) get no ray, those inside do."""
    k1 = -0.2
    t_max = 1 / math.sqrt(-3 * k1)
    d_max = t_max * (1 + k1 * t_max**2)
    assert cm.distortion_limit("fisheye", [k1, 0, 0, 0]) == pytest.approx((t_max, d_max), rel=1e-9)
    cam = _camera(model="fisheye", distortion=(k1, 0, 0, 0), fx=30.0, fy=30.0, cx=31.5, cy=23.5)
    raster = _raster_grid(0.5)
    rd = np.hypot((raster[:, 0] - 32.0) / 30.0, (raster[:, 1] - 24.0) / 30.0)
    valid = np.linalg.norm(warprt.camera_rays(warprt.Scene(camera=cam), points=raster)[1], axis=1) > 0.5
    assert valid[rd < d_max * (1 - 1e-5)].all() and not valid[rd > d_max * (1 + 1e-5)].any()
    assert (rd > d_max * 1.1).sum() > 100


# --- orthographic ----------------------------------------------------------------------------


def test_orthographic_rays_and_projection_follow_the_closed_form():
    """Raster point (x, y) starts at eye + ((x - 0.5 - cx) / fx) u - ((y - 0.5 - cy) / fy) v
    and runs along -w; ``project`` is its inverse: ((p - eye)·u fx + cx + 0.5, -(p - eye)·v fy +
    cy + 0.5)."""
    cam = _camera(model="orthographic", fx=20.0, fy=16.0, cx=30.2, cy=25.1)
    u, v, w = cam.basis(0.0)
    raster = _raster_grid(0.5)
    o, d = warprt.camera_rays(warprt.Scene(camera=cam), points=raster)
    xn = (raster[:, 0] - 0.5 - cam.cx) / cam.fx
    yn = (raster[:, 1] - 0.5 - cam.cy) / cam.fy
    want_o = np.asarray(cam.eye) + xn[:, None] * u - yn[:, None] * v
    np.testing.assert_allclose(o, want_o, atol=8 * EPS32 * np.abs(want_o).max())
    np.testing.assert_allclose(d, np.tile(-w, (len(raster), 1)), atol=4 * EPS32)
    pts = (want_o - 2.5 * w).astype(np.float32).astype(np.float64)
    got = _project(cam, pts)
    q = pts - np.asarray(cam.eye)
    want = np.stack([q @ u * cam.fx + cam.cx + 0.5, -(q @ v) * cam.fy + cam.cy + 0.5], 1)
    assert np.abs(got - want).max() <= 8 * EPS32 * np.abs(want).max()
    np.testing.assert_allclose(got, raster, atol=16 * EPS32 * W)


# --- a render: where a sphere lands in a distorted image ----------------------------------------


def test_a_sphere_in_a_distorted_render_covers_the_pixels_cv2_undistorts_onto_it():
    """A sphere seen through the barrel distortion: at one centred sample per pixel, pixel (i, j)
    is covered exactly when the ray through OpenCV's undistortion of its centre (cv2.undistortPoints,
    float64, independent of warprt's float32 Newton iteration) meets the sphere; pixels within
    1e-4 radians of the silhouette are left out."""
    dist = (-0.35, 0.12, 0.002, -0.001, -0.02)
    cam = _camera(model="opencv", distortion=dist, **K_OPENCV)
    _, _, R = _cv_pose(cam)
    centre = np.asarray(cam.eye) + R.T @ np.array([0.25, -0.1, 2.5])
    radius = 0.9
    scene = warprt.Scene(camera=cam, shapes=(warprt.Sphere(center=tuple(centre), radius=radius),),
                         lights=()).with_settings(sampler="regular")
    cov = _render(scene, "coverage")
    jj, ii = np.mgrid[0:H, 0:W]
    pix = np.stack([ii.ravel(), jj.ravel()], 1).astype(np.float64)  # OpenCV's pixel centres
    und = _undistort_cv(pix, cam.camera_matrix(), dist)
    rays = R.T @ np.concatenate([und, np.ones((len(und), 1))], 1).T
    rays = (rays / np.linalg.norm(rays, axis=0)).T
    c = centre - np.asarray(cam.eye)
    along = rays @ c
    miss = np.sqrt(np.maximum(c @ c - along**2, 0.0)) - radius  # the ray's distance from the sphere
    angle = miss / np.linalg.norm(c)
    sure = np.abs(angle) > 1e-4
    want = (miss < 0).reshape(H, W)
    assert want.sum() > 100 and (~want).sum() > 100
    assert (cov.ravel()[sure] == want.ravel()[sure]).all()
    # the undistorted pinhole's coverage differs: the distortion is what the test sees
    plain = _render(scene.replace(camera=_camera(**K_OPENCV)), "coverage")
    assert (plain.ravel()[sure] != want.ravel()[sure]).sum() > 20


# --- rolling shutter -------------------------------------------------------------------------


def test_rolling_shutter_shears_a_moving_edge_along_the_closed_form_line():
    """A box moving along +x at speed s seen by a pinhole at rest with an instantaneous shutter
    (open = close = t0) and line delay δ: row j sees it at time t0 + j δ, so its left edge (at
    depth Z, x = x0 + s t) is at raster column cx + 0.5 + fx (x0 + s (t0 + j δ)) / Z: a line in
    j of slope fx s δ / Z. A pixel centre is covered exactly when it lies right of that line."""
    fx, cx, cy = 40.0, 31.5, 23.5
    cam = warprt.Camera(eye=(0, 0, 0), look_at=(0, 0, -1), up=(0, 1, 0), width=W, height=H, fx=fx, cx=cx, cy=cy,
                        shutter=(0.1, 0.1), rolling_shutter=0.015)
    Z, x0, speed = 5.0, -3.0, 3.0  # (the edge stays left of the eye: the box's side face is never in view)
    # the box's left face at x = x0 at time 0 (its centre 10 to the right: the right face out of view)
    box = warprt.Box(size=(20.0, 10.0, 1.0), transform=warprt.Transform(translate=(x0 + 10.0, 0, -Z - 0.5)),
                     transform_end=warprt.Transform(translate=(x0 + 10.0 + speed, 0, -Z - 0.5)))
    scene = warprt.Scene(camera=cam, shapes=(box,), lights=()).with_settings(sampler="regular")
    cov = _render(scene, "coverage")
    j = np.arange(H)
    edge = cx + 0.5 + fx * (x0 + speed * (0.1 + j * 0.015)) / Z  # raster column of the edge in row j
    centres = np.arange(W) + 0.5
    want = centres[None, :] > edge[:, None]
    sure = np.abs(centres[None, :] - edge[:, None]) > 1e-3
    assert (cov[sure] == want[sure]).all()
    # the edge really moves: 16.8 columns from the top row to the bottom one
    assert edge[-1] - edge[0] == pytest.approx(fx * speed * 0.015 * (H - 1) / Z)
    assert edge[-1] - edge[0] > 10
    # without the line delay every row sees time 0.1: a vertical edge
    flat = _render(scene.replace(camera=warprt.Camera(**{**_fields(cam), "rolling_shutter": 0.0})), "coverage")
    assert (flat == flat[:1]).all()


def _render(scene, aov: str) -> np.ndarray:
    """One centred sample per pixel through the general kernel (every feature: no kernel variant
    of its own to compile), AOV ``aov``."""
    return warprt.Renderer(scene, features=warprt.Features.full()).render(spp=1, aovs=[aov], progress=False).aovs[aov]


def _fields(cam):
    import dataclasses

    return {f.name: getattr(cam, f.name) for f in dataclasses.fields(cam)}


# --- bad input ---------------------------------------------------------------------------------


@pytest.mark.parametrize("kw, field, words", [
    (dict(model="opencv", fx=50, distortion=(0.1, 0.2, 0.3)), "distortion", "4, 5, 8 or 12"),
    (dict(model="opencv", fx=50, distortion=tuple(range(14))), "distortion", "tilted"),
    (dict(model="fisheye", fx=50, distortion=(0.1, 0.2)), "distortion", "4 coefficients"),
    (dict(model="pinhole", fx=50, distortion=(0.1, 0.2, 0.0, 0.0)), "distortion", "no distortion"),
    (dict(fx=0.0), "fx", "> 0"),
    (dict(fx=-5.0), "fx", "> 0"),
    (dict(fx=50, fy=0.0), "fy", "> 0"),
    (dict(fx=50, cx=float("nan")), "cx", "finite"),
    (dict(fy=50), "fy", "without fx"),
    (dict(fx=50, fov=40), "fov", "not both"),
    (dict(model="fisheye"), "fx", "needs fx"),
    (dict(model="orthographic"), "fx", "needs fx"),
    (dict(model="fisheye", fx=20, aperture=0.1), "aperture", "thin lens"),
    (dict(model="kannala"), "model", "one of"),
    (dict(rolling_shutter=-1.0), "rolling_shutter", ">= 0"),
    (dict(rolling_shutter=0.01), "rolling_shutter", "after time 1"),
])
def test_bad_camera_input_names_the_field(kw, field, words):
    with pytest.raises(warprt.SceneError) as e:
        warprt.Camera(width=W, height=H, **kw)
    assert e.value.field == field
    assert words in str(e.value)


def test_toml_and_python_take_the_same_fields():
    """``[camera]`` in a scene file takes the Python fields by the same names."""
    text = """
[camera]
eye = [0.4, 1.2, 3.0]
look_at = [-0.3, 0.1, -1.0]
width = 64
height = 48
model = "opencv"
fx = 52.0
fy = 53.5
cx = 31.3
cy = 24.6
distortion = [-0.28, 0.07, 0.0012, -0.0009, -0.008]
rolling_shutter = 0.0
"""
    cam = warprt.scene_from_string(text).camera
    assert cam == warprt.Camera(eye=(0.4, 1.2, 3.0), look_at=(-0.3, 0.1, -1.0), width=64, height=48, model="opencv",
                                fx=52.0, fy=53.5, cx=31.3, cy=24.6, distortion=DISTORTIONS["barrel 5"])
    np.testing.assert_array_equal(cam.dist_coeffs()[:5], DISTORTIONS["barrel 5"])


# --- batches: each camera its own model --------------------------------------------------------


def test_a_batch_renders_each_camera_with_its_own_model_as_a_single_render_does():
    """``BatchRenderer(scene, cameras=[...])``: an intrinsics pinhole, an OpenCV-distorted camera,
    a fisheye and an orthographic camera in one batch; each frame's depth equals the single
    render's through that camera (the batch's pose goes through a float32 quaternion: the depths
    agree to 1e-5 relative, and at most a few silhouette pixels see another surface or none)."""
    cams = [_camera(**K_OPENCV), _camera(model="opencv", distortion=DISTORTIONS["thin prism 12"], **K_OPENCV),
            _camera(model="fisheye", distortion=FISHEYE_K, **FISHEYE),
            _camera(model="orthographic", fx=12.0, fy=12.0, cx=30.0, cy=22.0)]
    scene = warprt.Scene(camera=cams[0], shapes=(warprt.Sphere(center=(0.0, 0.3, -0.5), radius=1.2),
                                                 warprt.Sphere(center=(-0.5, 1.6, 1.0), radius=0.3)),
                         lights=()).with_settings(sampler="regular")
    batch = warprt.BatchRenderer(scene, worlds=1, cameras=cams, device="cpu", features=warprt.Features.full())
    out = batch.render(spp=1, aovs=["depth"])
    for c, cam in enumerate(cams):
        got = out.frame(0, c).aovs["depth"]
        want = _render(scene.replace(camera=cam), "depth")
        hit, hit_want = np.isfinite(got), np.isfinite(want)
        assert 0.04 * W * H < hit.sum() < 0.95 * W * H, cam.model  # spheres and background in view
        both = hit & hit_want
        # (measured: 3.6e-6 relative at most, at the silhouettes)
        differ = ~np.isclose(got[both], want[both], rtol=1e-5, atol=0)
        assert differ.sum() + (hit != hit_want).sum() <= 3, (cam.model, differ.sum(), (hit != hit_want).sum())
    first = [out.frame(0, c).aovs["depth"] for c in range(len(cams))]  # (copies: the next render reuses the buffers)
    # the models really differ: no two frames alike
    assert all(not np.array_equal(first[a], first[b]) for a in range(4) for b in range(a))
    # set_cameras swaps them without a rebuild
    batch.set_cameras(cams[::-1])
    again = batch.render(spp=1, aovs=["depth"])
    for c in range(4):
        np.testing.assert_array_equal(again.frame(0, 3 - c).aovs["depth"], first[c])
    assert batch.counters["rebuilds"] == (2 if batch.bvh is not None else 1)


# --- Newton's SensorCamera: the same rays from its own kernels -----------------------------------


def test_newton_sensor_camera_rays_equal_warprt_s_with_its_conventions():
    """Newton 1.8's ``SensorCamera`` ray bundles (camera space: x right, y up, looking along -z)
    against warprt's camera at the origin looking along -z: its film form (focal length,
    apertures, offsets) through ``Camera.from_aperture``, and its OpenCV pinhole, whose cx, cy
    count pixel centres at i + 0.5 (OpenCV's + 0.5), to Newton's own undistortion's tolerance
    (its acceptance is 2e-5 in normalised coordinates)."""
    pytest.importorskip("newton")
    from newton.sensors import SensorCamera

    w, h = 16, 12
    pose = dict(eye=(0, 0, 0), look_at=(0, 0, -1), up=(0, 1, 0), width=w, height=h)
    film = dict(focal_length=2.0, horizontal_aperture=3.0, vertical_aperture=2.4, horizontal_aperture_offset=0.1,
                vertical_aperture_offset=0.2)
    theirs = SensorCamera.compute_camera_rays_pinhole(w, h, **film, device="cpu").numpy()[:, :, 0, 1].reshape(-1, 3)
    ours = warprt.camera_rays(warprt.Scene(camera=warprt.Camera.from_aperture(**film, **pose)))[1]
    np.testing.assert_allclose(ours, theirs, atol=8 * EPS32)
    fx, fy, cx, cy = 11.0, 11.5, 7.2, 5.9
    dist = dict(k1=-0.12, k2=0.02, p1=0.001, p2=-0.002, k3=0.001, k4=0.05, s1=0.001, s3=-0.002)
    theirs = SensorCamera.compute_camera_rays_pinhole_opencv(w, h, fx, fy, cx + 0.5, cy + 0.5, **dist,
                                                            device="cpu").numpy()[:, :, 0, 1].reshape(-1, 3)
    coeffs = [dist.get(k, 0.0) for k in ("k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6", "s1", "s2", "s3", "s4")]
    cam = warprt.Camera(model="opencv", fx=fx, fy=fy, cx=cx, cy=cy, distortion=coeffs, **pose)
    ours = warprt.camera_rays(warprt.Scene(camera=cam))[1]
    both = (np.linalg.norm(theirs, axis=1) > 0.5) & (np.linalg.norm(ours, axis=1) > 0.5)
    assert both.mean() > 0.9
    np.testing.assert_allclose(ours[both], theirs[both], atol=4e-5)


def test_left_out_intrinsics_follow_the_image():
    """fy left out is fx; cx, cy left out are the image centre at the camera's present size (a
    resized copy stays centred); fov left out is 45 degrees unless fx is given."""
    import dataclasses

    cam = warprt.Camera(fx=50.0, width=64, height=48)
    assert cam.intrinsics() == (50.0, 50.0, 31.5, 23.5) and cam.fov is None
    assert dataclasses.replace(cam, width=32).intrinsics() == (50.0, 50.0, 15.5, 23.5)
    assert warprt.Camera(width=64, height=48).fov == 45.0


def test_a_distorted_thin_lens_focuses_each_pixel_where_its_pinhole_ray_meets_the_plane_of_focus():
    """The opencv model with a thin lens: a pixel's rays from every lens point meet where its
    distorted pinhole ray (aperture 0) crosses the plane of focus, ``focus_distance`` along -w."""
    dist = DISTORTIONS["barrel 5"]
    lensed = _camera(model="opencv", distortion=dist, aperture=0.2, focus_distance=3.0, **K_OPENCV)
    pinhole = _camera(model="opencv", distortion=dist, **K_OPENCV)
    w = np.asarray(lensed.basis()[2])
    rng = np.random.default_rng(4)
    raster = np.repeat(rng.uniform(0, [W, H], (20, 2)), 16, axis=0)
    lens = rng.uniform(0, 1, (len(raster), 2))
    o, d = warprt.camera_rays(warprt.Scene(camera=lensed), points=raster, lens=lens)
    o0, d0 = warprt.camera_rays(warprt.Scene(camera=pinhole), points=raster)
    focus = o0 + d0 * (3.0 / (d0 @ -w))[:, None]  # the pinhole ray at depth 3 along the axis
    t = ((focus - o) @ -w) / (d @ -w)
    hit = o + d * t[:, None]
    np.testing.assert_allclose(hit, focus, atol=8 * EPS32 * 3.0)  # (measured: 2.1 roundoffs of the depth at most)
    assert np.linalg.norm(o - o0, axis=1).max() > 0.1  # the origins spread over the lens
