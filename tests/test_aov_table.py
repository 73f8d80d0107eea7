"""Every row of warprt.aov's table, read back on a scene that exercises it, against the same
samples traced on the host in float64.

The scene: a camera that both moves and turns during the shutter, a floor, a wall, a sphere
moving across it, a disk seen from behind, and a rectangle, a disk and a sphere light in view. For every pixel the host
regenerates the render's own camera samples (``warprt.query.pixel_samples``: film position,
time), builds each sample's ray from the camera at that time, finds the nearest surface and
averages as aov.py documents: coverage = hits / samples; depth = the mean distance; z = the mean
distance along the viewing axis -w *at the sample's time*; the normal turned towards the camera,
renormalised; position; albedo = kd, or Le on an area light; motion = where the visible point
(carried by its object) projects at shutter close minus where it projects at shutter open, in
pixels; object_id = the majority among the first four ids seen (ties to the first), area lights
numbered len(shapes) + their index in ``scene.lights``; material = the index in
``scene.materials``, -1 on a light. Both a single render and world 0 of a batch (the same noise
keys) are checked.

Tolerances: pixels where some sample passes within 1e-4 (relative) of a silhouette or the
horizon are left out (float32 may see the other side; at most a fifth may be, 1% are); elsewhere
ids, material and coverage exact, and albedo and the geometric AOVs to float32 rounding (10x the
worst measured, below).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

import warprt
from warprt.query import pixel_samples, pixel_samples_1d
from warprt.worlds import BatchRenderer

import paths
from paths import AOV_NAMES, FULL

W, H, SPP, SEED = 24, 16, 8, 5
# 10x the worst measured in the two paths below: depth, z and position 1.1e-7 of the depth (times
# paths.grazing), normals 2e-6, motion 2.9e-6 pixels, albedo 1.7e-7 (float32 kd and Le summed)
DEPTH_RTOL, NORMAL_ATOL, MOTION_ATOL, ALBEDO_RTOL = 1.2e-6, 2e-5, 3e-5, 1.7e-6
RECT_LE, DISK_LE, SPHERE_LE = (1.5, 1.0, 0.5), (0.5, 2.0, 1.0), (3.0, 2.5, 2.0)


def aov_scene() -> warprt.Scene:
    eye, look = np.array([0.2, 1.2, 4.0]), np.array([0.0, 0.6, 0.0])
    turned = eye + paths.yaw(6.0) @ (look - eye)  # the look-at point turned 6 degrees about the eye
    cam = warprt.Camera(eye=tuple(eye), look_at=tuple(look), up=paths.open_up(eye, look), fov=45.0, width=W, height=H,
                        eye_end=tuple(eye + [0.3, 0.05, 0.0]), look_at_end=tuple(turned + [0.3, 0.05, 0.0]))
    return warprt.Scene(
        camera=cam,
        shapes=(warprt.Plane(material="floor"),
                warprt.Sphere(center=(-0.8, 0.5, 0.0), center_end=(-0.4, 0.65, 0.3), radius=0.5, material="red"),
                warprt.Rectangle(corner=(-2.5, 0.0, -1.5), edge1=(5.0, 0.0, 0.0), edge2=(0.0, 2.5, 0.0),
                                 material="wall"),
                # seen from behind: its normal (away from the camera) must be turned towards it
                warprt.Disk(center=(-0.3, 0.25, 1.3), normal=(0.2, 0.3, -1.0), radius=0.22, material="back")),
        materials={"floor": warprt.Material(kd=0.6), "red": warprt.Material(kd=(0.8, 0.2, 0.1), ks=0.3, p=20),
                   "wall": warprt.Material(kd=(0.3, 0.5, 0.7)), "back": warprt.Material(kd=(0.9, 0.8, 0.2))},
        lights=(warprt.PointLight(position=(2.0, 4.0, 3.0), intensity=0.7),
                warprt.RectLight(corner=(0.2, 0.2, 0.5), edge1=(0.9, 0.0, 0.0), edge2=(0.0, 0.7, 0.0), radiance=RECT_LE),
                warprt.DiskLight(center=(1.5, 1.35, 0.3), normal=(0.1, 0.0, 1.0), radius=0.4, radiance=DISK_LE),
                warprt.SphereLight(center=(-1.4, 1.5, 0.6), radius=0.35, radiance=SPHERE_LE)),
        ambient=0.05, background=(0.2, 0.25, 0.3), render=warprt.RenderSettings(sampler="sobol", spp=SPP, adaptive=False))


def frame(cam: warprt.Camera, t):
    """eye, u, v, w at times t (arrays), the camera's linear eye and look-at, fixed up."""
    e0, e1 = np.asarray(cam.eye), np.asarray(cam.eye_end)
    l0, l1 = np.asarray(cam.look_at), np.asarray(cam.look_at_end)
    t = np.asarray(t, np.float64)[:, None]
    eye, look = e0 + (e1 - e0) * t, l0 + (l1 - l0) * t
    w = eye - look
    w /= np.linalg.norm(w, axis=1, keepdims=True)
    u = np.cross(np.asarray(cam.up, np.float64), w)
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    return eye, u, np.cross(w, u), w


def project(cam: warprt.Camera, p, t):
    eye, u, v, w = frame(cam, np.full(len(p), t))
    q = p - eye
    zc = -(q * w).sum(1)
    top = math.tan(math.radians(cam.fov) / 2)
    right = top * cam.width / cam.height
    us, vs = (q * u).sum(1) / zc, (q * v).sum(1) / zc
    return np.stack([(us + right) / (2 * right) * cam.width, (top - vs) / (2 * top) * cam.height], axis=1)


def _planar(o, d, point, normal, inside):
    """t of the rays' hit of a plane and a margin (relative distance of the hit to the shape's
    boundary, ``inside``: p -> (is inside, margin))."""
    n = np.asarray(normal, np.float64)
    n = n / np.linalg.norm(n)
    dn = d @ n
    with np.errstate(divide="ignore", invalid="ignore"):
        t = ((np.asarray(point) - o) @ n) / dn
    p = o + t[:, None] * d
    ok, margin = inside(p)
    ok &= (t > 0) & np.isfinite(t)
    return np.where(ok, t, np.inf), np.where(np.isfinite(t) & (t > 0), margin, np.inf), np.broadcast_to(n, d.shape)


def _sphere(o, d, c, r):
    f = o - c
    b = (f * d).sum(1)
    disc = r * r - ((f * f).sum(1) - b * b)
    t = -b - np.sqrt(np.maximum(disc, 0.0))
    t = np.where((disc > 0) & (t > 0), t, np.inf)
    p = o + np.where(np.isfinite(t), t, 0)[:, None] * d
    return t, np.abs(disc) / (r * r), (p - c) / r


def host_aovs(scene: warprt.Scene, seed: int) -> tuple[dict, np.ndarray]:
    """The AOVs of ``scene`` per aov.py's table from its own camera samples, in float64, and
    the pixels where some sample passes within 1e-4 of a silhouette."""
    cam = scene.camera
    pixels = np.arange(W * H)
    film = pixel_samples("sobol", pixels, SPP, dim=0, seed=seed).reshape(-1, 2).astype(np.float64)
    time = pixel_samples_1d("sobol", pixels, SPP, dim=2, seed=seed).reshape(-1).astype(np.float64)
    px = np.repeat(np.stack([pixels % W, pixels // W], axis=1), SPP, axis=0) + film
    eye, u, v, w = frame(cam, time)
    top = math.tan(math.radians(cam.fov) / 2)
    right = top * W / H
    us = -right + 2 * right * px[:, 0] / W
    vs = top - 2 * top * px[:, 1] / H
    d = us[:, None] * u + vs[:, None] * v - w
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    o = eye
    floor, sphere, wall, back = scene.shapes
    rect, disk, ball = scene.lights[1:]
    c_t = np.asarray(sphere.center) + (np.asarray(sphere.center_end) - np.asarray(sphere.center)) * time[:, None]

    def in_rect(corner, e1, e2):
        corner, e1, e2 = (np.asarray(x, np.float64) for x in (corner, e1, e2))

        def inside(p):
            a, b = (p - corner) @ e1 / (e1 @ e1), (p - corner) @ e2 / (e2 @ e2)
            return (a > 0) & (a < 1) & (b > 0) & (b < 1), np.minimum.reduce([abs(a), abs(1 - a), abs(b), abs(1 - b)])
        return inside

    def in_disk(dk):
        def inside(p):
            r = np.linalg.norm(p - np.asarray(dk.center), axis=1)
            return r < dk.radius, np.abs(r / dk.radius - 1)
        return inside

    hits = [  # (t, margin, normal), in the id order below
        _planar(o, d, floor.point, floor.normal, lambda p: (np.ones(len(p), bool), np.full(len(p), np.inf))),
        _sphere(o, d, c_t, sphere.radius),
        _planar(o, d, wall.corner, np.cross(wall.edge1, wall.edge2), in_rect(wall.corner, wall.edge1, wall.edge2)),
        _planar(o, d, back.center, back.normal, in_disk(back)),
        _planar(o, d, rect.corner, np.cross(rect.edge1, rect.edge2), in_rect(rect.corner, rect.edge1, rect.edge2)),
        _planar(o, d, disk.center, disk.normal, in_disk(disk)),
        _sphere(o, d, np.asarray(ball.center, np.float64), ball.radius),
    ]
    n_shapes = len(scene.shapes)
    ids = np.array([0, 1, 2, 3, n_shapes + 1, n_shapes + 2, n_shapes + 3])  # area lights: len(shapes) + index
    names = list(scene.materials)
    mats = np.array([names.index(s.material) for s in scene.shapes] + [-1, -1, -1])
    albedo = np.array([scene.materials[s.material].kd for s in scene.shapes] + [RECT_LE, DISK_LE, SPHERE_LE], np.float64)
    ts = np.stack([h[0] for h in hits], axis=1)
    k = np.argmin(ts, axis=1)
    t = ts[np.arange(len(k)), k]
    hit = np.isfinite(t)
    k = np.where(hit, k, 0)
    margin = np.min(np.stack([h[1] for h in hits], axis=1), axis=1)
    # the floor meets the horizon where a ray runs nearly parallel to it
    margin = np.minimum(margin, np.abs(d[:, 1]) * 10)
    normal = np.stack([h[2] for h in hits], axis=1)[np.arange(len(k)), k]
    normal = np.where(((normal * d).sum(1) > 0)[:, None], -normal, normal)
    tt = np.where(hit, t, 0.0)
    p = o + tt[:, None] * d
    z = tt * -(d * w).sum(1)
    # the visible point carried by its object: the sphere moves, the rest stands still
    c0, c1 = np.asarray(sphere.center), np.asarray(sphere.center_end)
    on_sphere = (k == 1)[:, None]
    p0 = np.where(on_sphere, p + c0 - c_t, p)
    p1 = np.where(on_sphere, p + c1 - c_t, p)
    motion = project(cam, p1, 1.0) - project(cam, p0, 0.0)

    def per_pixel(x):
        x = x.reshape(W * H, SPP, *x.shape[1:])
        n = hit.reshape(W * H, SPP).sum(1)
        mask = hit.reshape(W * H, SPP, *([1] * (x.ndim - 2)))
        with np.errstate(invalid="ignore", divide="ignore"):
            return (np.where(mask, x, 0).sum(1) / n.reshape(-1, *([1] * (x.ndim - 2)))).reshape(H, W, *x.shape[2:])

    out = {"coverage": hit.reshape(W * H, SPP).mean(1).reshape(H, W), "depth": per_pixel(t), "z": per_pixel(z),
           "position": per_pixel(p), "albedo": per_pixel(albedo[k]), "motion": per_pixel(motion)}
    nsum = per_pixel(normal)
    out["normal"] = nsum / np.linalg.norm(nsum, axis=-1, keepdims=True)
    seen = np.where(hit, ids[k], -1).reshape(W * H, SPP)
    oid, mid = np.full(W * H, -1), np.full(W * H, -1)
    for i in range(W * H):
        order = list(dict.fromkeys(int(s) for s in seen[i] if s >= 0))[:4]
        if order:
            votes = [int((seen[i] == s).sum()) for s in order]
            oid[i] = order[int(np.argmax(votes))]  # the first of the largest
            mid[i] = mats[list(ids).index(oid[i])]
    out["object_id"], out["material"] = oid.reshape(H, W), mid.reshape(H, W)
    doubtful = (margin < 1e-4).reshape(W * H, SPP).any(1).reshape(H, W)
    return out, doubtful


def check_table(got: dict, scene: warprt.Scene, what: str) -> None:
    want, doubtful = host_aovs(scene, SEED)
    ok = ~doubtful
    assert ok.mean() > 0.8, what
    for name in ("coverage", "object_id", "material"):
        np.testing.assert_array_equal(got[name][ok], want[name][ok].astype(got[name].dtype), err_msg=f"{what}: {name}")
    # every kind of pixel is there: lights (each), shapes, sky, and pixels partly covered
    assert {0, 1, 2, 3, 5, 6, 7} <= set(np.unique(got["object_id"][ok])), what
    back = ok & (want["object_id"] == 3) & (want["coverage"] == 1)
    assert back.any() and (got["normal"][back] @ np.asarray(scene.shapes[3].normal) < 0).all(), what
    assert ((got["coverage"] > 0) & (got["coverage"] < 1))[ok].any(), what
    hit = ok & (want["coverage"] > 0)
    miss = ok & (want["coverage"] == 0)
    assert np.isposinf(got["depth"][miss]).all() and np.isposinf(got["z"][miss]).all(), what
    np.testing.assert_allclose(got["albedo"][hit], want["albedo"][hit], rtol=ALBEDO_RTOL, err_msg=f"{what}: albedo")
    kappa = paths.grazing(want, scene.camera.eye, scene.camera.eye[1])
    for name in ("depth", "z"):
        err = np.abs(got[name][hit] / want[name][hit] - 1) / kappa[hit]
        assert err.max() < DEPTH_RTOL, f"{what}: {name} off by {err.max():.3g} of the depth (x grazing)"
    err = np.abs(got["position"] - want["position"]).max(-1)[hit] / (want["depth"][hit] * kappa[hit])
    assert err.max() < DEPTH_RTOL, f"{what}: position off by {err.max():.3g}"
    err = np.abs(got["normal"] - want["normal"]).max(-1)[hit]
    assert err.max() < NORMAL_ATOL, f"{what}: normal off by {err.max():.3g}"
    err = np.abs(got["motion"] - want["motion"]).max(-1)[hit]
    assert err.max() < MOTION_ATOL, f"{what}: motion off by {err.max():.3g} pixels"
    # what the scene makes of them: the lights' albedo is their radiance (a light is kd = 0), z
    # differs from depth, the motion is the camera's and the sphere's (the lit pixels move)
    for oid, le in ((5, RECT_LE), (6, DISK_LE), (7, SPHERE_LE)):
        whole = ok & (want["object_id"] == oid) & (want["coverage"] == 1) & (want["albedo"] == le).all(-1)
        assert whole.any(), (what, oid)  # pixels that see nothing but the light
        np.testing.assert_allclose(got["albedo"][whole], np.broadcast_to(le, got["albedo"][whole].shape),
                                   rtol=ALBEDO_RTOL)
    assert (np.abs(got["z"][hit] - got["depth"][hit]) > 1e-3).mean() > 0.5, what
    assert (np.abs(got["motion"][hit]).max(-1) > 0.5).mean() > 0.5, what


def test_every_aov_reads_back_as_the_table_says_in_a_single_render():
    scene = aov_scene()
    out = warprt.Renderer(scene, device="cpu", features=FULL).render(spp=SPP, seed=SEED, progress=False, aovs=AOV_NAMES)
    check_table(out.aovs, scene, "single render")


def test_every_aov_reads_back_as_the_table_says_in_a_batch():
    """World 0 camera 0 of a batch (the scene's own poses, the single render's noise keys)."""
    scene = aov_scene()
    br = BatchRenderer(scene, worlds=2, cameras=1, device="cpu", features=FULL, motion_blur=True)
    got = br.render(spp=SPP, seed=SEED, aovs=AOV_NAMES).aovs_numpy()
    check_table({k: v[0, 0] for k, v in got.items()}, scene, "batch world 0")
