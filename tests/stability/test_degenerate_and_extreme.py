"""Degenerate geometry and extreme values: zero-area and sliver triangles, NaN/Inf vertices,
zero-area lights and zero-radius shapes, coincident surfaces, extreme Phong exponents, extreme
light intensities and many lights.

Failure modes, the naive method that shows each one, and what warprt does:

* **zero-area faces**: the textbook face normal normalize(e1 × e2) of a zero-area face is 0/0 =
  NaN, which poisons every pixel it shades. warprt refuses such faces (``degenerate="error"``,
  the default: ``SceneError`` on ``shapes[i].faces`` naming the first bad face) or drops them
  with a warning (``"drop"``); the rest of the mesh renders exactly as the clean mesh.
* **sliver triangles** (aspect ratio 1e6): Möller-Trumbore as published (an absolute EPSILON of
  1e-6 on the determinant) takes a small sliver for a ray parallel to it and misses it
  everywhere. Warp's ray-triangle test hits every ray whose float64 crossing lies inside, with
  t within 5e-7 relative of the closed form, also on the shared diagonal of two slivers.
* **NaN/Inf vertices** (Python arrays, TOML ``nan``/``inf``, mesh files) raise ``SceneError``
  naming ``shapes[i].vertices`` and the first bad vertex.
* **zero-area lights**: a rectangle light with a zero or parallel edge is a ``SceneError``
  (edge1 / edge2); a sphere or disk light of radius 0 contributes nothing (each light sample acts
  as a point light of intensity Le·cosθ'·dA/π, and dA = 0) and is never hit, so the image is the
  ambient term exactly; a small radius r tends to the point-light limit, a point light of
  intensity Le·r² with inverse-square falloff. A zero-radius sphere or disk is never hit. The
  textbook rectangle inside test divides by |e1 × e2|², which underflows to 0 for a tiny
  rectangle: a = 0/0 = NaN, and NaN passes the rejection test ``a < 0 or a > 1``.
* **coincident surfaces**: the nearest hit must be strictly nearer to replace the current one,
  and the shapes are tested in the order spheres, planes, rectangles, disks, meshes (each kind in
  scene order). Coincident shapes with the same representation (two equal planes, rectangles,
  disks, spheres, or two instances of one mesh) compute the same t bit for bit, so the first one
  listed wins at every pixel; a plane, rectangle and disk on the same axis-aligned plane also
  compute equal t and the kind order decides. A plane and a mesh on the same plane do *not* tie
  cleanly: Warp's triangle t differs from the plane's by a few ulps either way, and with a strict
  test the mesh won about a fifth of the pixels in a noisy pattern. A mesh hit must therefore be
  nearer than an analytic hit by 2^-17·t (the spawn-offset factor) to replace it: analytic
  shapes win exact ties, a mesh lifted beyond the band wins.
* **extreme Phong exponents**: pow(n·h, p) in float32 overflows (n·h of float32 unit vectors is
  1 + 2^-23 at the highlight, and (1 + 2^-23)^p is Inf for p > 7.4e8; p beyond the float32 range is
  stored as Inf, and exp(Inf·log 1) = exp(NaN)); exp(p·log x) at p = 0, x = 0 is NaN. warprt's
  phong_power is 1 for p = 0 and for x ≥ 1 and underflows to 0 otherwise, so p = 0, 1e-6, 1e4,
  1e7, 3e38 and 1e39 all give the closed form (bracketed by the float32 error of n·h).
* **extreme intensities**: the float32 sum of the light terms overflows to Inf for intensities
  near 3e38, and Inf times a zero weight (a coloured mirror, a coloured glass's transmittance)
  is NaN. The renderer documents one guard: each sample is sanitised (NaN → 0) and clamped to
  ``render.clamp`` (default 1e20, at most 1e30, so that the float32 film sum of up to 2^20
  samples stays finite). warprt multiplies colours with a saturating product (0·x = 0 for any
  x, overflow saturates at the float32 maximum), so an overflowing term never becomes NaN and
  never wipes the other contributions of its channel (it did: a red mirror reflecting an
  overflowing surface lost its green ambient term). The image is min(closed form, clamp),
  finite, for every intensity from 1e-38 (subnormal results, no flush to zero on the CPU) to
  1e39 (beyond float32, stored as Inf).
* **many lights**: 500 point lights sum to the float64 closed form within the float32 bound
  n·u·L + Σ I·(kd + p·ks)·δ (below), measured ~1e-6 relative; 500 lights of 1e36 overflow the
  float32 sum and give the clamp, not Inf.

Every render uses the all-features kernel through ``_util``; images are at most 32×32.
"""

from __future__ import annotations

import math
import re
import warnings

import numpy as np
import pytest

import warprt

from ._util import image, pixel_hits, render, unit

FLT_MAX = float(np.finfo(np.float32).max)
CLAMP = warprt.RenderSettings().clamp  # 1e20, the documented default
MAX_CLAMP = 1e30  # the documented largest render.clamp: 2^20 samples of it sum to 1e36 < FLT_MAX

# --- zero-area faces ---------------------------------------------------------------------------

QUAD_V = np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0], [0, -1, 0]], np.float64)
QUAD_F = np.array([[0, 1, 2], [0, 2, 3]])
DEGENERATE_F = np.array([[0, 1, 2], [1, 1, 2], [0, 2, 3], [0, 4, 1]])  # face 1: repeated index; face 3: collinear
KD_Q, KA_Q, IA_Q, LIGHT_Q = 0.7, 0.3, 0.5, np.array([0.4, 0.6, 1.5])


def quad_scene(faces, degenerate="error", width=24):
    return warprt.Scene(
        camera=warprt.Camera(eye=(0.2, 0.1, 3.0), look_at=(0, 0, 0), fov=40, width=width, height=width),
        shapes=(warprt.Mesh(vertices=QUAD_V, faces=faces, degenerate=degenerate, material="m"),),
        materials={"m": warprt.Material(kd=KD_Q, ka=KA_Q)}, lights=(warprt.PointLight(position=tuple(LIGHT_Q)),),
        ambient=IA_Q, background=(0.1, 0.2, 0.3), render=warprt.RenderSettings(sampler="regular"))


def test_naive_normal_of_a_zero_area_face_is_nan():
    v = QUAD_V.astype(np.float32)
    for a, b, c in DEGENERATE_F[[1, 3]]:
        n = np.cross(v[b] - v[a], v[c] - v[a])
        with np.errstate(invalid="ignore"):
            assert np.isnan(n / np.linalg.norm(n)).all()


def test_zero_area_faces_are_refused_naming_the_field_and_the_face(device):
    with pytest.raises(warprt.SceneError) as err:
        render(quad_scene(DEGENERATE_F))
    assert err.value.field == "shapes[0].faces"
    assert "2 of 4 faces have zero area (first: face 1)" in err.value.problem
    assert 'degenerate = "drop"' in err.value.problem
    # from a scene file the message carries the file, the field path and the face
    text = ("[[shapes]]\ntype = 'mesh'\n"
            f"vertices = {QUAD_V.tolist()}\nfaces = {DEGENERATE_F[[0, 2, 3]].tolist()}\n")
    scene = warprt.scene_from_string(text, source="quad.toml")
    with pytest.raises(warprt.SceneError) as err:
        warprt.Renderer(scene, device=device)
    assert str(err.value).startswith("quad.toml: shapes[0].faces: 1 of 3 faces have zero area (first: face 2)")


def test_dropped_zero_area_faces_leave_the_clean_mesh_exactly():
    with pytest.warns(UserWarning, match="dropping 2 zero-area faces of 4"):
        img = image(quad_scene(DEGENERATE_F, degenerate="drop"))
    clean = image(quad_scene(QUAD_F))
    np.testing.assert_array_equal(img, clean)
    # and the clean quad is the closed form ka·Ia + kd·I·n·l (float64, at the hit points)
    o, d, h = pixel_hits(quad_scene(QUAD_F))
    hit = h["hit"]
    assert 200 < hit.sum() < 24 * 24  # the quad and some background are on screen
    p = h["position"][hit].astype(np.float64)
    ndl = unit(LIGHT_Q - p)[:, 2]
    expected = KA_Q * IA_Q + KD_Q * ndl
    got = img.reshape(-1, 3)[hit]
    np.testing.assert_allclose(got, np.repeat(expected[:, None], 3, 1), rtol=1e-5, atol=1e-6)
    background = img.reshape(-1, 3)[~hit]
    np.testing.assert_array_equal(background, np.broadcast_to(np.float32([0.1, 0.2, 0.3]), background.shape))


def test_dropping_every_face_is_an_error():
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        with pytest.raises(warprt.SceneError) as err:
            render(quad_scene(DEGENERATE_F[[1, 3]], degenerate="drop"))
    assert err.value.field == "shapes[0].faces" and "every face has zero area" in err.value.problem


def test_faces_that_collapse_only_in_float32_are_harmless():
    """The zero-area check runs on the float64 input; a face 1e-6 high at 100 units collapses to
    zero height in float32 (ulp 7.6e-6) and is kept, but it shades nothing: rays at it hit the
    adjacent real face along its edge (t = 2, a unit normal) or nothing, and the image stays
    finite."""
    v = np.array([[100, 100, 0], [101, 100, 0], [101, 100.000001, 0], [100, 100.000001, 0], [100, 101, 0]], float)
    f = np.array([[0, 1, 2], [0, 2, 3], [0, 1, 4]])
    from warprt.build import prepare_mesh

    v32, _ = prepare_mesh(v, f)
    assert v32[2, 1] == v32[0, 1]  # collapsed in float32
    scene = warprt.Scene(shapes=(warprt.Mesh(vertices=v, faces=f, smooth=True),))
    xs = np.linspace(100.05, 100.95, 50)
    o = np.c_[xs, np.full(50, 100.0), np.full(50, 2.0)].astype(np.float32)
    q = warprt.trace_rays(scene, o, np.tile(np.float32([0, 0, -1]), (50, 1)))
    assert np.isfinite(q["normal"][q["hit"]]).all()
    np.testing.assert_allclose(np.linalg.norm(q["normal"][q["hit"]], axis=1), 1.0, rtol=1e-6)
    assert (q["t"][q["hit"]] == 2.0).all()  # whatever is hit is the z = 0 plane, 2 units away
    cam = warprt.Camera(eye=(100.5, 100.2, 3), look_at=(100.5, 100.2, 0), width=9, height=9, fov=30)
    lit = warprt.Scene(camera=cam, shapes=scene.shapes, lights=(warprt.PointLight(position=(100, 103, 3)),), ambient=0.1)
    assert np.isfinite(image(lit)).all()


# --- sliver triangles ---------------------------------------------------------------------------

# (length, height): a strip of two triangles with aspect ratio 1e6, split along its diagonal
SLIVERS = [(0.1, 1e-7), (1.0, 1e-6), (10.0, 1e-5)]


def _naive_moller_trumbore(o, d, v0, v1, v2, eps=1e-6):
    """Möller & Trumbore (1997) as published, float32, EPSILON = 1e-6 on the determinant."""
    o, d = o.astype(np.float32), d.astype(np.float32)
    v0, v1, v2 = (np.asarray(x, np.float32) for x in (v0, v1, v2))
    e1, e2 = v1 - v0, v2 - v0
    pv = np.cross(d, e2)
    det = np.sum(pv * e1, 1)
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = np.float32(1.0) / det
        s = o - v0
        u = np.sum(s * pv, 1) * inv
        q = np.cross(s, e1)
        v = np.sum(d * q, 1) * inv
        t = np.sum(q * e2, 1) * inv
    return (np.abs(det) > eps) & (u >= 0) & (v >= 0) & (u + v <= 1) & (t > 0)


def _sliver_rays(length, height, n, rng, on_diagonal=False):
    """float32 rays from a point in front of the strip to points of it, and their float64 closed
    form: t to the plane z = 0 and whether the crossing is inside the strip (2% margin)."""
    src = np.array([0.3 * length, 0.5, 2.0])
    a = rng.uniform(0.01, 0.99, n)
    b = a + rng.uniform(-0.3, 0.3, n) if on_diagonal else rng.uniform(0.05, 0.95, n)
    target = np.c_[a * length, b * height, np.zeros(n)]
    o = np.broadcast_to(src, target.shape).astype(np.float32)
    d = unit(target - src).astype(np.float32)
    o64, d64 = o.astype(np.float64), d.astype(np.float64)
    t = -o64[:, 2] / d64[:, 2]
    x, y = (o64 + t[:, None] * d64)[:, :2].T
    L32, H32 = np.float32(length), np.float32(height)
    inside = (x > 0.005 * L32) & (x < 0.995 * L32) & (y > 0.02 * H32) & (y < 0.98 * H32)
    return o, d, t, inside


def _sliver_mesh(length, height):
    v = np.array([[0, 0, 0], [length, 0, 0], [length, height, 0], [0, height, 0]], np.float64)
    return v, np.array([[0, 1, 2], [0, 2, 3]])


@pytest.mark.parametrize("length, height", SLIVERS[:2], ids=["0.1", "1"])
def test_naive_moller_trumbore_misses_small_slivers(length, height):
    """|det| = 2·area·|cos| is 2e-8 to 2e-6·|cos|: at or below the published EPSILON."""
    v, f = _sliver_mesh(length, height)
    o, d, _, inside = _sliver_rays(length, height, 2000, np.random.default_rng(0))
    naive = _naive_moller_trumbore(o, d, *v[f[0]]) | _naive_moller_trumbore(o, d, *v[f[1]])
    assert inside.sum() > 1500
    assert naive[inside].mean() < 0.05, f"naive MT hit {naive[inside].mean():.1%} of the sliver rays"


@pytest.mark.parametrize("length, height", SLIVERS, ids=["0.1", "1", "10"])
@pytest.mark.parametrize("where", ["interior", "diagonal"])
def test_sliver_triangles_are_hit_at_the_closed_form_t(length, height, where):
    """Every ray whose exact (float64) crossing lies inside the strip hits it, with t within
    1e-6 relative of the closed form (measured 4.2e-7: a few ulps of the coordinates); rays aimed
    at the shared diagonal never leak between the two slivers."""
    v, f = _sliver_mesh(length, height)
    scene = warprt.Scene(shapes=(warprt.Mesh(vertices=v, faces=f),))
    o, d, t, inside = _sliver_rays(length, height, 3000, np.random.default_rng(1), on_diagonal=(where == "diagonal"))
    q = warprt.trace_rays(scene, o, d)
    assert inside.sum() > 1500
    assert q["hit"][inside].all(), f"{(~q['hit'][inside]).sum()} rays leak through the sliver"
    rel = np.abs(q["t"][inside] - t[inside]) / t[inside]
    assert rel.max() <= 1e-6, f"t off by {rel.max():.3g} relative"
    assert np.isfinite(q["normal"][q["hit"]]).all()
    np.testing.assert_allclose(np.abs(q["normal"][inside][:, 2]), 1.0, atol=1e-6)


# --- NaN / Inf vertices ------------------------------------------------------------------------

@pytest.mark.parametrize("bad, toml_bad", [(math.nan, "nan"), (math.inf, "inf"), (-math.inf, "-inf")],
                         ids=["nan", "inf", "-inf"])
def test_nan_or_inf_vertices_are_scene_errors(device, bad, toml_bad, tmp_path):
    v = [[0, 0, 0], [1, 0, 0], [0, bad, 0], [0, 1, 0]]
    f = [[0, 1, 3], [0, 1, 2]]
    with pytest.raises(warprt.SceneError) as err:  # Python API: at construction
        warprt.Mesh(vertices=v, faces=f)
    assert err.value.field == "vertices" and "1 vertices are NaN or infinite (first: vertex 2)" in err.value.problem
    text = f"[[shapes]]\ntype = 'mesh'\nvertices = [[0, 0, 0], [1, 0, 0], [0, {toml_bad}, 0], [0, 1, 0]]\nfaces = {f}\n"
    with pytest.raises(warprt.SceneError) as err:  # TOML: at load time, with the field path
        warprt.scene_from_string(text, source="bad.toml")
    assert str(err.value) == "bad.toml: shapes[0].vertices: 1 vertices are NaN or infinite (first: vertex 2)"
    obj = tmp_path / "bad.obj"  # mesh file: when the scene is built
    obj.write_text(f"v 0 0 0\nv 1 0 0\nv 0 {toml_bad} 0\nv 0 1 0\nf 1 2 4\nf 1 2 3\n")
    with pytest.raises(warprt.SceneError) as err:
        warprt.Renderer(warprt.Scene(shapes=(warprt.Mesh(file=str(obj)),)), device=device)
    assert err.value.field == "shapes[0].vertices" and "first: vertex 2" in err.value.problem


def test_vertex_coordinates_beyond_1e30_are_scene_errors():
    with pytest.raises(warprt.SceneError) as err:
        warprt.Mesh(vertices=[[0, 0, 0], [1, 0, 0], [0, 2e30, 0]], faces=[[0, 1, 2]])
    assert err.value.field == "vertices" and "exceed 1e30" in err.value.problem


# --- zero-area lights, zero-radius shapes ------------------------------------------------------


@pytest.mark.parametrize("edges, field", [
    (((0, 0, 0), (0, 0, 1)), "edge1"), (((1, 0, 0), (0, 0, 0)), "edge2"), (((1, 0, 0), (-2, 0, 0)), "edge2")],
    ids=["zero-edge1", "zero-edge2", "parallel"])
def test_rectangle_light_without_area_is_a_scene_error(edges, field):
    with pytest.raises(warprt.SceneError) as err:
        warprt.RectLight(edge1=edges[0], edge2=edges[1])
    assert err.value.field == field
    text = f"[[lights]]\ntype = 'rectangle'\nedge1 = {list(edges[0])}\nedge2 = {list(edges[1])}\n"
    with pytest.raises(warprt.SceneError) as err:
        warprt.scene_from_string(text, source="l.toml")
    assert err.value.field == f"lights[0].{field}" and str(err.value).startswith(f"l.toml: lights[0].{field}: ")


def test_naive_rectangle_inside_test_accepts_nan_for_a_tiny_rectangle():
    """a = ((p - c) × e2)·n / (n·n) with n = e1 × e2: for edges of 1e-20, n is subnormal, n·n
    underflows to 0 and a = 0/0 = NaN, which the rejection test `a < 0 or a > 1` lets through:
    a 1e-20 rectangle becomes an infinite plane."""
    e1, e2 = np.float32([1e-20, 0, 0]), np.float32([0, 1e-20, 0])
    n = np.cross(e1, e2)
    rel = np.float32([0.7, -3.0, 0.0])  # a point of the plane far outside the rectangle
    with np.errstate(divide="ignore", invalid="ignore", under="ignore"):
        a = np.dot(np.cross(rel, e2), n) / np.dot(n, n)
    assert np.isnan(a) and not (a < 0 or a > 1)


@pytest.mark.parametrize("kind", ["shape", "light"])
@pytest.mark.parametrize("size", [1e-20, 1e-30])
def test_tiny_rectangle_is_not_an_infinite_plane(kind, size):
    """A rectangle far smaller than a pixel covers no pixel (at most the one through its centre),
    whether a shape (ka = 1) or a light (Le = 5) in front of a black background; a rectangle
    light that small also lights nothing: the floor keeps its ambient value."""
    corner, e1, e2 = (-size / 2, 1 - size / 2, 0.0), (size, 0, 0), (0, size, 0)
    shapes = (warprt.Plane(material="floor"),)
    lights = ()
    if kind == "shape":
        shapes += (warprt.Rectangle(corner=corner, edge1=e1, edge2=e2, material="bright"),)
    else:
        lights = (warprt.RectLight(corner=corner, edge1=e1, edge2=e2, radiance=5.0, samples=4),)
    scene = warprt.Scene(
        camera=warprt.Camera(eye=(0, 1, 5), look_at=(0, 1, 0), fov=40, width=15, height=15), shapes=shapes,
        materials={"bright": warprt.Material(kd=0, ka=5.0), "floor": warprt.Material(kd=0.8, ka=0.25)},
        lights=lights, ambient=0.5, render=warprt.RenderSettings(sampler="regular"))
    field = "shapes[1]" if kind == "shape" else "lights[0]"
    with pytest.warns(RuntimeWarning, match=rf"{re.escape(field)} measures only {size:g} across: below about 1e-19"):
        img = image(scene)  # (too small for float32's squared lengths: it is said)
    assert np.isfinite(img).all()
    assert (img >= 1.0).any(axis=-1).sum() <= 1, f"{(img >= 1.0).any(axis=-1).sum()} pixels see the tiny rectangle"
    floor = img[10:, :, 0]  # rows below the horizon see the floor: ambient only
    np.testing.assert_array_equal(floor, np.float32(0.125))


def _zero_radius_scene(kind, radius, le=1.0e6, width=15):
    """A floor lit only by a sphere or disk light of the given radius at (0, 1, 0); the camera
    looks straight at the light's centre (odd width: the centre pixel's ray passes through it)."""
    light = (warprt.SphereLight(center=(0, 1, 0), radius=radius, radiance=le) if kind == "sphere"
             else warprt.DiskLight(center=(0, 1, 0), normal=(0, -0.6, 0.8), radius=radius, radiance=le))
    return warprt.Scene(
        camera=warprt.Camera(eye=(0, 1, 5), look_at=(0, 1, 0), fov=60, width=width, height=width),
        shapes=(warprt.Plane(material="floor"),), materials={"floor": warprt.Material(kd=0.8, ka=0.25)},
        lights=(light,), ambient=0.5, background=(0.0, 0.0, 0.0), render=warprt.RenderSettings(sampler="regular"))


@pytest.mark.parametrize("kind", ["sphere", "disk"])
def test_zero_radius_area_light_contributes_nothing_and_is_invisible(kind):
    img = image(_zero_radius_scene(kind, 0.0))
    assert np.isfinite(img).all()
    o, d, h = pixel_hits(_zero_radius_scene(kind, 0.0))
    on_floor = (h["shape"] == 0).reshape(15, 15)
    # the floor is ka·Ia exactly, everything else (the centre pixel through the light included) black
    np.testing.assert_array_equal(img[on_floor], np.float32(0.125))
    np.testing.assert_array_equal(img[~on_floor], 0.0)
    assert img[7, 7].max() == 0.0


@pytest.mark.parametrize("kind", ["sphere", "disk"])
def test_small_area_light_tends_to_the_point_light_limit(kind):
    """Radius r = 1e-3 at distance d: a sphere light acts as a point light of intensity Le·r²
    (irradiance Le·π·sin²α·cosθ, sin α = r/d), a disk light as one of intensity Le·r²·cosθ'
    (with inverse-square falloff). One light sample per pixel: the sample's offset within the
    light changes the value by at most (|tanθ| + |tanθ'| + 2)·r/d relative, the tolerance."""
    r, le = 1e-3, 1.0e6
    scene = _zero_radius_scene(kind, r, le)
    img = image(scene)[..., 0].ravel()
    o, d, h = pixel_hits(scene)
    floor = h["hit"] & (h["shape"] == 0)
    assert floor.sum() > 60
    p = h["position"][floor].astype(np.float64)
    to_c = np.array([0.0, 1.0, 0.0]) - p
    dist = np.linalg.norm(to_c, axis=1)
    l = to_c / dist[:, None]
    cos_t = l[:, 1]
    if kind == "sphere":
        cos_l = np.ones_like(cos_t)
        tan_l = np.zeros_like(cos_t)
    else:
        ln = unit([0, -0.6, 0.8])
        cos_l = np.maximum(-(l @ ln), 0.0)
        tan_l = np.sqrt(np.maximum(1 - cos_l ** 2, 0)) / np.maximum(cos_l, 1e-3)
    expected = 0.25 * 0.5 + 0.8 * le * r * r * cos_t * cos_l / dist ** 2
    tan_t = np.sqrt(1 - cos_t ** 2) / cos_t
    tol = (np.abs(tan_t) + tan_l + 2) * r / dist * (expected - 0.125) + 1e-5 * expected
    err = np.abs(img[floor] - expected)
    assert (err <= tol).all(), f"worst excess {(err - tol).max():.3g}"
    assert (expected - 0.125).max() > 0.05  # the light does light the floor measurably


def test_naive_normal_of_a_zero_radius_sphere_is_nan():
    """The textbook quadratic has the double root t = |c - o| for a ray through the centre of a
    zero-radius sphere, and the normal (p - c)/r is 0/0."""
    o, d, c, r = np.float32([0, 0, 5]), np.float32([0, 0, -1]), np.float32([0, 0, 0]), np.float32(0)
    b = np.dot(d, o - c)
    disc = b * b - (np.dot(o - c, o - c) - r * r)
    assert disc >= 0  # the naive test reports a hit
    with np.errstate(invalid="ignore"):
        assert np.isnan(((o + (-b) * d) - c) / r).all()


@pytest.mark.parametrize("shape", [warprt.Sphere(radius=0.0), warprt.Disk(normal=(0, 0, 1), radius=0.0)],
                         ids=["sphere", "disk"])
def test_zero_radius_shapes_are_never_hit(shape):
    scene = warprt.Scene(
        camera=warprt.Camera(eye=(0, 0, 5), look_at=(0, 0, 0), fov=30, width=9, height=9), shapes=(shape,),
        materials={"default": warprt.Material(kd=0, ka=1)}, ambient=1.0,
        render=warprt.RenderSettings(sampler="regular"))
    # rays exactly through the centre, along the axes and from a few exact lattice points
    o = np.float32([[0, 0, 5], [0, 0, -5], [0, 4, 0], [3, 0, 0], [2, 2, 1]])
    d = np.float32([[0, 0, -1], [0, 0, 1], [0, -1, 0], [-1, 0, 0], [-2, -2, -1]]) / np.float32([1, 1, 1, 1, 3])[:, None]
    q = warprt.trace_rays(scene, o, d)
    assert not q["hit"].any(), f"rays {np.flatnonzero(q['hit'])} hit a zero-radius {type(shape).__name__}"
    img = image(scene)
    assert np.isfinite(img).all() and (img == 0).all()


# --- coincident surfaces -----------------------------------------------------------------------

A, B = (1.0, 0.0, 0.0), (0.0, 1.0, 0.0)  # ka of the first and of the second listed shape
_QV = np.array([[-4, 0, -4], [-4, 0, 4], [4, 0, 4], [4, 0, -4]], np.float64)
_QF = np.array([[0, 1, 2], [0, 2, 3]])


def _pair(kind, mat):
    n = tuple(unit((0.3, 1.0, 0.2)))
    return {"sphere": lambda: warprt.Sphere(radius=1.0, material=mat),
            "plane": lambda: warprt.Plane(normal=n, material=mat),
            "rectangle": lambda: warprt.Rectangle(corner=(-3, 0.5, -2), edge1=(0, 0.3, 4), edge2=(6, -0.5, 0.1),
                                                  material=mat),
            "disk": lambda: warprt.Disk(center=(0.1, 0.2, -0.3), normal=n, radius=3.0, material=mat),
            "mesh": lambda: warprt.Mesh(vertices=_QV, faces=_QF, transform=warprt.Transform(rotate=(10, 20, 5)),
                                        material=mat),
            "axis-plane": lambda: warprt.Plane(material=mat),
            "axis-rectangle": lambda: warprt.Rectangle(corner=(-4, 0, -4), edge1=(0, 0, 8), edge2=(8, 0, 0),
                                                       material=mat),
            "axis-disk": lambda: warprt.Disk(radius=4.0, material=mat),
            "axis-mesh": lambda: warprt.Mesh(vertices=_QV, faces=_QF, material=mat)}[kind]()


def coincident_scene(first, second):
    return warprt.Scene(
        camera=warprt.Camera(eye=(0.3, 2.0, 3.0), look_at=(0, 0, 0), width=32, height=32, fov=50),
        shapes=(_pair(first, "a"), _pair(second, "b")),
        materials={"a": warprt.Material(kd=0, ka=A), "b": warprt.Material(kd=0, ka=B)}, ambient=1.0,
        render=warprt.RenderSettings(sampler="regular"))


def _winners(img):
    covered = img.max(axis=-1) > 0
    a = covered & (img == np.float32(A)).all(axis=-1)
    b = covered & (img == np.float32(B)).all(axis=-1)
    assert (a | b).sum() == covered.sum(), "a covered pixel shows neither colour"
    return a, b, covered


@pytest.mark.parametrize("kind", ["sphere", "plane", "rectangle", "disk", "mesh"])
def test_identical_coincident_shapes_first_listed_wins_everywhere(kind):
    """Same representation, same arithmetic, the same t bit for bit: a later shape must be
    strictly nearer to replace the current hit, so the first one listed wins every pixel; the
    image is bit-identical for any tile size and worker count."""
    scene = coincident_scene(kind, kind)
    img = image(scene)
    a, b, covered = _winners(img)
    assert covered.sum() > 150 and not b.any(), f"the second {kind} wins {b.sum()} of {covered.sum()} pixels"
    again = render(scene, workers=1, slices=5).image
    np.testing.assert_array_equal(img, again)


def test_a_tie_the_bvh_reaches_second_still_goes_to_the_first_listed():
    """Two rectangles on y = 0, the small one listed first: the same t bit for bit where both
    are hit, and the large one's box (padded in proportion to its size) is entered first, so the
    BVH meets the later-listed shape first. The first listed must still win on all its pixels,
    as the loops over shapes would give: exactly the pixels it covers alone."""
    small = warprt.Rectangle(corner=(-2, 0, -2), edge1=(0, 0, 4), edge2=(4, 0, 0), material="a")
    large = warprt.Rectangle(corner=(-4, 0, -4), edge1=(0, 0, 8), edge2=(8, 0, 0), material="b")
    scene = coincident_scene("axis-rectangle", "axis-rectangle")
    a, b, covered = _winners(image(scene.replace(shapes=(small, large))))
    alone = image(scene.replace(shapes=(small,))).max(axis=-1) > 0
    assert alone.sum() > 400 and b.sum() > 50
    np.testing.assert_array_equal(a, alone)
    # the same for rays one by one (the ray queries; secondary rays take the same path), where
    # the render's camera rays went through the BVH in packets
    both = scene.replace(shapes=(small, large))
    o, d = warprt.camera_rays(both)
    got = warprt.trace_rays(warprt.Renderer(both, device="cpu"), o, d)["shape"]
    on_small = warprt.trace_rays(warprt.Renderer(scene.replace(shapes=(small,)), device="cpu"), o, d)["shape"] == 0
    assert on_small.sum() > 400 and (got == 1).sum() > 50
    np.testing.assert_array_equal(got[on_small], 0)


@pytest.mark.parametrize("first, second, winner", [
    ("axis-rectangle", "axis-plane", "b"), ("axis-disk", "axis-plane", "b"), ("axis-disk", "axis-rectangle", "b"),
    ("axis-plane", "axis-rectangle", "a")], ids=["rect-plane", "disk-plane", "disk-rect", "plane-rect"])
def test_coplanar_plane_rectangle_and_disk_follow_the_kind_order(first, second, winner):
    """On y = 0 with power-of-two edges a plane, a rectangle and a disk compute the same t, and
    the kind tested first (planes, then rectangles, then disks) wins everywhere, whatever the
    scene order."""
    a, b, covered = _winners(image(coincident_scene(first, second)))
    assert covered.sum() > 400
    assert (b if winner == "b" else a).sum() == covered.sum(), f"a: {a.sum()}, b: {b.sum()} of {covered.sum()}"


@pytest.mark.parametrize("first, second", [("axis-plane", "axis-mesh"), ("axis-mesh", "axis-plane")])
def test_plane_and_mesh_at_the_same_place_do_not_z_fight(first, second):
    """Warp's triangle t and the plane's t differ by a few ulps either way; a mesh must be nearer
    by 2^-17·t to replace an analytic hit, so the plane wins every pixel in either scene order."""
    a, b, covered = _winners(image(coincident_scene(first, second)))
    plane = a if first == "axis-plane" else b
    assert covered.sum() > 400
    assert plane.sum() == covered.sum(), f"a: {a.sum()}, b: {b.sum()} of {covered.sum()}"


@pytest.mark.parametrize("lift", [1e-4, 1e-3])
def test_mesh_just_above_a_plane_is_seen(lift):
    """The tie band is relative 2^-17 ≈ 7.6e-6 of t (t ≈ 3.6 here, band ≈ 2.8e-5): a mesh lifted
    by 1e-4 above the plane, beyond the band, wins every pixel it covers."""
    scene = coincident_scene("axis-plane", "axis-mesh")
    mesh = scene.shapes[1]
    lifted = warprt.Mesh(vertices=np.asarray(mesh.vertices) + [0.0, lift, 0.0], faces=mesh.faces, material="b")
    a, b, covered = _winners(image(scene.replace(shapes=(scene.shapes[0], lifted))))
    assert b.sum() > 400 and a.sum() < covered.sum() - 400, (a.sum(), b.sum())
    mesh_only = image(scene.replace(shapes=(lifted,))).max(axis=-1) > 0
    np.testing.assert_array_equal(b, mesh_only)


# --- extreme Phong exponents -------------------------------------------------------------------

KD_P, KS_P = 0.5, 0.5
DELTA_NH = 1e-6  # bound on |n·h (float32) - n·h (float64)|: a few ulps of 1 (2^-23 = 1.2e-7 each)


def test_naive_float32_phong_power_overflows_and_makes_nan():
    # n·h of float32 unit vectors exceeds 1 at the highlight
    rng = np.random.default_rng(3)
    n = unit(rng.normal(size=(20000, 3))).astype(np.float32)
    h = n / np.linalg.norm(n, axis=1, keepdims=True).astype(np.float32)
    ndh = np.sum(n * h, axis=1, dtype=np.float32)
    assert ndh.max() > 1.0
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        assert np.isinf(np.power(ndh.max(), np.float32(1e9)))  # (1 + 2^-23)^1e9
        assert np.isnan(np.exp(np.float32(0.0) * np.log(np.float32(0.0))))  # p = 0 at n·h = 0
        assert np.isnan(np.exp(np.float32(np.inf) * np.log(np.float32(1.0))))  # p stored as float32 Inf


def phong_scene(p, intensity=1.0, clamp=CLAMP, width=15):
    """A plane facing the camera lit by a light at the eye: the highlight peak (n·h = 1) is the
    centre pixel (odd width)."""
    return warprt.Scene(
        camera=warprt.Camera(eye=(0, 0, 3), look_at=(0, 0, 0), fov=40, width=width, height=width),
        shapes=(warprt.Plane(normal=(0, 0, 1), material="m"),),
        materials={"m": warprt.Material(kd=KD_P, ka=0.0, ks=KS_P, p=p)},
        lights=(warprt.PointLight(position=(0.0, 0.0, 3.0), intensity=intensity),),
        render=warprt.RenderSettings(sampler="regular", clamp=clamp))


def phong_closed_form(scene, p, intensity=1.0):
    """Per pixel: the float64 value with n·h lowered and raised by DELTA_NH (the bracket)."""
    o, d, h = pixel_hits(scene)
    assert h["hit"].all()
    pos = h["position"].astype(np.float64)
    l = unit(np.asarray(scene.lights[0].position) - pos)
    ndl = l[:, 2]
    ndh = unit(l - d)[:, 2]
    with np.errstate(over="ignore", under="ignore", divide="ignore", invalid="ignore"):
        lo = np.where(p == 0, 1.0, np.clip(ndh - DELTA_NH, 0, 1) ** np.float64(p))
        hi = np.where(p == 0, 1.0, np.clip(ndh + DELTA_NH, 0, 1) ** np.float64(p))
    diffuse = intensity * KD_P * ndl
    return diffuse + intensity * KS_P * lo, diffuse + intensity * KS_P * hi, ndh


@pytest.mark.filterwarnings("ignore:overflow encountered in cast:RuntimeWarning")  # 1e39 -> float32 Inf
@pytest.mark.parametrize("p", [0.0, 1e-6, 1.0, 1e4, 1e7, 3e38, 1e39],
                         ids=["0", "1e-6", "1", "1e4", "1e7", "3e38", "1e39"])
def test_extreme_phong_exponents_match_the_closed_form(p):
    """The pixel lies within the closed form evaluated at n·h ± 1e-6 (relative 1e-5 on top);
    p = 1e39 is beyond float32 and stored as Inf. Everywhere off the highlight peak the bracket is
    tight (x^p at most 1.2e-4 wide for p = 1e4), so this checks the value, not only finiteness."""
    scene = phong_scene(p)
    img = image(scene)
    assert np.isfinite(img).all()
    lo, hi, ndh = phong_closed_form(scene, p)
    v = img[..., 0].ravel().astype(np.float64)
    bad = (v < lo * (1 - 1e-5) - 1e-7) | (v > hi * (1 + 1e-5) + 1e-7)
    assert not bad.any(), f"{bad.sum()} pixels off, e.g. {v[bad][:3]} not in [{lo[bad][:3]}, {hi[bad][:3]}]"
    assert (hi - lo < 2e-4).mean() > 0.9  # the bracket decides most pixels
    if p == 0.0:
        np.testing.assert_allclose(v, lo, rtol=1e-5)  # 0^0 = 1: the full ks everywhere
    peak = np.argmax(ndh)  # the centre pixel, where h = n up to rounding
    assert 1 - ndh[peak] < 1e-6 and v[peak] >= KD_P * 0.999  # keeps its diffuse term (and its highlight)


# --- extreme intensities -----------------------------------------------------------------------


def test_naive_float32_light_sum_overflows_to_inf_and_nan():
    intensity, kd, ndl = np.float32(3e38), np.float32(0.8), np.float32([0.9, 0.8])
    with np.errstate(over="ignore", invalid="ignore"):
        total = np.float32(0.0)
        for c in ndl:
            total = total + intensity * kd * c
        assert np.isinf(total)
        assert np.isnan(total * np.float32(0.0))  # a zero throughput channel, a zero transmittance
        assert np.isinf(np.sum(np.full(500, 1e36, np.float32)))  # many large terms


@pytest.mark.filterwarnings("ignore:overflow encountered in cast:RuntimeWarning")  # 1e39 -> float32 Inf
@pytest.mark.parametrize("intensity", [1e-38, 1e30, 1e38, 3e38, 1e39], ids=["1e-38", "1e30", "1e38", "3e38", "1e39"])
@pytest.mark.parametrize("clamp", [CLAMP, MAX_CLAMP], ids=["clamp-1e20", "clamp-1e30"])
def test_extreme_intensity_is_the_closed_form_or_the_clamp(intensity, clamp):
    """The image is min(closed form, clamp) to 1e-5 relative, finite everywhere; 1e-38 gives
    subnormal results (about 1e-39, each rounding worth ~1e-6 relative: measured 4e-6), kept
    rather than flushed to zero; 1e39 is Inf in float32 and gives the clamp."""
    scene = phong_scene(8.0, intensity=intensity, clamp=clamp)
    img = image(scene)
    assert np.isfinite(img).all()
    lo, hi, _ = phong_closed_form(scene, 8.0, intensity=intensity)
    v = img[..., 0].ravel().astype(np.float64)
    lo, hi = np.minimum(lo, clamp), np.minimum(hi, clamp)
    bad = (v < lo * (1 - 1e-5) - 1e-44) | (v > hi * (1 + 1e-5) + 1e-44)
    assert not bad.any(), f"{bad.sum()} pixels off: {v[bad][:3]} vs [{lo[bad][:3]}, {hi[bad][:3]}]"
    if intensity == 1e-38:
        assert (v > 0).all() and (v < np.finfo(np.float32).tiny).any()  # subnormal, not flushed


def _overflow_mirror_scene():
    """Camera between a horizontal mirror (y = 0: km = (1, 0, 0), ka = (0, 1, 0), kd = 0) and a
    diffuse ceiling (y = 2, kd = 4) lit from below by two lights of 3e38: every pixel sees the
    mirror, whose reflection sees the ceiling, whose local term overflows float32 (> 3.4e38)."""
    return warprt.Scene(
        camera=warprt.Camera(eye=(0, 1, 0.5), look_at=(0, 0, 0), fov=40, width=16, height=16),
        shapes=(warprt.Plane(material="mirror"), warprt.Plane(point=(0, 2, 0), normal=(0, -1, 0), material="ceiling")),
        materials={"mirror": warprt.Material(kd=0.0, ka=(0, 1, 0), mirror=(1, 0, 0)),
                   "ceiling": warprt.Material(kd=4.0, ka=0.0)},
        lights=(warprt.PointLight(position=(0.5, 0.5, 0.0), intensity=3e38),
                warprt.PointLight(position=(-0.5, 0.5, 0.0), intensity=3e38)),
        ambient=1.0, render=warprt.RenderSettings(sampler="regular"))


def test_overflow_in_a_reflection_does_not_wipe_the_other_channels():
    """True value per pixel: R = km·(ceiling ≥ 1e38) → clamp; G = ka·Ia + 0·(ceiling) = 1; B = 0.
    A plain float32 product gives 0·Inf = NaN in G, and the sample's NaN → 0 guard then drops
    the ambient term too (G = 0)."""
    img = image(_overflow_mirror_scene())
    assert np.isfinite(img).all()
    np.testing.assert_array_equal(img[..., 0], np.float32(CLAMP))
    np.testing.assert_array_equal(img[..., 1], np.float32(1.0))
    np.testing.assert_array_equal(img[..., 2], np.float32(0.0))


def test_overflow_behind_coloured_glass_does_not_wipe_the_other_channels():
    """A floor (ka = 0.5, kd = 1, ks = 1, p = 1) under a pane of red glass (kt = (1, 0, 0)) lit
    from above by a light of 3e38: the light term is Inf in float32 where kd·n·l + ks·(n·h) >
    1.13, times T = (1, 0, 0). True value: R = clamp, G = B = ka·Ia = 0.5 (the camera is below
    the pane and sees the floor directly)."""
    scene = warprt.Scene(
        camera=warprt.Camera(eye=(0, 1.5, 2.5), look_at=(0, 0, 0), fov=30, width=16, height=16),
        shapes=(warprt.Plane(material="floor"),
                warprt.Rectangle(corner=(-9, 2, -9), edge1=(0, 0, 18), edge2=(18, 0, 0), material="glass")),
        materials={"floor": warprt.Material(kd=1.0, ka=0.5, ks=1.0, p=1.0),
                   "glass": warprt.Material(kd=0.0, ka=0.0, transparency=(1, 0, 0))},
        lights=(warprt.PointLight(position=(0, 5, 0), intensity=3e38),), ambient=1.0,
        render=warprt.RenderSettings(sampler="regular"))
    img = image(scene)
    assert np.isfinite(img).all()
    np.testing.assert_array_equal(img[..., 0], np.float32(CLAMP))
    np.testing.assert_array_equal(img[..., 1:], np.float32(0.5))


def test_film_sum_of_clamped_samples_stays_finite():
    """At the largest clamp, 1e30, every sample of an overflowing light term (3e38·kd with kd = 4)
    is clamped, and the float32 film sum of the samples stays finite: the image is the clamp."""
    assert MAX_CLAMP * 2.0 ** 20 < FLT_MAX
    scene = phong_scene(8.0, intensity=3e38, clamp=MAX_CLAMP, width=8)
    scene = scene.replace(materials={"m": warprt.Material(kd=4.0, ka=0.0)})
    result = render(scene, spp=16)
    assert np.isfinite(result.image).all()
    np.testing.assert_allclose(result.image, np.float32(MAX_CLAMP), rtol=16 * 2.0 ** -24)  # float32 sum of 16


# --- many lights -------------------------------------------------------------------------------

N_LIGHTS = 500


def many_lights_scene(intensities, rng, width=16):
    pos = np.c_[rng.uniform(-3, 3, N_LIGHTS), rng.uniform(0.5, 4, N_LIGHTS), rng.uniform(-3, 3, N_LIGHTS)]
    return warprt.Scene(
        camera=warprt.Camera(eye=(0, 2.5, 3.5), look_at=(0, 0, 0), fov=45, width=width, height=width),
        shapes=(warprt.Plane(material="m"),),
        materials={"m": warprt.Material(kd=(0.7, 0.5, 0.3), ka=0.0, ks=0.2, p=8.0)},
        lights=tuple(warprt.PointLight(position=tuple(p), intensity=tuple(i)) for p, i in zip(pos, intensities)),
        render=warprt.RenderSettings(sampler="regular")), pos


def test_many_point_lights_sum_to_the_float64_closed_form():
    """500 lights of random colour (total intensity ~1 per channel). Tolerance: the float32 sum
    of n positive terms is within (n-1)·u of the exact sum (u = 2^-24: 3e-5 relative for n =
    500, the worst case; typical √n·u ~ 1e-6); each term's cosines are off by at most δ = 1e-6,
    which moves it by I·(kd + p·ks)·δ. Measured: ~1e-6 relative."""
    rng = np.random.default_rng(7)
    intens = rng.uniform(0.5, 1.5, (N_LIGHTS, 3)) / N_LIGHTS
    scene, pos = many_lights_scene(intens, rng)
    img = image(scene).reshape(-1, 3).astype(np.float64)
    o, d, h = pixel_hits(scene)
    assert h["hit"].all()
    p = h["position"].astype(np.float64)
    l = unit(pos[None, :, :] - p[:, None, :])  # (pixels, lights, 3)
    ndl = np.maximum(l[..., 1], 0.0)
    ndh = np.maximum(unit(l - d[:, None, :])[..., 1], 0.0)
    kd = np.array([0.7, 0.5, 0.3])
    f = kd[None, None, :] * ndl[..., None] + 0.2 * (ndh ** 8)[..., None] * (ndl > 0)[..., None]
    expected = np.einsum("plc,lc->pc", f, intens)
    tol = (N_LIGHTS - 1) * 2.0 ** -24 * expected + intens.sum(0) * (kd + 8 * 0.2) * 1e-6
    err = np.abs(img - expected)
    assert (err <= tol).all(), f"worst error {err.max():.3g} > tolerance {tol[err > tol].min():.3g}"
    assert (err / expected).max() < 1e-5


def test_many_huge_lights_give_the_clamp_not_inf():
    """500 lights of 1e36: the float32 sum overflows (the naive sum above is Inf); the image is
    the documented clamp, 1e20, in every channel of every pixel."""
    rng = np.random.default_rng(8)
    scene, _ = many_lights_scene(np.full((N_LIGHTS, 3), 1e36), rng, width=8)
    img = image(scene)
    np.testing.assert_array_equal(img, np.float32(CLAMP))


# --- limits on the render call ------------------------------------------------------------------


@pytest.mark.parametrize("how", ["renderer", "render"])
def test_spp_beyond_the_scene_file_cap_is_refused_before_rendering(how):
    """One cap on samples per pixel, the scene file's 2^20, also for ``Renderer.render(spp=...)``
    and ``warprt.render(spp=...)`` (10^7 spp used to render for minutes); the message points to
    ``time_budget``/``target_error`` for an open-ended render."""
    scene = warprt.Scene(camera=warprt.Camera(width=4, height=3))
    limit = 1 << 20
    with pytest.raises(warprt.SceneError):
        scene.with_settings(spp=limit + 1)
    call = (lambda n: warprt.Renderer(scene, device="cpu").render(spp=n, progress=False)) if how == "renderer" \
        else (lambda n: warprt.render(scene, spp=n, device="cpu", progress=False))
    for spp in (limit + 1, 10_000_000):
        with pytest.raises(warprt.RenderError) as err:
            call(spp)
        msg = str(err.value)
        assert "spp" in msg and "1048576" in msg and "time_budget" in msg and "target_error" in msg, msg


def test_a_tiny_up_vector_renders_the_same_image():
    """up = (0, 1e-30, 0) is a valid direction: its float32 cross product with w would underflow
    (|u|² = 1e-60), so the camera uploads the unit up; the image is that of up = (0, 1, 0)."""
    def scene(up):
        return warprt.Scene(camera=warprt.Camera(eye=(0.3, 1, 4), up=up, width=12, height=8),
                            shapes=(warprt.Sphere(),), lights=(warprt.PointLight(),), ambient=0.1)
    ref = image(scene((0, 1, 0)))
    assert ref.max() > 0
    np.testing.assert_array_equal(image(scene((0, 1e-30, 0))), ref)


@pytest.mark.parametrize("seed", [-1, 1 << 32, (1 << 32) + 5, 2 ** 70])
def test_seeds_outside_32_bits_are_refused_not_wrapped(seed):
    """Seeds are 32-bit; -1 or 2^32 + 5 used to be taken modulo 2^32 silently (2^32 + 5 gave the
    image of seed 5). Renderer.render, render, render_sequence and render_frames refuse them."""
    from warprt.animation import render_sequence
    from warprt.batch import render_frames

    scene = warprt.Scene(camera=warprt.Camera(width=4, height=3))
    for call in (lambda: warprt.Renderer(scene, device="cpu").render(seed=seed, progress=False),
                 lambda: warprt.render(scene, seed=seed, device="cpu", progress=False),
                 lambda: render_sequence(scene, seed=seed, device="cpu", progress=False),
                 lambda: render_frames(scene, seed=seed, executor="thread")):
        with pytest.raises(warprt.RenderError, match=r"seed must be in \[0, 2\^32 - 1 = 4294967295\]"):
            call()


def test_the_largest_seed_renders():
    scene = warprt.Scene(camera=warprt.Camera(width=4, height=3), shapes=(warprt.Sphere(),),
                         lights=(warprt.PointLight(),))
    assert np.isfinite(image(scene, seed=(1 << 32) - 1)).all()


def _scaled_scene(scale, source=None):
    return warprt.Scene(camera=warprt.Camera(eye=(0, 0, 5 * scale), width=16, height=12),
                        shapes=(warprt.Sphere(radius=scale),), lights=(warprt.PointLight(position=(0, 5 * scale, 0)),),
                        ambient=0.1, source=source)


def test_a_scene_beyond_1e19_warns_that_float32_distances_overflow():
    """At scale 1e19 the squared distances of the sphere test overflow float32 and the image is
    black (exit 0 before); the renderer now warns, naming the extent. 1e18 renders and is quiet."""
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        warprt.Renderer(_scaled_scene(1e18), device="cpu")
    with pytest.warns(RuntimeWarning, match=r"scene coordinates reach 5e\+19.*scale the scene down"):
        warprt.Renderer(_scaled_scene(1e19), device="cpu")


# --- the other end of float32: scenes too small ------------------------------------------------------------


@pytest.mark.parametrize("kw, field, words", [
    (dict(eye=(0, 0, 0), look_at=(0, 0, 1e-30)), "look_at", "differ by a vector whose squared length underflows"),
    (dict(eye=(1e8, 0, 0), look_at=(1e8 + 1e-3, 0, 0)), "look_at", "they are the same point"),
    (dict(eye=(0, 0, 0), look_at=(0, 0, 1), eye_end=(0, 0, 1 + 1e-10)), "eye_end", "the same point"),
    (dict(fov=1e-40), "fov", "below float32's normal range"),
])
def test_a_camera_whose_float32_frame_underflows_is_refused(kw, field, words):
    """eye and look_at 1e-30 apart (a valid view in float64) gave an all-black image: the float32
    frame the device computes has no viewing direction. Refused, naming the field; 1e-18 apart
    (a squared length of 1e-36, a normal float32) still renders."""
    with pytest.raises(warprt.SceneError) as info:
        warprt.Camera(**kw)
    assert info.value.field == field and words in str(info.value)
    scene = warprt.Scene(camera=warprt.Camera(eye=(0, 0, 0), look_at=(0, 0, 1e-18), width=8, height=6),
                         shapes=(warprt.Sphere(center=(0, 0, 5)),), lights=(warprt.PointLight(position=(0, 0, 0)),))
    assert image(scene).max() > 0
    with pytest.raises(warprt.SceneError, match=r"^scene.toml: camera.look_at: eye and look_at are 1e-30 apart"):
        warprt.scene_from_string("[camera]\nlook_at = [0, 0, 1e-30]\neye = [0, 0, 0]\n", source="scene.toml")


def test_a_scene_of_tiny_geometry_warns_that_float32_lengths_underflow():
    """A whole mesh scene at 1e-30 (camera included, with a field of view that sees it) renders
    black: its float32 edge products underflow. The renderer warns, naming the shape, as it warns
    for coordinates beyond 1e19; the same scene at 1e-6 is quiet and renders."""
    import warnings

    def scene(scale):
        v = np.array([[-1, -1, 0], [1, -1, 0], [0, 1, 0]], float) * scale
        return warprt.Scene(camera=warprt.Camera(eye=(0, 0, 5 * scale), look_at=(0, 0, -1), fov=30 * scale,
                                                 width=8, height=6),
                            shapes=(warprt.Mesh(vertices=v, faces=[[0, 1, 2]]),),
                            lights=(warprt.PointLight(position=(0, 0, 5)),), ambient=0.2)

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert image(scene(1e-6)).max() > 0
    with pytest.warns(RuntimeWarning, match=r"shapes\[0\] measures only 2\.83e-30 across: below about 1e-19 the "
                                            r"renderer's float32 squared lengths underflow"):
        black = image(scene(1e-30))
    assert black.max() == 0.0  # what the warning is about
    with pytest.warns(RuntimeWarning, match=r"shapes\[0\] \(and 1 more\) measures only 1e-25"):
        warprt.Renderer(warprt.Scene(shapes=(warprt.Sphere(radius=1e-25), warprt.Box(size=(1e-22, 1e-22, 1e-22)))),
                        device="cpu")
