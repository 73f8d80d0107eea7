"""Helpers for the tests that render one scene through several paths (tests/test_crossed_paths.py,
tests/test_motion_known_answers.py, tests/test_aov_table.py): a scene that uses every shape and
light kind, the single-render scene equal to a world and camera of a batch (posed on the host in
float64), pairwise covering designs, and the two ways two renders may agree.

**The same samples** (a path promises the single render's noise keys: world 0 camera 0 of a
batch, any world with the ``regular`` sampler, whose samples are the same in every pixel, an
animation frame, a Newton world): the images agree to float32 rounding except where a sample's
rounding flips what it sees (a silhouette, a shadow edge). The batch builds its camera from a
quaternion and poses its shapes in float32 on the device where the host composes them in
float64: measured over the crossed cases (batches and Newton worlds; the animation frames came
out bit-identical), pixels differ by at most 7e-6 (relative 3.8e-5) and none held a flipped
sample (tests/test_worlds.py sees up to 3 of 768 pixels at 1 spp). Tolerances: 10x those, and 1%
of the pixels may flip. AOVs, where ids, material and coverage agree and the colour is close:
albedo exact, depth, z and position within 6.6e-7 of the depth times ``grazing`` (measured; the
float32 error of a direction grows with the angle of incidence and, on the floor, with the
distance over the eye's height), normals within 1.6e-5, motion within 1.9e-5 pixels (measured),
tested at 10x.

**Different samples** (other worlds and cameras with a randomised sampler, adaptive against
uniform sampling): both are unbiased estimates of the same pixel means, independent between
pixels, so the mean over pixels of their difference is zero (its z, self-normalised, within
Z_LIMIT), and the squared difference of the two renders is, pixel for pixel, that of two more
renders of the single path with other seeds (the paired z of the squared differences within
Z_LIMIT: a shading error confined to a few pixels shows here, not in the mean).
"""

from __future__ import annotations

import itertools
import math

import numpy as np
import trimesh
import warp as wp

import warprt
from warprt import Features
from warprt.aov import AOVS
from warprt.scene.transform import quaternion_matrix, quaternion_product

FULL = Features.full()
AOV_NAMES = list(AOVS)
Z_LIMIT = 5.0  # |z| of a test statistic that is N(0, 1) when the paths agree
FLAT_ATOL = 7e-5  # 10x the measured float32 differences between paths of the same samples
FLAT_RTOL = 4e-4
FLIP_FRACTION = 0.01  # pixels with a flipped sample: none measured here, up to 3 of 768 in test_worlds
DEPTH_RTOL = 7e-6  # depth, z and position: 10x the measured 6.6e-7 of the depth (times ``grazing``)
NORMAL_ATOL = 1.6e-4  # 10x the measured 1.6e-5
MOTION_ATOL = 2e-4  # pixels: 10x the measured 1.9e-5


# --- designs ----------------------------------------------------------------------------------


def pairwise(factors: dict) -> list[dict]:
    """A covering design: rows (dicts of factor -> level) in which every pair of levels of every
    two factors occurs at least once. Greedy over the full product, deterministic: each row is
    the first one covering the most pairs not yet covered."""
    names = list(factors)
    rows = [dict(zip(names, combo)) for combo in itertools.product(*(factors[n] for n in names))]

    def pairs(row):
        return {(a, row[a], b, row[b]) for a, b in itertools.combinations(names, 2)}

    todo = set().union(*(pairs(r) for r in rows))
    design = []
    while todo:
        best = max(rows, key=lambda r: len(pairs(r) & todo))
        design.append(best)
        todo -= pairs(best)
    return design


def case_id(case: dict) -> str:
    return "-".join(f"{k}={v}" for k, v in case.items())


# --- the scene --------------------------------------------------------------------------------

W, H = 32, 24
EYE = np.array([0.3, 1.6, 4.0])
LOOK = np.array([0.0, 0.4, 0.0])
UP = (0.0, 1.0, 0.0)
TURN = 6.0  # degrees the turning camera yaws over the shutter
FOCUS = 4.2


def yaw(deg: float) -> np.ndarray:
    t = math.radians(deg)
    return np.array([[math.cos(t), 0.0, math.sin(t)], [0.0, 1.0, 0.0], [-math.sin(t), 0.0, math.cos(t)]])


def open_up(eye, look, up=UP) -> tuple:
    """The camera's v axis at ``eye`` looking at ``look`` with ``up``: as ``up`` it gives the same
    frame, and a batch camera keeps it over the shutter (worlds.py: the up vector is the
    shutter-open one), so a scene camera with it turns as the batch's does."""
    w = np.subtract(eye, look)
    w = w / np.linalg.norm(w)
    u = np.cross(up, w)
    u /= np.linalg.norm(u)
    return tuple(float(x) for x in np.cross(w, u))


def camera(motion: str = "still", lens: bool = False, eye=EYE, look=LOOK, width=W, height=H, fov=45.0,
           up=None) -> warprt.Camera:
    """A camera still, translating (eye and look-at shifted together) or turning about its eye
    (the look-at point yawed at the same distance)."""
    eye, look = np.asarray(eye, np.float64), np.asarray(look, np.float64)
    kw = {}
    if motion == "translate":
        kw = dict(eye_end=tuple(eye + [0.35, 0.1, 0.0]), look_at_end=tuple(look + [0.35, 0.1, 0.0]))
    elif motion == "turn":
        kw = dict(look_at_end=tuple(eye + yaw(TURN) @ (look - eye)))
    if lens:
        kw.update(aperture=0.08, focus_distance=FOCUS)
    return warprt.Camera(eye=tuple(eye), look_at=tuple(look), up=open_up(eye, look) if up is None else up, fov=fov,
                         width=width, height=height, **kw)


def closed_mesh() -> tuple[np.ndarray, np.ndarray]:
    ico = trimesh.creation.icosphere(subdivisions=1, radius=0.3)
    return np.asarray(ico.vertices, np.float64), np.asarray(ico.faces, np.int64)


def _moved(t: warprt.Transform, motion: str) -> warprt.Transform | None:
    if motion == "translate":
        return warprt.Transform(translate=tuple(np.add(t.translate, (0.25, 0.05, -0.1))), rotate=t.rotate,
                                scale=t.scale)
    if motion == "turn":
        return warprt.Transform(translate=t.translate, rotate=tuple(np.add(t.rotate, (10.0, 35.0, 0.0))),
                                scale=t.scale)
    return None


def every_kind_scene(sampler: str = "stratified", camera_motion: str = "still", objects: str = "still",
                     lens: bool = False, spp: int = 8, adaptive: bool = False, defaults: bool = False) -> warprt.Scene:
    """Every shape kind (a plane, a sphere, a rectangle, a disk, a box, a capsule, a cylinder and a
    non-uniformly scaled closed mesh) under every light kind (point, directional, rectangle,
    sphere and disk lights, the area lights in view), with the sphere, the solids and the mesh
    still, translating or turning over the shutter. Its settings are stated, not the defaults:
    the area lights' shadow rays per sample fixed (a batch takes 1 for ``"auto"``) and uniform
    sampling unless ``adaptive`` (``render.adaptive``: what ``render()`` does when not told).
    ``defaults``: the area lights and the sampling as a user gets them (each light class's own
    ``samples``, adaptive sampling)."""
    n = (lambda k: {}) if defaults else (lambda k: {"samples": k})
    adaptive = adaptive or defaults
    v, f = closed_mesh()
    mats = {"floor": warprt.Material(kd=0.6), "red": warprt.Material(kd=(0.8, 0.2, 0.2), ks=0.3, p=20),
            "green": warprt.Material(kd=(0.2, 0.7, 0.3)), "blue": warprt.Material(kd=(0.2, 0.3, 0.8), ks=0.2, p=8)}
    posed = {
        "box": warprt.Transform(translate=(0.25, 0.25, 0.6), rotate=(0, 25, 0)),
        "capsule": warprt.Transform(translate=(1.0, 0.4, 0.4), rotate=(0, 0, 30)),
        "cylinder": warprt.Transform(translate=(-0.3, 0.5, -0.4), rotate=(60, 0, 0)),
        "mesh": warprt.Transform(translate=(0.6, 0.9, -0.2), rotate=(10, 20, 30), scale=(1.0, 1.5, 0.8)),
    }
    end = {k: _moved(t, objects) for k, t in posed.items()}
    sphere_end = {"translate": (-0.7, 0.4, 0.35), "turn": (-1.0, 0.35, 0.5)}.get(objects)
    shapes = (
        warprt.Plane(material="floor"),
        warprt.Sphere(center=(-1.0, 0.35, 0.3), radius=0.35, material="red", center_end=sphere_end),
        warprt.Rectangle(corner=(-1.6, 0.0, -1.2), edge1=(1.2, 0.0, 0.2), edge2=(0.0, 1.0, 0.0), material="green"),
        warprt.Disk(center=(1.3, 0.5, -0.9), normal=(-0.3, 0.2, 1.0), radius=0.4, material="blue"),
        warprt.Box(size=(0.4, 0.5, 0.3), transform=posed["box"], transform_end=end["box"], material="blue"),
        warprt.Capsule(radius=0.15, transform=posed["capsule"], transform_end=end["capsule"], material="red"),
        warprt.Cylinder(radius=0.18, transform=posed["cylinder"], transform_end=end["cylinder"], material="green"),
        warprt.Mesh(vertices=v, faces=f, material="red", transform=posed["mesh"], transform_end=end["mesh"]),
    )
    lights = (warprt.PointLight(position=(2.0, 4.0, 3.0), intensity=0.5),
              warprt.DirectionalLight(direction=(-0.3, -1.0, -0.2), intensity=0.3),
              warprt.RectLight(corner=(-0.9, 1.7, -1.0), edge1=(0.6, 0.0, 0.0), edge2=(0.0, -0.2, 0.5), radiance=1.5,
                               **n(2)),
              warprt.SphereLight(center=(-1.9, 1.3, -0.5), radius=0.25, radiance=2.0, **n(1)),
              warprt.DiskLight(center=(1.8, 1.4, -0.6), normal=(-1.0, -0.6, 0.6), radius=0.3, radiance=2.0,
                               **n(1)))
    return warprt.Scene(camera=camera(camera_motion, lens), shapes=shapes, materials=mats, lights=lights,
                        ambient=0.05, background=(0.2, 0.25, 0.3),
                        render=warprt.RenderSettings(sampler=sampler, spp=spp, adaptive=adaptive))


# --- batches on the host ----------------------------------------------------------------------


def quat(axis, degrees: float) -> np.ndarray:
    axis = np.asarray(axis, np.float64) / np.linalg.norm(axis)
    h = math.radians(degrees) / 2
    return np.concatenate([axis * math.sin(h), [math.cos(h)]])


def pose(translate=(0.0, 0.0, 0.0), axis=(0.0, 1.0, 0.0), degrees=0.0) -> np.ndarray:
    """A rigid pose as the batch takes it: (x, y, z, qx, qy, qz, qw)."""
    return np.concatenate([np.asarray(translate, np.float64), quat(axis, degrees)])


IDENTITY = pose()


def apply(p: np.ndarray, x) -> tuple:
    return tuple(float(c) for c in quaternion_matrix(p[3:]) @ np.asarray(x, np.float64) + p[:3])


def turn(p: np.ndarray, x) -> tuple:
    return tuple(float(c) for c in quaternion_matrix(p[3:]) @ np.asarray(x, np.float64))


def compose(p: np.ndarray, t: warprt.Transform | None) -> warprt.Transform:
    """The transform ``p ∘ t`` (the batch puts its pose on top of a shape's own transform)."""
    t = t or warprt.Transform()
    return warprt.Transform.from_quaternion(quaternion_product(p[3:], t.quaternion()), translate=apply(p, t.translate),
                                            scale=t.scale)


def posed_shape(s, p0: np.ndarray, p1: np.ndarray):
    """Shape ``s`` with the batch pose p0 at shutter open and p1 at close (worlds.py's rules:
    planes, rectangles and disks take the open pose)."""
    from dataclasses import replace

    if isinstance(s, warprt.Sphere):
        return replace(s, center=apply(p0, s.center), center_end=apply(p1, s.center_end or s.center))
    if isinstance(s, warprt.Plane):
        return replace(s, point=apply(p0, s.point), normal=turn(p0, s.normal))
    if isinstance(s, warprt.Rectangle):
        return replace(s, corner=apply(p0, s.corner), edge1=turn(p0, s.edge1), edge2=turn(p0, s.edge2))
    if isinstance(s, warprt.Disk):
        return replace(s, center=apply(p0, s.center), normal=turn(p0, s.normal))
    t0 = s.transform or warprt.Transform()
    return replace(s, transform=compose(p0, t0), transform_end=compose(p1, s.transform_end or t0))


def camera_of_pose(cam: warprt.Camera, p0: np.ndarray, p1: np.ndarray, fov: float) -> warprt.Camera:
    """The scene camera a batch camera pose pair gives: looking along the pose's -z with its +y
    up at shutter open; the scene camera's image size, aperture, focus and shutter."""
    from dataclasses import replace

    r0, r1 = quaternion_matrix(p0[3:]), quaternion_matrix(p1[3:])
    eye0, eye1 = p0[:3], p1[:3]
    return replace(cam, eye=tuple(eye0), look_at=tuple(eye0 - r0[:, 2]), up=tuple(r0[:, 1]), fov=fov,
                   eye_end=tuple(eye1), look_at_end=tuple(eye1 - r1[:, 2]), focus_distance=cam.focus, keyframes=())


def camera_pose(eye, look, up=UP) -> np.ndarray:
    """The batch pose (position, quaternion) of a camera at ``eye`` looking at ``look``."""
    from warprt.worlds import camera_quaternion

    return np.concatenate([np.asarray(eye, np.float64), camera_quaternion(eye, look, up)])


def posed_scene(scene: warprt.Scene, shapes0, shapes1, lights, cam0, cam1, fov) -> warprt.Scene:
    """The single-render scene of one world and camera of a batch of ``scene``: shape poses
    (S, 7) at open and close, the positions (directions) of its point (directional) lights in
    ``scene.lights`` order, camera poses at open and close and the field of view."""
    from dataclasses import replace

    shapes = tuple(posed_shape(s, shapes0[i], shapes1[i]) for i, s in enumerate(scene.shapes))
    out, k = [], 0
    for light in scene.lights:
        if isinstance(light, warprt.PointLight):
            light = replace(light, position=tuple(float(x) for x in lights[k]))
            k += 1
        elif isinstance(light, warprt.DirectionalLight):
            light = replace(light, direction=tuple(float(x) for x in lights[k]))
            k += 1
        out.append(light)
    return scene.replace(shapes=shapes, lights=tuple(out), camera=camera_of_pose(scene.camera, cam0, cam1, fov))


def set_batch(br, shapes0, shapes1, lights, cams0, cams1, fov) -> None:
    br.set_shape_poses(shapes0, end=shapes1)
    br.set_camera_poses(cams0, end=cams1)
    wp.copy(br.light_positions, wp.array(np.asarray(lights, np.float32), dtype=wp.vec3, device=br.device))
    wp.copy(br.fov, wp.array(np.asarray(fov, np.float32), dtype=float, device=br.device))


# --- comparisons ------------------------------------------------------------------------------


def render(scene, spp, seed=0, aovs=AOV_NAMES, **kw):
    return warprt.Renderer(scene, device=kw.pop("device", "cpu"), features=FULL, packets=kw.pop("packets", None)) \
        .render(spp=spp, seed=seed, progress=False, aovs=aovs, **kw)


def grazing(aovs, eye, height: float) -> np.ndarray:
    """How much a depth's relative float32 error grows over a direction's, per pixel: 1 + tan of
    the angle between the line of sight (from ``eye`` to the position) and the normal, plus the
    floor's depth / ``height`` (the eye's height over the floor: far out, where it meets the
    horizon, a pixel's samples mix the floor with other surfaces and its mean normal says little)."""
    d = aovs["position"] - np.asarray(eye, np.float32)
    c = np.abs((aovs["normal"] * d).sum(axis=-1)) / np.maximum(np.linalg.norm(d, axis=-1), 1e-30)
    c = np.clip(c, 1e-6, 1.0)
    depth = np.where(np.isfinite(aovs["depth"]), aovs["depth"], 0.0)
    return 1.0 + np.sqrt(1.0 - c * c) / c + depth / height


def same_samples(img_a, aovs_a, img_b, aovs_b, what: str, eye, height: float = 1.0) -> None:
    """Renders of the same samples through two paths: equal to float32 rounding except pixels
    where a sample flips (see the module docstring). ``eye``: the camera's eye (at shutter open),
    ``height``: a lower bound of its height over the floor."""
    diff = np.abs(img_a - img_b).max(axis=2)
    close = diff <= FLAT_ATOL + FLAT_RTOL * np.abs(img_b).max(axis=2)
    far = ~close
    assert far.mean() <= FLIP_FRACTION, f"{what}: {far.sum()} of {far.size} pixels differ (worst {diff.max():.3g})"
    if aovs_a is None:
        return
    ids_a, ids_b = aovs_a["object_id"], aovs_b["object_id"]
    same = (ids_a == ids_b) & (aovs_a["coverage"] == aovs_b["coverage"]) & close
    assert same.mean() >= 1.0 - FLIP_FRACTION, f"{what}: ids or coverage differ at {(~same).sum()} pixels"
    np.testing.assert_array_equal(aovs_a["material"][same], aovs_b["material"][same], err_msg=what)
    hit = same & (aovs_b["coverage"] > 0)
    kappa = grazing(aovs_b, eye, height)
    for name in ("depth", "z"):
        err = np.abs(aovs_a[name][hit] / aovs_b[name][hit] - 1) / kappa[hit]
        assert (err <= DEPTH_RTOL).all(), f"{what}: {name} off by {err.max():.3g} of the depth (x grazing)"
    pos = np.abs(aovs_a["position"] - aovs_b["position"]).max(axis=2)[hit] / (aovs_b["depth"][hit] * kappa[hit])
    assert (pos <= DEPTH_RTOL).all(), f"{what}: position off by {pos.max():.3g} of the depth (x grazing)"
    for name, atol in (("normal", NORMAL_ATOL), ("albedo", 0.0), ("motion", MOTION_ATOL)):
        d = np.abs(aovs_a[name] - aovs_b[name]).max(axis=2)[hit]
        assert (d <= atol).all(), f"{what}: {name} differs by {d.max():.3g}"
    for aovs in (aovs_a, aovs_b):  # the miss value: one everywhere
        miss = aovs["coverage"] == 0
        assert np.isposinf(aovs["depth"][miss]).all() and np.isposinf(aovs["z"][miss]).all(), what
        assert (aovs["object_id"][miss] == -1).all() and (aovs["material"][miss] == -1).all(), what
        for name in ("normal", "albedo", "position", "motion"):
            assert (aovs[name][miss] == 0).all(), f"{what}: {name} of a miss"


def z_mean(a, b) -> float:
    """Self-normalised z of the mean over pixels of a - b (channels summed per pixel)."""
    d = (np.asarray(a, np.float64) - b).reshape(a.shape[0] * a.shape[1], -1).sum(axis=1)
    return float(d.sum() / math.sqrt(max((d * d).sum(), 1e-300)))


def z_spread(a, b, c, d) -> float:
    """Paired z of (a - b)² against (c - d)² over pixels: positive when a and b differ by more
    than two renders of one path do."""
    x = ((np.asarray(a, np.float64) - b) ** 2).reshape(a.shape[0] * a.shape[1], -1).sum(axis=1)
    y = ((np.asarray(c, np.float64) - d) ** 2).reshape(a.shape[0] * a.shape[1], -1).sum(axis=1)
    e = x - y
    return float(e.sum() / math.sqrt(max((e * e).sum(), 1e-300)))


def same_distribution(img, ref_a, ref_b, ref_c, what: str) -> None:
    """``img`` and three renders of the reference path with other seeds estimate the same
    pixels (see the module docstring)."""
    zm, zs = z_mean(img, ref_a), z_spread(img, ref_a, ref_b, ref_c)
    assert abs(zm) < Z_LIMIT and zs < Z_LIMIT, f"{what}: mean z {zm:.2f}, spread z {zs:.2f}"
