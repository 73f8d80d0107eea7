"""Camera rays against the lecture's witness-point formula, computed independently in numpy.

For raster point (x, y) (pixels, y down from the top) the witness point is
s = eye + us·u + vs·v - D·w with w = normalize(eye - look_at), u = normalize(up × w), v = w × u,
top = D·tan(fov/2), right = top·W/H, us = -right + 2·right·x/W, vs = top - 2·top·y/H; the pinhole
ray runs from the eye through s. A thin lens of radius a starts the ray on the lens disk
eye + a·(lx·u + ly·v) and aims it at the point where the pinhole ray meets the plane of focus.

Tolerances: directions are float32 unit vectors, compared with a float64 reference to 2e-6 per
component (a few float32 ulps); origins to 1e-6 relative to the scene's coordinates.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

import warprt
from warprt._warp import MODULE_OPTIONS

DIR_TOL = 2e-6


def frame(eye, look_at, up):
    eye, look_at, up = (np.asarray(a, np.float64) for a in (eye, look_at, up))
    w = eye - look_at
    w /= np.linalg.norm(w)
    u = np.cross(up, w)
    u /= np.linalg.norm(u)
    v = np.cross(w, u)
    return u, v, w


def witness(eye, look_at, up, fov, width, height, dist, points):
    """Witness points (N, 3) for raster points (N, 2), float64."""
    u, v, w = frame(eye, look_at, up)
    top = dist * math.tan(math.radians(fov) / 2.0)
    right = top * width / height
    x, y = points[:, 0:1].astype(np.float64), points[:, 1:2].astype(np.float64)
    us = -right + 2.0 * right * x / width
    vs = top - 2.0 * top * y / height
    return np.asarray(eye, np.float64) + us * u + vs * v - dist * w


def pixel_centres(width, height):
    """Row-major (i + 0.5, j + 0.5), row j = 0 at the top: independent of warprt."""
    pts = [(i + 0.5, j + 0.5) for j in range(height) for i in range(width)]
    return np.array(pts, np.float64)


def unit(a):
    return a / np.linalg.norm(a, axis=-1, keepdims=True)


CAMERAS = [
    # eye, look_at, up, fov, width, height
    ((0.0, 0.0, 5.0), (0.0, 0.0, 0.0), (0.0, 1.0, 0.0), 45.0, 7, 5),
    ((3.0, -2.0, 1.5), (-1.0, 0.5, 2.0), (0.2, 0.3, 1.0), 70.0, 5, 9),
    ((-4.0, 6.0, -3.0), (2.0, -1.0, 0.5), (1.0, 1.0, 0.0), 20.0, 13, 3),
    ((100.0, 50.0, -20.0), (101.0, 49.0, -19.5), (0.0, 0.0, 1.0), 120.0, 4, 4),
]


@pytest.mark.parametrize("eye, look_at, up, fov, width, height", CAMERAS)
def test_pixel_centre_rays_follow_the_witness_point_formula(eye, look_at, up, fov, width, height):
    scene = warprt.Scene(camera=warprt.Camera(eye=eye, look_at=look_at, up=up, fov=fov, width=width, height=height))
    o, d = warprt.camera_rays(scene)
    assert o.shape == d.shape == (width * height, 3)
    s = witness(eye, look_at, up, fov, width, height, 1.0, pixel_centres(width, height))
    expected = unit(s - np.asarray(eye))
    np.testing.assert_allclose(o, np.broadcast_to(eye, o.shape), rtol=1e-6, atol=1e-6)
    np.testing.assert_allclose(d, expected, rtol=0, atol=DIR_TOL)
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0, atol=1e-6)


@pytest.mark.parametrize("dist", [0.01, 1.0, 3.7, 250.0])
def test_image_plane_distance_does_not_change_directions(dist):
    eye, look_at, up, fov, width, height = CAMERAS[1]
    cam = warprt.Camera(eye=eye, look_at=look_at, up=up, fov=fov, width=width, height=height, distance=dist)
    _, d = warprt.camera_rays(warprt.Scene(camera=cam))
    s = witness(eye, look_at, up, fov, width, height, dist, pixel_centres(width, height))
    np.testing.assert_allclose(d, unit(s - np.asarray(eye)), atol=DIR_TOL)
    # and the same as for D = 1
    s1 = witness(eye, look_at, up, fov, width, height, 1.0, pixel_centres(width, height))
    np.testing.assert_allclose(d, unit(s1 - np.asarray(eye)), atol=DIR_TOL)


def test_row_zero_is_the_top_and_column_zero_the_left():
    """Looking down -z with up = +y: u = +x, v = +y. Pixel (0, 0) looks up-left, the last pixel
    down-right; the centre of an odd image looks straight ahead."""
    w, h = 5, 3
    scene = warprt.Scene(camera=warprt.Camera(eye=(0, 0, 0), look_at=(0, 0, -1), fov=60, width=w, height=h))
    _, d = warprt.camera_rays(scene)
    d = d.reshape(h, w, 3)
    assert d[0, 0, 0] < 0 and d[0, 0, 1] > 0
    assert d[-1, -1, 0] > 0 and d[-1, -1, 1] < 0
    np.testing.assert_allclose(d[1, 2], [0, 0, -1], atol=1e-7)
    # x grows with the column, y falls with the row
    assert np.all(np.diff(d[:, :, 0], axis=1) > 0)
    assert np.all(np.diff(d[:, :, 1], axis=0) < 0)
    # the top-left corner point (0, 0) of the raster lies at (-right, top, -1)
    top = math.tan(math.radians(30.0))
    _, c = warprt.camera_rays(scene, points=[[0.0, 0.0], [w, h]])
    np.testing.assert_allclose(c[0], unit(np.array([-top * w / h, top, -1.0])), atol=DIR_TOL)
    np.testing.assert_allclose(c[1], unit(np.array([top * w / h, -top, -1.0])), atol=DIR_TOL)


def test_pixel_centres_use_half_pixel_offsets():
    """The default rays equal the rays through explicit points (i + 0.5, j + 0.5), and differ from
    rays through the pixel corners (i, j)."""
    cam = warprt.Camera(eye=(1, 2, 3), look_at=(0, 0, 0), width=6, height=4, fov=50)
    scene = warprt.Scene(camera=cam)
    _, d = warprt.camera_rays(scene)
    jj, ii = np.mgrid[0:4, 0:6]
    _, d_centres = warprt.camera_rays(scene, points=np.stack([ii.ravel() + 0.5, jj.ravel() + 0.5], 1))
    _, d_corners = warprt.camera_rays(scene, points=np.stack([ii.ravel(), jj.ravel()], 1).astype(float))
    np.testing.assert_array_equal(d, d_centres)
    assert np.abs(d - d_corners).max() > 1e-2


def test_arbitrary_raster_points_match_the_formula():
    eye, look_at, up, fov, width, height = CAMERAS[2]
    cam = warprt.Camera(eye=eye, look_at=look_at, up=up, fov=fov, width=width, height=height, distance=2.5)
    rng = np.random.default_rng(3)
    pts = rng.uniform([-2.0, -1.0], [width + 2.0, height + 1.0], (200, 2)).astype(np.float32)
    _, d = warprt.camera_rays(warprt.Scene(camera=cam), points=pts)
    s = witness(eye, look_at, up, fov, width, height, 2.5, pts.astype(np.float64))
    np.testing.assert_allclose(d, unit(s - np.asarray(eye)), atol=DIR_TOL)


@pytest.mark.parametrize("aperture, focus", [(0.25, None), (0.05, 12.0), (1.5, 0.8)])
def test_thin_lens_rays_meet_at_one_focus_point(aperture, focus):
    eye, look_at, up = (2.0, 1.0, 6.0), (0.0, 0.5, 0.0), (0.0, 1.0, 0.0)
    width, height, fov = 8, 6, 40.0
    cam = warprt.Camera(eye=eye, look_at=look_at, up=up, fov=fov, width=width, height=height,
                        aperture=aperture, focus_distance=focus, distance=1.7)
    scene = warprt.Scene(camera=cam)
    f = focus if focus is not None else float(np.linalg.norm(np.subtract(look_at, eye)))
    u, v, w = frame(eye, look_at, up)
    rng = np.random.default_rng(11)
    for px in [(0.5, 0.5), (3.5, 2.5), (7.5, 5.5), (1.25, 4.75)]:
        n = 64
        pts = np.tile(np.array(px, np.float32), (n, 1))
        lens = rng.uniform(0, 1, (n, 2)).astype(np.float32)
        o, d = warprt.camera_rays(scene, points=pts, lens=lens)
        # the focus point: where the pinhole ray through the witness point meets the plane of focus
        s = witness(eye, look_at, up, fov, width, height, 1.7, np.array([px], np.float64))[0]
        pin = s - np.asarray(eye)
        focus_point = np.asarray(eye) + pin * (f / 1.7)
        # origins lie on the lens disk: in the (u, v) plane through the eye, within the aperture
        rel = o.astype(np.float64) - np.asarray(eye)
        np.testing.assert_allclose(rel @ w, 0.0, atol=1e-5)
        radius = np.hypot(rel @ u, rel @ v)
        assert radius.max() <= aperture * (1 + 1e-5)
        assert radius.max() > 0.3 * aperture  # the samples really spread over the lens
        # every ray passes through the focus point: distance from the point to the line
        to_fp = focus_point - o
        along = np.sum(to_fp * d, axis=1)
        assert np.all(along > 0)
        miss = np.linalg.norm(to_fp - along[:, None] * d, axis=1)
        assert miss.max() < 2e-5 * max(1.0, np.linalg.norm(focus_point))
        # and the plane of focus is at distance f along -w from the eye
        np.testing.assert_allclose((focus_point - np.asarray(eye)) @ (-w), f, rtol=1e-9)


def test_zero_aperture_ignores_the_lens_samples():
    cam = warprt.Camera(eye=(0, 1, 4), look_at=(0, 0, 0), width=4, height=4)
    scene = warprt.Scene(camera=cam)
    o0, d0 = warprt.camera_rays(scene)
    rng = np.random.default_rng(0)
    o1, d1 = warprt.camera_rays(scene, lens=rng.uniform(0, 1, (16, 2)))
    np.testing.assert_array_equal(o0, o1)
    np.testing.assert_array_equal(d0, d1)


def _random_cameras(rng, n: int, eye_exp: float, look_exp: float, lens: bool = False) -> list:
    """n random cameras' device records: eyes up to 10^eye_exp from the origin, look-at points up
    to 10^look_exp from the eye, tilted up vectors, 5-150° fields of view (or, for 30% of them,
    intrinsics with fx ≠ fy and the principal point off centre), images of 1-399 pixels a side,
    image planes at 0.01-100; with ``lens``, apertures 1e-4-3.2 and focus distances 0.1-100."""
    from warprt import camera as cm

    cams = []
    for _ in range(n):
        eye = rng.normal(0, 1, 3) * 10.0 ** rng.uniform(-1, eye_exp)
        look = eye + rng.normal(0, 1, 3) * 10.0 ** rng.uniform(-1, look_exp)
        optics = {}
        kw = dict(eye=tuple(eye), look_at=tuple(look), up=tuple(rng.normal(0, 1, 3)), fov=float(rng.uniform(5, 150)),
                  width=int(rng.integers(1, 400)), height=int(rng.integers(1, 400)),
                  distance=float(10.0 ** rng.uniform(-2, 2)))
        if rng.random() < 0.3:  # intrinsics: focal lengths apart, the principal point off centre
            f = kw["height"] / (2 * math.tan(math.radians(kw.pop("fov")) / 2))
            kw.update(fx=f * rng.uniform(0.8, 1.25), fy=f, cx=rng.uniform(-0.2, 1.2) * kw["width"],
                      cy=rng.uniform(-0.2, 1.2) * kw["height"])
        if lens:
            optics = dict(aperture=float(10.0 ** rng.uniform(-4, 0.5)), focus_distance=float(10.0 ** rng.uniform(-1, 2)))
        scene = warprt.Scene(camera=warprt.Camera(**kw, **optics), shapes=(warprt.Sphere(center=(0, 0, 0), radius=1.0),),
                             lights=())
        cams.append(cm.camera_data(scene))
    return cams


def test_a_packets_directions_equal_camera_ray_lane_by_lane(device):
    """``camera.camera_packet`` (a camera packet's 8 pinhole directions at once, in the frame
    ``camera_frame`` gives), as clang vectors and lane by lane (its CUDA branch, compiled here on
    the CPU), equals ``camera_ray`` for each lane bit for bit: random cameras (narrow to wide
    fields of view, tilted up vectors, far eyes, non-square images, image planes near and far)
    and raster points over the
    whole image, its corners and edges included."""
    import warp as wp

    from warprt import camera as cm

    rng = np.random.default_rng(21)
    n = 512
    cams = _random_cameras(rng, n, eye_exp=3, look_exp=2)
    size = np.array([[c.width, c.height] for c in cams], np.float32)
    pts = rng.random((n, 8, 2)).astype(np.float32) * size[:, None]
    pts[:, 0] = 0.0
    pts[:, 1] = size
    pts[:, 2, 0] = size[:, 0]

    def kernel_for(packet):
        @wp.kernel(module="unique", enable_backward=False, module_options=MODULE_OPTIONS)
        def k(cams: wp.array(dtype=cm.CameraData), fx: wp.array2d(dtype=float), fy: wp.array2d(dtype=float),
              out: wp.array2d(dtype=wp.vec3), want: wp.array2d(dtype=wp.vec3)):
            i = wp.tid()
            cam = cams[i]
            f = cm.camera_frame(cam, cam.t_open)
            px = cm.PacketF()
            py = cm.PacketF()
            for j in range(8):
                px[j] = fx[i, j]
                py[j] = fy[i, j]
            dx = cm.PacketF()
            dy = cm.PacketF()
            dz = cm.PacketF()
            packet(cam.right, cam.top, cam.x_off, cam.y_off, cam.dist, cam.width, cam.height, f.u, f.v, f.w, px, py, dx, dy,
                   dz)
            for j in range(8):
                out[i, j] = wp.vec3(dx[j], dy[j], dz[j])
                r = cm.camera_ray(cam, fx[i, j], fy[i, j], wp.vec2(0.5, 0.5), cam.t_open)
                want[i, j] = r.d
        return k

    lanes = wp.func_native(cm._CAMERA_PACKET.replace("#if defined(__clang__) && !defined(__CUDA_ARCH__)", "#if 0"))(
        cm.camera_packet.func)
    for variant, fn in (("vectors", cm.camera_packet), ("lanes", lanes)):
        out = wp.zeros((n, 8), dtype=wp.vec3, device=device)
        want = wp.zeros((n, 8), dtype=wp.vec3, device=device)
        wp.launch(kernel_for(fn), dim=n, device=device,
                  inputs=[wp.array(cams, dtype=cm.CameraData, device=device),
                          wp.array(np.ascontiguousarray(pts[..., 0]), dtype=float, device=device),
                          wp.array(np.ascontiguousarray(pts[..., 1]), dtype=float, device=device), out, want])
        got, ref = out.numpy(), want.numpy()
        assert np.isfinite(ref).all() and (np.abs(np.linalg.norm(ref, axis=-1) - 1) < 1e-6).all()
        np.testing.assert_array_equal(got.view(np.uint32), ref.view(np.uint32), err_msg=variant)


def test_a_lens_packets_rays_equal_camera_ray_lane_by_lane(device):
    """``camera.lens_packet`` (a thin-lens camera packet's 8 rays at once: the concentric map's
    disk points, origins and directions), as clang vectors and lane by lane (its CUDA branch,
    compiled here on the CPU), equals ``camera_ray`` for each lane bit for bit, origins and
    directions: random cameras (tiny to wide apertures, focus near and far, tilted up vectors,
    non-square images) and lens points over the whole square, its centre (the disk's centre, a
    special case of the map), edges, corners and diagonals (where the map changes branch)."""
    import warp as wp

    from warprt import camera as cm

    rng = np.random.default_rng(22)
    n = 512
    cams = _random_cameras(rng, n, eye_exp=2, look_exp=1.5, lens=True)
    size = np.array([[c.width, c.height] for c in cams], np.float32)
    pts = rng.random((n, 8, 4)).astype(np.float32)
    pts[..., :2] *= size[:, None]
    special = np.float32([[0.5, 0.5], [0, 0], [1, 1], [0, 1], [0.5, 0], [0.25, 0.25], [0.75, 0.25], [0.5, 0.9]])
    pts[: n // 4, :, 2:] = special[None]

    def kernel_for(packet):
        @wp.kernel(module="unique", enable_backward=False, module_options=MODULE_OPTIONS)
        def k(cams: wp.array(dtype=cm.CameraData), p: wp.array3d(dtype=float), out: wp.array3d(dtype=wp.vec3),
              want: wp.array3d(dtype=wp.vec3)):
            i = wp.tid()
            cam = cams[i]
            f = cm.camera_frame(cam, cam.t_open)
            fx = cm.PacketF()
            fy = cm.PacketF()
            lx = cm.PacketF()
            ly = cm.PacketF()
            for j in range(8):
                fx[j] = p[i, j, 0]
                fy[j] = p[i, j, 1]
                lx[j] = p[i, j, 2]
                ly[j] = p[i, j, 3]
            ox = cm.PacketF()
            oy = cm.PacketF()
            oz = cm.PacketF()
            dx = cm.PacketF()
            dy = cm.PacketF()
            dz = cm.PacketF()
            packet(cam.right, cam.top, cam.x_off, cam.y_off, cam.dist, cam.focus, cam.lens_radius, cam.width,
                   cam.height, f.eye, f.u, f.v, f.w, fx, fy, lx, ly, ox, oy, oz, dx, dy, dz)
            for j in range(8):
                out[i, j, 0] = wp.vec3(ox[j], oy[j], oz[j])
                out[i, j, 1] = wp.vec3(dx[j], dy[j], dz[j])
                r = cm.camera_ray(cam, fx[j], fy[j], wp.vec2(lx[j], ly[j]), cam.t_open)
                want[i, j, 0] = r.o
                want[i, j, 1] = r.d
        return k

    lanes = wp.func_native(cm._LENS_PACKET.replace("#if defined(__clang__) && !defined(__CUDA_ARCH__)", "#if 0"))(
        cm.lens_packet.func)
    for variant, fn in (("vectors", cm.lens_packet), ("lanes", lanes)):
        out = wp.zeros((n, 8, 2), dtype=wp.vec3, device=device)
        want = wp.zeros((n, 8, 2), dtype=wp.vec3, device=device)
        wp.launch(kernel_for(fn), dim=n, device=device,
                  inputs=[wp.array(cams, dtype=cm.CameraData, device=device), wp.array(pts, dtype=float, device=device),
                          out, want])
        got, ref = out.numpy(), want.numpy()
        assert np.isfinite(ref).all() and (np.abs(np.linalg.norm(ref[:, :, 1], axis=-1) - 1) < 1e-6).all()
        # the lens points really spread over the lens (origins off the eye)
        eyes = np.array([[c.eye0[0], c.eye0[1], c.eye0[2]] for c in cams], np.float32)
        assert (np.linalg.norm(ref[:, :, 0] - eyes[:, None], axis=-1) > 0).mean() > 0.8
        np.testing.assert_array_equal(got.view(np.uint32), ref.view(np.uint32), err_msg=variant)
