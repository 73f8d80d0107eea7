"""Boxes, capsules and cylinders (warprt.Box, Capsule, Cylinder): analytic solids intersected in
their own frame.

Hits are checked against an independent float64 reference written here the textbook way (a
box's slab test on its turned axes; a cylinder's side quadratic and its two cap planes; a
capsule's side quadratic and its two end spheres, each root kept where it lies on that piece),
not the renderer's interval form. Rays within float32 reach of a silhouette, an edge or a rim
can go either way, so hit/miss is compared only where the reference answer is the same for the
solid grown and shrunk by 1e-4. Shading, shadows and transmission are checked against their
closed forms, spawning at scales from 1e-3 to 1e4, and batches against single renders.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

import warprt
from warprt.errors import SceneError
from warprt.records import features_of
from warprt.worlds import BatchRenderer

REGULAR = warprt.RenderSettings(sampler="regular", spp=1)
Q = (0.2, -0.4, 0.3, 0.84)  # a general rotation (normalised by the Transform)
GROW = 1e-4


def quat_mul(a, b) -> np.ndarray:
    """The rotation b, then a (x, y, z, w)."""
    (ax, ay, az, aw), (bx, by, bz, bw) = a, b
    return np.array([aw * bx + ax * bw + ay * bz - az * by, aw * by - ax * bz + ay * bw + az * bx,
                     aw * bz + ax * by - ay * bx + az * bw, aw * bw - ax * bx - ay * by - az * bz])


def _quat(q) -> np.ndarray:
    q = np.asarray(q, np.float64)
    return q / np.linalg.norm(q)


# --- independent float64 references ------------------------------------------------------------

def ref_box(o, d, half, eps=0.0):
    """Nearest t > 0 of unit rays (o, d) (box frame) with the box |x_k| <= half_k + eps; inf if none."""
    h = np.asarray(half) + eps
    with np.errstate(divide="ignore", invalid="ignore"):
        t0 = (-h - o) / d
        t1 = (h - o) / d
    lo = np.where(d == 0, np.where(np.abs(o) <= h, -np.inf, np.inf), np.minimum(t0, t1))
    hi = np.where(d == 0, np.where(np.abs(o) <= h, np.inf, -np.inf), np.maximum(t0, t1))
    tn, tf = lo.max(axis=1), hi.min(axis=1)
    t = np.where(tn > 0, tn, tf)
    return np.where((tn <= tf) & (t > 0), t, np.inf)


def _quadratic(a, b, c):
    """Both roots of a t² + 2 b t + c = 0 (nan where none)."""
    disc = b * b - a * c
    with np.errstate(invalid="ignore", divide="ignore"):
        s = np.sqrt(disc)
        return (-b - s) / a, (-b + s) / a


def ref_round(o, d, r, h, capsule: bool, eps=0.0):
    """Nearest t > 0 of rays (o, d) (local frame, axis y) with a capsule or closed cylinder of
    radius r and half length h, grown by eps; inf if none."""
    r, h = r + eps, h + eps * (not capsule)
    cands = []
    a = d[:, 0] ** 2 + d[:, 2] ** 2
    b = o[:, 0] * d[:, 0] + o[:, 2] * d[:, 2]
    c = o[:, 0] ** 2 + o[:, 2] ** 2 - r * r
    for t in _quadratic(a, b, c):  # the side: |y| <= h
        y = o[:, 1] + t * d[:, 1]
        cands.append(np.where(np.abs(y) <= h, t, np.nan))
    for s in (-1.0, 1.0):
        if capsule:  # the end spheres, beyond the segment
            f = o - np.array([0.0, s * h, 0.0])
            for t in _quadratic(np.ones(len(o)), (f * d).sum(1), (f * f).sum(1) - r * r):
                y = o[:, 1] + t * d[:, 1]
                cands.append(np.where(s * y >= h, t, np.nan))
        else:  # the caps: the plane y = s h within the radius
            with np.errstate(divide="ignore", invalid="ignore"):
                t = (s * h - o[:, 1]) / d[:, 1]
            p = o + t[:, None] * d
            cands.append(np.where(p[:, 0] ** 2 + p[:, 2] ** 2 <= r * r, t, np.nan))
    t = np.stack(cands, 1)
    t = np.where(t > 0, t, np.inf)
    return np.nanmin(np.where(np.isnan(t), np.inf, t), axis=1)


def rays_at(center, reach, n, rng, inside=0):
    """Rays from a sphere of radius 4·reach about ``center`` towards points in its reach (plus
    ``inside`` rays starting near the centre)."""
    u = rng.normal(size=(n, 3))
    o = center + 4 * reach * u / np.linalg.norm(u, axis=1, keepdims=True)
    target = center + rng.uniform(-1.3, 1.3, size=(n, 3)) * reach
    if inside:
        o[:inside] = center + rng.uniform(-0.1, 0.1, size=(inside, 3)) * reach
    d = target - o
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    # the rays as the renderer gets them (float32), so that the reference sees the same rays
    return o.astype(np.float32).astype(np.float64), d.astype(np.float32).astype(np.float64)


SOLIDS = {
    "box": (lambda t: warprt.Box(center=(0.1, -0.2, 0.05), size=(1.2, 0.5, 0.8), transform=t), 0.8),
    "capsule": (lambda t: warprt.Capsule(start=(0.0, -0.4, 0.1), end=(0.3, 0.5, -0.2), radius=0.3, transform=t), 0.9),
    "cylinder": (lambda t: warprt.Cylinder(start=(0.0, -0.4, 0.1), end=(0.3, 0.5, -0.2), radius=0.35, transform=t),
                 0.9),
}


def frame(shape):
    """(centre, 3x3 local-to-world rotation, size) of ``shape`` from its fields and transform
    (not from ``shape.world()``, which the renderer's tables come from). Capsules and cylinders
    get any frame whose y axis runs from start to end (they are symmetric about it)."""
    t = shape.transform or warprt.Transform()
    if isinstance(shape, warprt.Box):
        half = 0.5 * np.asarray(shape.size) * np.abs(t.scale)
        return np.asarray(t.apply_point(shape.center)), t.rotation_matrix(), half
    a, b = np.asarray(t.apply_point(shape.start)), np.asarray(t.apply_point(shape.end))
    y = (b - a) / np.linalg.norm(b - a) if np.any(a != b) else np.array([0.0, 1.0, 0.0])
    x = np.cross(y, [0.3, 0.5, 0.8])
    x /= np.linalg.norm(x)
    m = np.stack([x, y, np.cross(x, y)], 1)
    return 0.5 * (a + b), m, (shape.radius * t.scale[0], 0.5 * np.linalg.norm(b - a), 0.0)


def reference(shape, o, d, eps=0.0):
    """The float64 reference hit distance of world rays (o, d) with ``shape``."""
    centre, m, size = frame(shape)
    ol, dl = (o - centre) @ m, d @ m
    if isinstance(shape, warprt.Box):
        return ref_box(ol, dl, size, eps)
    return ref_round(ol, dl, size[0], size[1], isinstance(shape, warprt.Capsule), eps)


@pytest.mark.parametrize("scale", [1e-3, 1.0, 1e4])
@pytest.mark.parametrize("kind", sorted(SOLIDS))
def test_hits_agree_with_a_float64_reference(kind, scale):
    make, reach = SOLIDS[kind]
    shape = make(warprt.Transform(translate=(0.3 * scale, scale, -0.2 * scale), rotation_quaternion=Q, scale=scale))
    centre = frame(shape)[0]
    rng = np.random.default_rng(5)
    o, d = rays_at(centre, reach * scale, 4000, rng, inside=400)
    out = warprt.trace_rays(warprt.Scene(shapes=(shape,)), o, d, device="cpu")
    ref = reference(shape, o, d)
    grown, shrunk = reference(shape, o, d, GROW * scale), reference(shape, o, d, -GROW * scale)
    sure = np.isfinite(grown) == np.isfinite(shrunk)
    assert sure.mean() > 0.99
    assert 0.2 < np.isfinite(ref).mean() < 0.9  # both hits and misses
    assert np.array_equal(out["hit"][sure], np.isfinite(ref)[sure])
    both = out["hit"] & np.isfinite(ref) & sure
    # float32: the rays' own coordinates are ~4·reach·scale (L) and the solid's frame is turned
    # in float32, which moves a hit along the ray by its error over cos θ (θ from the normal):
    # measured |Δt|·cos θ <= 5.9e-7·L (capsules), 2.5e-7·L (boxes, cylinders)
    L = 4 * reach * scale
    n = out["normal"][both].astype(np.float64)
    cos = np.abs((n * d[both]).sum(1))
    assert (np.abs(out["t"][both] - ref[both]) * cos).max() < 2e-6 * L
    # the point lies on the surface: off it along the normal by float32 rounding only
    p = out["position"][both].astype(np.float64)
    assert np.abs(((p - (o[both] + ref[both, None] * d[both])) * n).sum(1)).max() < 2e-6 * L
    assert np.abs(np.linalg.norm(n, axis=1) - 1).max() < 1e-6
    pos0, m, size = frame(shape)
    pl, nl = (p - pos0) @ m, n @ m
    if kind == "box":
        axis = np.abs(nl).argmax(1)
        assert np.abs(np.abs(nl).max(1) - 1).max() < 1e-6  # along a local axis
        face = np.take_along_axis(pl, axis[:, None], 1)[:, 0]
        sign = np.sign(np.take_along_axis(nl, axis[:, None], 1)[:, 0])
        np.testing.assert_allclose(face * sign, np.asarray(size)[axis], atol=5e-6 * 4 * reach * scale)
    else:
        r, h = size[0], size[1]
        y = np.clip(pl[:, 1], -h, h)
        radial = pl - np.stack([np.zeros_like(y), y, np.zeros_like(y)], 1)
        dist = np.linalg.norm(radial, axis=1)
        if kind == "capsule":
            expect = radial / dist[:, None]
        else:  # a cap (|y| at h and inside the rim) or the side
            cap = (np.abs(np.abs(pl[:, 1]) - h) < 1e-5 * scale) & (dist < r * (1 - 1e-5))
            expect = np.where(cap[:, None], np.stack([np.zeros_like(y), np.sign(pl[:, 1]), np.zeros_like(y)], 1),
                              radial / dist[:, None])
        assert np.abs(nl - expect).max() < 2e-4


def test_rays_from_inside_find_the_far_side_and_the_range_is_open():
    box = warprt.Box(size=(2.0, 2.0, 2.0))
    scene = warprt.Scene(shapes=(box,))
    out = warprt.trace_rays(scene, [(0, 0, 0), (0, 0, 0), (0, 0, -5)], [(1, 0, 0), (0, -1, 0), (0, 0, 1)],
                            device="cpu")
    np.testing.assert_array_equal(out["t"], [1.0, 1.0, 4.0])
    np.testing.assert_array_equal(out["normal"], [(1, 0, 0), (0, -1, 0), (0, 0, -1)])
    # t_max excludes a hit exactly at t_max; t_min skips the entry and finds the exit
    assert not warprt.trace_rays(scene, [(0, 0, -5)], [(0, 0, 1)], t_max=4.0, device="cpu")["hit"][0]
    assert warprt.trace_rays(scene, [(0, 0, -5)], [(0, 0, 1)], t_min=4.5, device="cpu")["t"][0] == 6.0
    # parallel to a slab, in its plane: inside everywhere or nowhere (no 0 * inf)
    out = warprt.trace_rays(scene, [(-5, 1.0, 0), (-5, 1.5, 0)], [(1, 0, 0), (1, 0, 0)], device="cpu")
    assert out["hit"].tolist() == [True, False] and out["t"][0] == 4.0
    # a cylinder and a capsule along the ray's own axis
    cyl = warprt.Cylinder(start=(0, -1, 0), end=(0, 1, 0), radius=0.5)
    cap = warprt.Capsule(start=(0, -1, 0), end=(0, 1, 0), radius=0.5)
    # from (0.1, 5, 0) straight down: the cap plane y = 1, or the top sphere at y = 1 + sqrt(0.5² - 0.1²)
    for shape, t, n in ((cyl, 4.0, (0, 1, 0)), (cap, 4.0 - math.sqrt(0.24), (0.2, math.sqrt(0.96), 0))):
        out = warprt.trace_rays(warprt.Scene(shapes=(shape,)), [(0.1, 5, 0)], [(0, -1, 0)], device="cpu")
        assert out["t"][0] == pytest.approx(t, abs=1e-6)
        np.testing.assert_allclose(out["normal"][0], n, atol=1e-6)


def test_a_sphere_like_capsule_and_zero_radius():
    """start = end: the capsule is a sphere; radius 0: never hit (as a sphere of radius 0)."""
    ball = warprt.Capsule(start=(0.2, 0.1, 0), end=(0.2, 0.1, 0), radius=0.5)
    rng = np.random.default_rng(1)
    o, d = rays_at(np.array([0.2, 0.1, 0.0]), 0.5, 500, rng)
    a = warprt.trace_rays(warprt.Scene(shapes=(ball,)), o, d, device="cpu")
    b = warprt.trace_rays(warprt.Scene(shapes=(warprt.Sphere(center=(0.2, 0.1, 0), radius=0.5),)), o, d,
                          device="cpu")
    assert np.array_equal(a["hit"], b["hit"]) and np.abs(a["t"][a["hit"]] - b["t"][a["hit"]]).max() < 1e-5
    thin = warprt.Capsule(radius=0.0)
    assert not warprt.trace_rays(warprt.Scene(shapes=(thin,)), o, d, device="cpu")["hit"].any()


def _lit_scene(shape, light_dir, ambient=0.0, **kw):
    return warprt.Scene(
        camera=warprt.Camera(eye=(3.0, 2.5, 3.5), look_at=(0, 0.4, 0), fov=40, width=64, height=48),
        shapes=(warprt.Plane(material="floor"), shape),
        materials={"floor": warprt.Material(kd=0.5), "solid": warprt.Material(kd=(0.8, 0.4, 0.2), **kw)},
        lights=(warprt.DirectionalLight(direction=light_dir, intensity=1.0),), ambient=ambient, render=REGULAR)


@pytest.mark.parametrize("scale", [1e-3, 1.0, 1e4])
def test_lambert_faces_and_hard_shadows_match_the_closed_form(scale):
    """Each pixel: the surface its centre ray sees (trace_rays) shaded kd·max(0, n·l) when the
    float64 shadow ray towards the light misses every solid, else 0; no acne on the solids (their
    own shadow rays leave them) at any scale."""
    light = np.array([0.6, -1.0, 0.4])  # the shadows fall towards the camera
    l = -light / np.linalg.norm(light)
    t = warprt.Transform(translate=(0, 0.5 * scale, 0), rotate=(10, 35, -5), scale=scale)
    for shape in (warprt.Box(size=(1.0, 0.8, 0.7), transform=t, material="solid"),
                  warprt.Capsule(start=(-0.4, 0, 0), end=(0.4, 0.2, 0), radius=0.3, transform=t, material="solid"),
                  warprt.Cylinder(start=(0, -0.4, 0), end=(0, 0.4, 0.2), radius=0.4, transform=t, material="solid")):
        scene = _lit_scene(shape, tuple(light))
        scene = scene.with_camera(eye=tuple(np.array(scene.camera.eye) * scale),
                                  look_at=tuple(np.array(scene.camera.look_at) * scale))
        img = warprt.render(scene, device="cpu", progress=False)
        o, d = warprt.camera_rays(scene, device="cpu")
        hit = warprt.trace_rays(scene, o, d, device="cpu")
        p = hit["position"].astype(np.float64)
        n = hit["normal"].astype(np.float64)
        kd = np.where((hit["shape"] == 1)[:, None], [0.8, 0.4, 0.2], 0.5)
        expect = kd * np.maximum(0, n @ l)[:, None]
        blocked = np.isfinite(reference(shape, p + n * 1e-4 * scale, np.tile(l, (len(p), 1))))
        expect[blocked] = 0
        # pixels whose shadow ray passes within float32 reach of the silhouette may go either way
        unsure = np.isfinite(reference(shape, p + n * 1e-4 * scale, np.tile(l, (len(p), 1)), 3e-4 * scale)) != \
            np.isfinite(reference(shape, p + n * 1e-4 * scale, np.tile(l, (len(p), 1)), -3e-4 * scale))
        got = img.reshape(-1, 3)
        ok = hit["hit"] & ~unsure
        assert (hit["shape"] == 1).sum() > 100 and blocked[hit["shape"] == 0].sum() > 50  # solid and shadow seen
        # float32 shading: measured at most 3e-6
        assert np.abs(got[ok] - expect[ok]).max() < 2e-5, (shape, np.abs(got[ok] - expect[ok]).max())


def test_a_transparent_box_passes_kt_squared():
    """A point light seen through a glass box (two crossings): the floor under it gets kt² of the
    light, exactly; beside it, all of it."""
    kt = 0.6
    box = warprt.Box(center=(0, 1.5, 0), size=(1.0, 0.4, 1.0), material="glass")
    scene = warprt.Scene(
        camera=warprt.Camera(eye=(0, 6, 0.01), look_at=(0, 0, 0), fov=50, width=41, height=41),
        shapes=(warprt.Plane(material="floor"), box),
        materials={"floor": warprt.Material(kd=0.5), "glass": warprt.Material(kd=0.0, transparency=kt, ior=1.0)},
        lights=(warprt.PointLight(position=(0, 3, 0), intensity=1.0),), render=warprt.RenderSettings(
            sampler="regular", spp=1, max_depth=0))
    # the all-features kernel the suite compiles anyway (test_lambert_faces... keeps `solids` alone)
    img = warprt.Renderer(scene, device="cpu", features=warprt.Features.full()).render(progress=False).image
    o, d = warprt.camera_rays(scene, device="cpu")
    hit = warprt.trace_rays(scene, o, d, device="cpu")
    p = hit["position"].astype(np.float64)
    floor = hit["shape"] == 0
    to_l = np.array([0, 3.0, 0]) - p
    l = to_l / np.linalg.norm(to_l, axis=1, keepdims=True)
    through = np.isfinite(reference(box, p, l))
    unsure = np.isfinite(reference(box, p, l, 1e-4)) != np.isfinite(reference(box, p, l, -1e-4))
    expect = 0.5 * l[:, 1] * np.where(through, kt * kt, 1.0)
    got = img.reshape(-1, 3)[:, 0]
    ok = floor & ~unsure
    assert through[ok].sum() > 20 and (~through[ok]).sum() > 20
    np.testing.assert_allclose(got[ok], expect[ok], rtol=2e-6)


def test_moving_box_coverage_is_the_fraction_of_the_shutter_it_covers():
    """A box sliding along x over the shutter: the coverage AOV of a pixel whose ray meets the
    box's path is the fraction of time the box is on that ray (stratified time, 64 strata: within
    one stratum)."""
    box = warprt.Box(size=(1.0, 1.0, 1.0), transform=warprt.Transform(translate=(-1.0, 0, 0)),
                     transform_end=warprt.Transform(translate=(1.0, 0, 0)))
    scene = warprt.Scene(camera=warprt.Camera(eye=(0, 0, 10), look_at=(0, 0, 0), fov=1e-3, width=1, height=1),
                         shapes=(box,), render=warprt.RenderSettings(sampler="stratified", spp=64))
    for x in (-1.2, -0.3, 0.0, 0.7, 1.45):
        s = scene.with_camera(eye=(x, 0, 10), look_at=(x, 0, 0))
        cov = float(warprt.Renderer(s, device="cpu", features=warprt.Features.full()).render(
            progress=False, aovs=("coverage",)).aovs["coverage"][0, 0])
        # the ray x is inside [c - 0.5, c + 0.5] for c = -1 + 2 t: t in [(x - 0.5 + 1) / 2, (x + 0.5 + 1) / 2]
        lo, hi = np.clip([(x + 0.5) / 2, (x + 1.5) / 2], 0, 1)
        assert abs(cov - (hi - lo)) <= 1 / 64 + 1e-9, (x, cov, hi - lo)


def test_batched_solids_equal_single_renders_of_each_world():
    """Per-world poses compose with each solid's own transform (pose ∘ transform), as for meshes."""
    t = warprt.Transform(translate=(0.2, 0.0, 0.1), rotate=(0, 30, 10))
    shapes = (warprt.Plane(material="floor"),
              warprt.Box(center=(0.1, 0.0, 0.0), size=(0.6, 0.5, 0.4), transform=t, material="solid"),
              warprt.Capsule(start=(-0.3, 0, 0), end=(0.3, 0, 0), radius=0.2, transform=t, material="solid"),
              warprt.Cylinder(start=(0, -0.2, 0), end=(0, 0.2, 0), radius=0.25, transform=t, material="solid"))
    scene = _lit_scene(shapes[1], (-0.5, -1, -0.3), ambient=0.1).replace(shapes=shapes)
    rng = np.random.default_rng(2)
    W = 3
    poses = np.zeros((W, 4, 7))
    poses[..., 6] = 1.0
    for w in range(W):
        for j in (1, 2, 3):
            poses[w, j, :3] = [rng.uniform(-1, 1), rng.uniform(0.3, 0.7), rng.uniform(-1, 1)]
            poses[w, j, 3:] = _quat(rng.normal(size=4))
    br = BatchRenderer(scene, worlds=W, cameras=1, device="cpu")
    br.set_shape_poses(poses)
    batch = br.render(spp=1).numpy()
    flipped = 0
    for w in range(W):
        moved = [shapes[0]]
        for j in (1, 2, 3):
            # pose ∘ t: rotate by both, then translate t's offset turned by the pose
            pose = warprt.Transform.from_quaternion(poses[w, j, 3:], translate=poses[w, j, :3])
            q = quat_mul(poses[w, j, 3:], t.quaternion())
            moved.append(dataclasses.replace(shapes[j], transform=warprt.Transform.from_quaternion(
                q, translate=pose.apply_point(t.translate))))
        ref = warprt.render(scene.replace(shapes=tuple(moved)), device="cpu", progress=False)
        diff = np.abs(batch[w, 0] - ref).max(axis=2)
        bad = diff > 1e-4
        flipped += int(bad.sum())
        assert diff[~bad].max() < 2e-5, diff[~bad].max()
        if w:
            assert np.abs(batch[w, 0] - batch[0, 0]).max() > 0.05
    assert flipped <= 4, flipped


def test_solids_in_scene_files_and_their_errors():
    scene = warprt.scene_from_string("""
[camera]
eye = [0, 1, 5]
[[shapes]]
type = "box"
center = [0, 0.5, 0]
size = [1, 1, 2]
transform = { rotate = [0, 45, 0] }
[[shapes]]
type = "capsule"
start = [1, 0, 0]
end = [1, 1, 0]
radius = 0.2
[[shapes]]
type = "cylinder"
start = [-1, 0, 0]
end = [-1, 1, 0]
radius = 0.3
transform_end = { translate = [0, 0.5, 0] }
""")
    assert [type(s).__name__ for s in scene.shapes] == ["Box", "Capsule", "Cylinder"]
    assert features_of(scene) == warprt.Features(solids=True, motion=True, analytic_bvh=True)  # 3 bounded shapes
    for bad, field in ((dict(size=(1, 0, 1)), "size[1]"), (dict(size=(1, 1)), "size")):
        with pytest.raises(SceneError) as e:
            warprt.Box(**bad)
        assert field in str(e.value)
    with pytest.raises(SceneError, match="uniform"):
        warprt.Capsule(transform=warprt.Transform(scale=(1, 2, 1)))
    with pytest.raises(SceneError, match="no height"):
        warprt.Cylinder(start=(0, 1, 0), end=(0, 1, 0))
    with pytest.raises(SceneError, match="scale"):
        warprt.Box(transform_end=warprt.Transform(scale=2.0))
    with pytest.raises(SceneError, match="radius"):
        warprt.Capsule(radius=-1.0)
    with pytest.raises(SceneError, match="did you mean 'radius'"):
        warprt.Cylinder(radiu=1.0)
