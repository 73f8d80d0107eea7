"""Shadow rays from and through triangle meshes against an exact float64 shadow test.

Two kinds of scene, the two on which warprt came out a shade darker than Mitsuba 3 (docs/
architecture.md, "Meshes against an exact shadow test"): a large closed bumpy mesh on the ground
under rectangle lights, and instanced, non-uniformly scaled and turned meshes under a point
light alone. Each light is rendered on its own with the ``regular`` sampler at 1 spp (the
pixel-centre ray, the light's one sample), so a pixel is the unshadowed direct light U times a
visibility of 0 or 1; a rectangle light is 1e-4 across, so where its shadow ray goes is known to
that. The host finds each pixel's hit and the shadow segment towards the light in float64
(tests/exact_rays.py: Möller and Trumbore over every triangle, the instances posed in float64)
and decides visibility with no spawn offset at all: the exact answer for the polygonal surface.

A pixel's answer can only depend on the offset where the segment passes within a few offsets of
another triangle (a grazing ray over a crease or a silhouette): the test also decides it from
the point moved off the surface by STABLE_OFFSET (8x warprt's largest spawn offset there,
2^-17 of the coordinates, docs/architecture.md "Robust spawning") and calls the pixel unstable
where the two answers differ. On every stable pixel warprt's visibility must be the exact one
(no false shadow from a self-hit or a traversal that stops early, no leak from one that misses a
triangle); unstable pixels are rare (measured at most 0.2% of the lit ones) and bound the mean
difference. The traversals these scenes take: the CPU tree copy, shadow packets, interior balls,
normal cones, escaping faces and horizons, camera bins (docs/architecture.md, accel.py).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

import warprt
from benchmarks.corpus_scenes import torus

from exact_rays import Triangles

RES = 48
UNSTABLE_SHARE = 0.006  # of the pixels checked: 3x the measured 0.2%


def bumpy_torus(n_major: int, n_minor: int, major: float, minor: float, bumps: float):
    """A closed torus around y (quads split in two, consistently wound) with bumps on its tube:
    concave creases everywhere, for shadow rays to graze."""
    return torus(n_major, n_minor, major, minor, bumps, waves=(6, 4))


MATERIALS = {"ground": warprt.Material(kd=0.6, ka=0.0), "mesh": warprt.Material(kd=(0.8, 0.55, 0.3), ka=0.0)}
KD = {0: 0.6, 1: 0.8}  # red channel: the ground, a mesh


def big_mesh_scene():
    """6,144 triangles: enough for shadow packets, interior balls, normal cones, escape horizons
    and camera bins."""
    v, f = bumpy_torus(64, 48, major=0.9, minor=0.35, bumps=0.12)
    v = v + [0.0, 0.35 * 1.12 + 0.02, 0.0]
    return warprt.Scene(camera=warprt.Camera(eye=(0.0, 2.2, 3.0), look_at=(0.0, 0.25, 0.0), fov=45.0, width=RES,
                                             height=RES),
                        shapes=(warprt.Plane(material="ground"), warprt.Mesh(vertices=v, faces=f, material="mesh")),
                        materials=MATERIALS, render=warprt.RenderSettings(sampler="regular", spp=1))


def tiny_rect_lights():
    """Points spread over a 2 x 2 rectangle light above the mesh, and one in the torus's hole
    (the torus beyond it, along the shadow rays of its inner side), each a light 1e-4 across
    facing down."""
    s = 1e-4
    points = [(-1.5 + 2 * a, 3.0, -1.0 + 2 * b) for a, b in ((0.5, 0.5), (0.05, 0.95), (0.9, 0.2))] + [(0.05, 0.45, 0.0)]
    return [warprt.RectLight(corner=tuple(np.subtract(q, s / 2)), edge1=(s, 0.0, 0.0), edge2=(0.0, 0.0, s), radiance=1e8)
            for q in points]


def instanced_scene():
    """Twelve instances of one 1,024-triangle mesh, each turned and scaled differently on each axis."""
    v, f = bumpy_torus(32, 16, major=0.5, minor=0.18, bumps=0.15)
    rng = np.random.default_rng(1)
    shapes = [warprt.Plane(material="ground")]
    for k in range(12):
        t = warprt.Transform(translate=(-1.6 + (k % 4) * 1.05, 0.55, -1.2 + (k // 4) * 1.1),
                             rotate=tuple(rng.uniform(-180, 180, 3)), scale=tuple(rng.uniform(0.5, 1.6, 3)))
        shapes.append(warprt.Mesh(vertices=v, faces=f, material="mesh", transform=t))
    return warprt.Scene(camera=warprt.Camera(eye=(0.0, 3.8, 4.2), look_at=(0.0, 0.3, 0.0), fov=50.0, width=RES,
                                             height=RES),
                        shapes=tuple(shapes), materials=MATERIALS,
                        render=warprt.RenderSettings(sampler="regular", spp=1))


def point_lights(scene):
    """Three around the instances, one low between them, and one 2e-3 above an instance's
    surface: a shadow segment must end at its light, not at the triangle just past it."""
    mesh = Triangles(world_triangles(scene)[0])
    t, _, _ = mesh.nearest(np.array([[0.4, 3.0, 0.35]]), np.array([[0.0, -1.0, 0.0]]))
    assert np.isfinite(t[0])
    close = (0.4, 3.0 - float(t[0]) + 2e-3, 0.35)
    return [warprt.PointLight(position=p, intensity=10.0, falloff="inverse_square")
            for p in ((1.0, 5.0, 2.0), (-4.0, 3.0, -1.0), (3.0, 1.2, 3.5), (-0.55, 0.45, -0.65), close)]


def world_triangles(scene):
    """Every mesh's triangles in world space, float64 (the float32 vertices warprt holds, posed by
    the transform in float64), and the shape each belongs to."""
    tris, owner = [], []
    for k, s in enumerate(scene.shapes):
        if isinstance(s, warprt.Mesh):
            v = np.asarray(s.vertices, np.float32).astype(np.float64)
            if s.transform is not None:
                m = s.transform.matrix()
                v = v @ m[:3, :3].T + m[:3, 3]
            tris.append(v[np.asarray(s.faces)])
            owner.append(np.full(len(s.faces), k))
    return np.concatenate(tris), np.concatenate(owner)


def surface_points(scene, renderer, mesh: Triangles):
    """Each pixel-centre ray's hit in float64 (the ground y = 0 or a triangle): point, normal turned
    to the camera, the triangle (-1: the ground), and whether warprt's ray query finds the same
    facet (same distance, same normal) away from edges."""
    o, d = warprt.camera_rays(scene)
    o64, d64 = o.astype(np.float64), d.astype(np.float64)
    d64 /= np.linalg.norm(d64, axis=1, keepdims=True)
    tm, tri, margin = mesh.nearest(o64, d64)
    with np.errstate(divide="ignore", invalid="ignore"):
        tg = np.where(d64[:, 1] < 0, -o64[:, 1] / d64[:, 1], np.inf)
    on_mesh = tm < tg
    t = np.where(on_mesh, tm, tg)
    p = o64 + np.where(np.isfinite(t), t, 0)[:, None] * d64
    clustered = np.argsort(mesh.index)  # original triangle -> its row in mesh.normals
    n = np.where(on_mesh[:, None], mesh.normals[clustered[np.maximum(tri, 0)]], [0.0, 1.0, 0.0])
    n = np.where(((n * d64).sum(1) > 0)[:, None], -n, n)
    hits = warprt.trace_rays(renderer, o, d)
    nw = hits["normal"].astype(np.float64)
    nw = np.where(((nw * d64).sum(1) > 0)[:, None], -nw, nw)
    same = (np.isfinite(t) & hits["hit"] & (np.abs(hits["t"] - t) <= 1e-5 * t) & ((nw * n).sum(1) > 1 - 1e-6)
            & (margin > 1e-5))
    return p, n, np.where(on_mesh, tri, -1), same


STABLE_OFFSET = 8 * 2.0 ** -17  # of (1 + the largest coordinate): see the module docstring


def check_shadows(scene, lights, what):
    tris, owner = world_triangles(scene)
    mesh = Triangles(tris)
    renderer = warprt.Renderer(scene.replace(lights=lights[:1]), device="cpu")
    p, n, tri, same = surface_points(scene, renderer, mesh)
    assert same.mean() > 0.9, what  # (pixels on an edge between two facets are left out)
    kd = np.where(tri >= 0, KD[1], KD[0])
    shift = n * (STABLE_OFFSET * (1.0 + np.abs(p).max(1)))[:, None]
    checked = unstable = lit = 0
    for k, light in enumerate(lights):
        renderer.update(scene.replace(lights=(light,)))
        image = renderer.render(spp=1, progress=False).image
        value = image[..., 0].reshape(-1).astype(np.float64)
        if isinstance(light, warprt.PointLight):
            target = np.asarray(light.position, np.float64)
            to = target - p
            dist = np.linalg.norm(to, axis=1)
            cos = (n * to).sum(1) / dist
            unshadowed = kd * light.intensity[0] * np.maximum(cos, 0.0) / dist ** 2
            targets = [target]
        else:
            corner, e1, e2 = (np.asarray(x, np.float64) for x in (light.corner, light.edge1, light.edge2))
            target = corner + 0.5 * (e1 + e2)
            nl = np.cross(e1, e2)
            area = np.linalg.norm(nl)
            to = target - p
            dist = np.linalg.norm(to, axis=1)
            cos = (n * to).sum(1) / dist
            cos_l = -(nl / area * to).sum(1) / dist
            unshadowed = (kd * light.radiance[0] * area * np.maximum(cos, 0) * np.maximum(cos_l, 0)
                          / (math.pi * dist ** 2))
            targets = [target, corner, corner + e1 + e2]
        ok = same & (cos > 0.02) & (unshadowed > 0)
        ratio = value / np.where(ok, unshadowed, 1.0)
        # one light sample, one point: a pixel is lit or not (a light 1e-4 across: to 1e-3)
        assert ((ratio[ok] < 1e-6) | (np.abs(ratio[ok] - 1) < 1e-3)).all(), (what, k, np.sort(ratio[ok])[:5])
        idx = np.nonzero(ok)[0]
        answers = []
        for origin in (p[idx], p[idx] + shift[idx]):
            for q in targets:
                seg = q - origin
                length = np.linalg.norm(seg, axis=1)
                blocked, margin = mesh.blocked(origin, seg / length[:, None], length, tri[idx])
                answers.append((~blocked, margin))
        exact = answers[0][0]
        steady = np.all([a == exact for a, _ in answers], axis=0) & np.all([m > 1e-6 for _, m in answers], axis=0)
        rendered = ratio[idx] > 0.5
        wrong = steady & (rendered != exact)
        assert not wrong.any(), (
            f"{what}, light {k}: {int((wrong & exact).sum())} pixels shadowed that the exact test lights, "
            f"{int((wrong & ~exact).sum())} lit that it shadows (of {int(steady.sum())})")
        # the doubtful pixels bound the difference of the means
        u = unshadowed[idx]
        assert abs((u * rendered).sum() - (u * exact).sum()) <= (u * ~steady).sum(), (what, k)
        checked += len(idx)
        unstable += int((~steady).sum())
        lit += int(exact.sum())
    assert checked > 0.5 * len(p) * len(lights) and lit > 0.25 * checked, (what, checked, lit)
    assert unstable <= UNSTABLE_SHARE * checked, (what, unstable, checked)


def test_a_large_closed_mesh_under_rectangle_lights_shadows_as_the_exact_test():
    check_shadows(big_mesh_scene(), tiny_rect_lights(), "closed mesh, rectangle lights")


def test_instanced_scaled_meshes_under_a_point_light_shadow_as_the_exact_test():
    scene = instanced_scene()
    check_shadows(scene, point_lights(scene), "instanced meshes, point light")
