"""Whole images against a small float64 ray tracer written here in NumPy, independently of the
device code: a smooth-shaded coarse mesh, a sphere and a ground plane under two inverse-square
point lights (one behind the objects), Blinn-Phong with ambient, hard shadows, pixel centres.

What it pins down that closed forms of single shapes do not:

* **smooth (interpolated) normals**: barycentric weights in the right order (w0 = 1 - u - v on
  the first vertex), area-weighted vertex normals, the fall-back to the geometric normal when the
  shading normal faces away from the viewer;
* **the n·l clamp of the shading normal**: on a smooth mesh near a light's terminator the
  geometric normal sees the light (ng·l > 0) while the shading normal does not (n·l < 0); that
  light must add nothing there (not a negative diffuse term, not a highlight);
* **render.t_min and render.t_max** for camera rays: the nearest hit in (t_min, t_max), seen
  from inside a sphere when t_min cuts through it.

Pixels whose answer a float32 renderer cannot decide (the hit shape, the shadow or a light's
side flip when the ray direction or the light moves by PERTURB) are left out; on the rest the
image must match to float32 accuracy.
"""

from __future__ import annotations

import importlib
import math

import numpy as np
import pytest

import warprt
from warprt.query import camera_rays

PERTURB = 2e-5  # relative: a pixel whose answer changes under this is undecidable in float32
W, H = 64, 48
AMBIENT = 0.05
LIGHTS = [((2.0, 3.0, 2.5), (9.0, 8.0, 7.0)),  # front, right
          ((-1.5, 1.2, -3.0), (6.0, 6.0, 8.0))]  # behind the objects: terminators face the camera
MATS = {"mesh": dict(ka=0.3, kd=(0.7, 0.5, 0.02), ks=0.5, p=8.0),  # blue: almost all highlight
        "ball": dict(ka=0.3, kd=(0.2, 0.4, 0.8), ks=0.6, p=80.0),
        "ground": dict(ka=0.3, kd=(0.6, 0.6, 0.6), ks=0.0, p=1.0)}
SPHERE_C, SPHERE_R = np.array([0.85, 0.55, 0.2]), 0.55
MESH_C, MESH_R = np.array([-0.7, 0.75, -0.1]), 0.75


def icosphere():
    """A once-subdivided icosahedron (80 faces): coarse, so shading and face normals differ by
    up to ~20°."""
    t = (1 + math.sqrt(5)) / 2
    v = [(-1, t, 0), (1, t, 0), (-1, -t, 0), (1, -t, 0), (0, -1, t), (0, 1, t), (0, -1, -t), (0, 1, -t),
         (t, 0, -1), (t, 0, 1), (-t, 0, -1), (-t, 0, 1)]
    f = [(0, 11, 5), (0, 5, 1), (0, 1, 7), (0, 7, 10), (0, 10, 11), (1, 5, 9), (5, 11, 4), (11, 10, 2), (10, 7, 6),
         (7, 1, 8), (3, 9, 4), (3, 4, 2), (3, 2, 6), (3, 6, 8), (3, 8, 9), (4, 9, 5), (2, 4, 11), (6, 2, 10),
         (8, 6, 7), (9, 8, 1)]
    verts = [np.array(p, float) / np.linalg.norm(p) for p in v]
    cache = {}

    def mid(a, b):
        key = (min(a, b), max(a, b))
        if key not in cache:
            m = verts[a] + verts[b]
            verts.append(m / np.linalg.norm(m))
            cache[key] = len(verts) - 1
        return cache[key]

    faces = []
    for a, b, c in f:
        ab, bc, ca = mid(a, b), mid(b, c), mid(c, a)
        faces += [(a, ab, ca), (b, bc, ab), (c, ca, bc), (ab, bc, ca)]
    return np.array(verts) * MESH_R + MESH_C, np.array(faces)


def scene(t_min=0.0, t_max=math.inf):
    v, f = icosphere()
    return warprt.Scene(
        camera=warprt.Camera(eye=(0.3, 1.4, 3.6), look_at=(0.0, 0.6, 0.0), fov=42.0, width=W, height=H),
        shapes=(warprt.Plane(material="ground"), warprt.Sphere(center=tuple(SPHERE_C), radius=SPHERE_R, material="ball"),
                warprt.Mesh(vertices=v, faces=f, material="mesh", smooth=True)),
        materials={k: warprt.Material(**m) for k, m in MATS.items()},
        lights=tuple(warprt.PointLight(position=p, intensity=i, falloff="inverse_square") for p, i in LIGHTS),
        ambient=AMBIENT,
        render=warprt.RenderSettings(spp=1, sampler="regular", t_min=t_min, t_max=t_max))


# --- the float64 reference -------------------------------------------------------------------------


def vertex_normals64(v, f):
    """Area-weighted: the sum of the unnormalised face normals around each vertex."""
    n = np.zeros_like(v)
    fn = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    for k in range(3):
        np.add.at(n, f[:, k], fn)
    return n / np.linalg.norm(n, axis=1, keepdims=True)


def hits(o, d, v, f, t_lo, t_hi):
    """Nearest hit per ray over plane y = 0, the sphere and the triangles (Möller-Trumbore):
    (t, shape id 0/1/2, face, b1, b2), t = inf for none."""
    n = len(o)
    best = np.full(n, np.inf)
    shape = np.full(n, -1)
    face = np.full(n, -1)
    b1 = np.zeros(n)
    b2 = np.zeros(n)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = -o[:, 1] / d[:, 1]
    t_hi = np.broadcast_to(np.asarray(t_hi, float), (n,))
    ok = (t > t_lo) & (t < t_hi) & (t < best)
    best[ok], shape[ok] = t[ok], 0
    oc = o - SPHERE_C
    b = np.sum(oc * d, 1)
    c = np.sum(oc * oc, 1) - SPHERE_R ** 2
    disc = b * b - c
    sq = np.sqrt(np.maximum(disc, 0))
    for t in (-b - sq, -b + sq):
        ok = (disc >= 0) & (t > t_lo) & (t < t_hi) & (t < best)
        best[ok], shape[ok] = t[ok], 1
    v0, e1, e2 = v[f[:, 0]], v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]]
    for k in range(len(f)):
        pv = np.cross(d, e2[k])
        det = pv @ e1[k]
        with np.errstate(divide="ignore", invalid="ignore"):
            inv = 1.0 / det
            tv = o - v0[k]
            u = np.sum(tv * pv, 1) * inv
            qv = np.cross(tv, e1[k])
            w = np.sum(qv * d, 1) * inv
            t = (qv @ e2[k]) * inv
        ok = (det != 0) & (u >= 0) & (w >= 0) & (u + w <= 1) & (t > t_lo) & (t < t_hi) & (t < best)
        best[ok], shape[ok], face[ok], b1[ok], b2[ok] = t[ok], 2, k, u[ok], w[ok]
    return best, shape, face, b1, b2


def shade64(o, d, t_lo, t_hi, light_shift=np.zeros(3)):
    """Radiance at pixel centres, and per pixel a key of every discrete decision (hit shape and
    face, each light's side and shadow) so that undecidable pixels can be found."""
    v, f = icosphere()
    vn = vertex_normals64(v, f)
    t, shape, face, b1, b2 = hits(o, d, v, f, t_lo, t_hi)
    n = len(o)
    rgb = np.zeros((n, 3))
    keys = np.stack([shape, face], 1).tolist()
    hit = np.isfinite(t)
    p = o + d * np.where(hit, t, 0)[:, None]
    ng = np.zeros((n, 3))
    ns = np.zeros((n, 3))
    ng[shape == 0] = (0, 1, 0)
    s1 = shape == 1
    ng[s1] = (p[s1] - SPHERE_C) / SPHERE_R
    m = shape == 2
    fm = face[m]
    fn = np.cross(v[f[fm, 1]] - v[f[fm, 0]], v[f[fm, 2]] - v[f[fm, 0]])
    ng[m] = fn / np.linalg.norm(fn, axis=1, keepdims=True)
    ns[:] = ng
    w0 = 1 - b1[m] - b2[m]
    sn = w0[:, None] * vn[f[fm, 0]] + b1[m][:, None] * vn[f[fm, 1]] + b2[m][:, None] * vn[f[fm, 2]]
    ns[m] = sn / np.linalg.norm(sn, axis=1, keepdims=True)
    back = np.sum(d * ng, 1) > 0
    ng[back] *= -1
    ns[back] *= -1
    away = np.sum(ns * d, 1) > 0
    ns[away] = ng[away]
    names = ["ground", "ball", "mesh"]
    idx = np.nonzero(hit)[0]
    mat_of = [MATS[names[k]] for k in shape[idx]]
    kd, ks, ka = (np.array([np.broadcast_to(np.asarray(m[k], float), 3) for m in mat_of]).reshape(-1, 3)
                  for k in ("kd", "ks", "ka"))
    expo = np.array([m["p"] for m in mat_of])
    col = ka * AMBIENT
    decisions = []
    for lp, li in LIGHTS:
        to_l = np.asarray(lp, float) + light_shift - p[idx]
        dist = np.linalg.norm(to_l, axis=1)
        l = to_l / dist[:, None]
        side = np.sum(ng[idx] * l, 1) > 0
        # shadow rays: any shape strictly between (the point's own surface excluded by a margin far
        # beyond float32 error at this scale, and far below any real gap)
        ts, *_ = hits(p[idx] + ng[idx] * 1e-7, l, v, f, 1e-6, dist - 1e-6)
        lit = side & ~np.isfinite(ts)
        decisions += [side, lit]
        ndl = np.sum(ns[idx] * l, 1)
        hv = l - d[idx]
        hv /= np.linalg.norm(hv, axis=1, keepdims=True)
        spec = np.maximum(np.sum(ns[idx] * hv, 1), 0.0) ** expo
        f_ = kd * ndl[:, None] + ks * spec[:, None]
        use = lit & (ndl > 0)
        col[use] += f_[use] * np.asarray(li, float) / dist[use, None] ** 2
    rgb[idx] = col
    for k, i in enumerate(idx):
        keys[i] += [int(dec[k]) for dec in decisions]
    return rgb, keys


def perturbed(d, k):
    """Directions turned by PERTURB about two axes (k = 0..3)."""
    axis = np.array([[1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 1, 0]], float)[k]
    q = d + PERTURB * np.cross(axis, d) * (1 if k % 2 else -1)
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def reference(sc):
    o, d = (x.astype(np.float64) for x in camera_rays(sc))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    t_lo, t_hi = sc.render.t_min, sc.render.t_max
    rgb, keys = shade64(o, d, t_lo, t_hi)
    decidable = np.ones(len(o), bool)
    for k in range(4):
        _, kk = shade64(o, perturbed(d, k), t_lo, t_hi)
        decidable &= np.array([a == b for a, b in zip(keys, kk)])
    for shift in (np.array([1, 1, 1]) * PERTURB * 4, -np.array([1, -1, 1]) * PERTURB * 4):
        _, kk = shade64(o, d, t_lo, t_hi, light_shift=shift)
        decidable &= np.array([a == b for a, b in zip(keys, kk)])
    return rgb.reshape(H, W, 3), decidable.reshape(H, W), keys


@pytest.mark.parametrize("alone", [False, True], ids=["packets", "one by one"])
@pytest.mark.parametrize("t_min, t_max", [(0.0, math.inf), (3.3, math.inf), (0.0, 3.6), (3.3, 4.4)],
                         ids=["full range", "t_min inside the objects", "t_max", "both"])
def test_image_matches_the_float64_tracer(t_min, t_max, alone, monkeypatch):
    """Camera rays in packets (a row's pixels, 8 at a time) and, with one pixel a thread at 1
    spp, each ray alone."""
    if alone:
        monkeypatch.setattr(importlib.import_module("warprt.render"), "pixels_per_thread", lambda dev, width: 1)
    sc = scene(t_min, t_max)
    img = warprt.Renderer(sc, device="cpu").render(progress=False).image.astype(np.float64)
    ref, ok, keys = reference(sc)
    shapes = np.array([k[0] for k in keys]).reshape(H, W)
    err = np.abs(img - ref).max(axis=2)
    tol = 2e-5 * np.abs(ref).max(axis=2) + 1e-6  # float32 shading of values O(1), highlights p = 80
    bad = ok & (err > tol)
    print(f"\n{ok.sum()} of {ok.size} pixels decidable; max error there {err[ok].max():.2e}; "
          f"shapes seen {np.unique(shapes[ok]).tolist()}")
    assert ok.mean() > 0.9
    assert not bad.any(), f"{bad.sum()} pixels differ, worst {err[bad].max():.3g} at {np.argwhere(bad)[:5].tolist()}"
    # the scene does what it is for: every shape seen, and where the cut is, the insides
    seen = set(np.unique(shapes[ok]).tolist())
    assert {0, 1, 2} <= seen or t_max < 4


def test_smooth_mesh_has_pixels_where_only_the_geometric_normal_sees_a_light():
    """The reference scene exercises the n·l clamp: pixels on the mesh where a light passes the
    geometric test but the shading normal faces away from it (without the clamp they would get
    a negative diffuse term)."""
    sc = scene()
    o, d = (x.astype(np.float64) for x in camera_rays(sc))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    v, f = icosphere()
    vn = vertex_normals64(v, f)
    t, shape, face, b1, b2 = hits(o, d, v, f, 0.0, math.inf)
    m = shape == 2
    p = o[m] + d[m] * t[m, None]
    fm = face[m]
    fn = np.cross(v[f[fm, 1]] - v[f[fm, 0]], v[f[fm, 2]] - v[f[fm, 0]])
    ng = fn / np.linalg.norm(fn, axis=1, keepdims=True)
    sn = (1 - b1[m] - b2[m])[:, None] * vn[f[fm, 0]] + b1[m, None] * vn[f[fm, 1]] + b2[m, None] * vn[f[fm, 2]]
    count = 0
    for lp, _ in LIGHTS:
        l = np.asarray(lp) - p
        count += int(((np.sum(ng * l, 1) > 1e-3) & (np.sum(sn * l, 1) < -1e-3)).sum())
    assert count >= 10, count
