"""The lecture scenes (scenes/*.toml, one concept each) load, render, and show what they claim.

Each scene is rendered at 32x24 with one sample per pixel through the pixel centre (the
``regular`` sampler) and compared with an independent Whitted ray tracer written here in NumPy
(float64) from the lecture's formulas: pinhole camera, spheres and planes, point lights with hard
shadows, L = ka*Ia + sum_i T_i I_i (kd max(0, n.l) + ks max(0, n.h)^p), mirror reflection weighted
by km, refraction weighted by kt with exact Fresnel. Pixels where the reference itself changes
when the raster point moves by 1/200 of a pixel (silhouettes, shadow edges) are left out of the
comparison; they are few, and each test checks that. On top of that, each scene gets a check of
the concept it teaches.
"""

from __future__ import annotations

import math
import pathlib

import numpy as np
import pytest

import warprt
from reference_formulas import fresnel_exact, fresnel_schlick
from warprt import Material, Plane, PointLight, Sphere

SCENES = pathlib.Path(__file__).resolve().parents[1] / "scenes"
LECTURE = ["ambient", "diffuse", "specular", "mirror", "refraction", "shadows"]
W, H = 32, 24


# --- an independent NumPy Whitted tracer ---------------------------------------------------------


def _unit(v):
    v = np.asarray(v, dtype=np.float64)
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    return v / np.where(n > 0, n, 1.0)


def _dot(a, b):
    return np.einsum("ij,ij->i", a, b)


class Reference:
    """Whitted ray tracing of spheres and planes under point lights, float64, one ray per raster point."""

    EPS = 1e-5  # spawn offset along the normal (scene units)

    def __init__(self, scene: warprt.Scene):
        self.scene = scene
        self.spheres, self.planes = [], []
        for i, s in enumerate(scene.shapes):
            assert getattr(s, "transform", None) is None, "the reference takes untransformed shapes"
            if isinstance(s, Sphere):
                assert s.center_end is None
                self.spheres.append((i, np.array(s.center), s.radius))
            elif isinstance(s, Plane):
                self.planes.append((i, np.array(s.point), _unit(s.normal)))
            else:
                raise AssertionError(f"the reference has no {type(s).__name__}")
        assert all(isinstance(l, PointLight) for l in scene.lights)
        self.mats = [scene.materials[s.material] for s in scene.shapes]
        self.ambient = np.array(scene.ambient)
        self.background = np.array(scene.background)

    # geometry
    def camera_rays(self, x, y):
        cam = self.scene.camera
        eye, look = np.array(cam.eye), np.array(cam.look_at)
        w = _unit(eye - look)
        u = _unit(np.cross(cam.up, w))
        v = np.cross(w, u)
        top = cam.distance * math.tan(math.radians(cam.fov) / 2)
        right = top * cam.width / cam.height
        us = -right + 2 * right * np.asarray(x) / cam.width
        vs = top - 2 * top * np.asarray(y) / cam.height
        s = eye + us[:, None] * u + vs[:, None] * v - cam.distance * w
        return np.broadcast_to(eye, s.shape).copy(), _unit(s - eye)

    def _sphere_roots(self, o, d, c, r):
        oc = o - c
        b = _dot(oc, d)
        disc = b * b - (_dot(oc, oc) - r * r)
        sq = np.sqrt(np.maximum(disc, 0.0))
        t0 = np.where(disc >= 0, -b - sq, -np.inf)
        t1 = np.where(disc >= 0, -b + sq, -np.inf)
        return t0, t1

    def _plane_t(self, o, d, p, n):
        dn = d @ n
        with np.errstate(divide="ignore", invalid="ignore"):
            t = ((p - o) @ n) / dn
        return np.where(dn != 0.0, t, -np.inf)

    def nearest(self, o, d, t_min=0.0):
        """(t, shape index or -1) of each ray's nearest hit beyond t_min."""
        best = np.full(len(o), np.inf)
        sid = np.full(len(o), -1)
        for i, c, r in self.spheres:
            t0, t1 = self._sphere_roots(o, d, c, r)
            t = np.where(t0 > t_min, t0, np.where(t1 > t_min, t1, np.inf))
            closer = t < best
            best[closer], sid[closer] = t[closer], i
        for i, p, n in self.planes:
            t = self._plane_t(o, d, p, n)
            t = np.where(t > t_min, t, np.inf)
            closer = t < best
            best[closer], sid[closer] = t[closer], i
        return best, sid

    def normal(self, p, sid):
        ng = np.zeros_like(p)
        for i, c, r in self.spheres:
            m = sid == i
            ng[m] = (p[m] - c) / r
        for i, _, n in self.planes:
            ng[sid == i] = n
        return _unit(ng)

    def transmittance(self, o, d, dist):
        """kt per surface crossed in (0, dist) (0 for opaque surfaces), as in the lecture's shadow rays."""
        T = np.ones((len(o), 3))
        for i, c, r in self.spheres:
            kt = np.array(self.mats[i].transparency)
            for t in self._sphere_roots(o, d, c, r):
                crossed = (t > 0) & (t < dist)
                T[crossed] *= kt
        for i, p, n in self.planes:
            t = self._plane_t(o, d, p, n)
            crossed = (t > 0) & (t < dist)
            T[crossed] *= np.array(self.mats[i].transparency)
        return T

    def _mat(self, sid, name):
        return np.array([getattr(self.mats[i], name) for i in sid], dtype=np.float64)

    def local(self, p, ng, v, sid):
        """ka*Ia + sum over lights of T*I*(kd max(0,n.l) + ks max(0,n.h)^p); ng faces the viewer."""
        L = self._mat(sid, "ka") * self.ambient
        kd, ks, pexp = self._mat(sid, "kd"), self._mat(sid, "ks"), self._mat(sid, "p")
        origin = p + self.EPS * ng
        for light in self.scene.lights:
            to = np.array(light.position) - origin
            dist = np.linalg.norm(to, axis=1)
            l = to / dist[:, None]
            ndl = _dot(ng, l)
            h = _unit(l + v)
            ndh = np.maximum(_dot(ng, h), 0.0)
            spec = np.where(pexp == 0, 1.0, ndh ** pexp)
            f = kd * np.maximum(ndl, 0)[:, None] + ks * spec[:, None]
            f[ndl <= 0] = 0.0
            I = np.array(light.intensity)[None, :]
            if light.falloff == "inverse_square":
                I = I / (dist * dist)[:, None]
            L += self.transmittance(origin, l, dist) * I * f
        return L

    def trace(self, o, d):
        """Radiance along each ray, recursing into mirror reflection and refraction."""
        rs = self.scene.render
        n_rays = len(o)
        L = np.zeros((n_rays, 3))
        pix = np.arange(n_rays)
        w = np.ones((n_rays, 3))
        depth = 0
        t_min = rs.t_min
        while len(o):
            t, sid = self.nearest(o, d, t_min)
            miss = sid < 0
            np.add.at(L, pix[miss], w[miss] * self.background)
            o, d, w, pix, t, sid = (a[~miss] for a in (o, d, w, pix, t, sid))
            if not len(o):
                break
            p = o + t[:, None] * d
            ng = self.normal(p, sid)
            front = _dot(d, ng) < 0
            ng[~front] *= -1
            np.add.at(L, pix, w * self.local(p, ng, -d, sid))
            if depth >= rs.max_depth:
                break
            km, kt = self._mat(sid, "mirror"), self._mat(sid, "transparency")
            ior = self._mat(sid, "ior")
            w_refl = km.copy()
            w_refr = np.zeros_like(kt)
            eta_i = np.where(front, 1.0, ior)
            eta_t = np.where(front, ior, 1.0)
            eta = eta_i / eta_t
            cos_i = -_dot(d, ng)
            k = 1 - eta * eta * (1 - cos_i * cos_i)
            refracts = kt.max(axis=1) > 0
            tir = refracts & (k < 0)
            w_refl[tir] += kt[tir]
            through = refracts & ~tir
            tdir = _unit(eta[:, None] * d + (eta * cos_i - np.sqrt(np.maximum(k, 0)))[:, None] * ng)
            fres = np.array([self.mats[i].fresnel for i in sid])
            F = np.where(fres == "exact", fresnel_exact(cos_i, eta_i, eta_t), 0.0)
            F = np.where(fres == "schlick", fresnel_schlick(cos_i, eta_i, eta_t), F)
            w_refl[through] += kt[through] * F[through, None]
            w_refr[through] = kt[through] * (1 - F[through, None])
            r = d - 2 * _dot(d, ng)[:, None] * ng
            push_refl = ((w * w_refl).max(axis=1) > rs.min_weight) & (_dot(r, ng) > 0)
            push_refr = through & ((w * w_refr).max(axis=1) > rs.min_weight) & (_dot(tdir, ng) < 0)
            o = np.concatenate([p[push_refl] + self.EPS * ng[push_refl], p[push_refr] - self.EPS * ng[push_refr]])
            d = np.concatenate([r[push_refl], tdir[push_refr]])
            w = np.concatenate([(w * w_refl)[push_refl], (w * w_refr)[push_refr]])
            pix = np.concatenate([pix[push_refl], pix[push_refr]])
            depth += 1
            t_min = 0.0
        return L

    def image(self, dx=0.0, dy=0.0):
        cam = self.scene.camera
        jj, ii = np.mgrid[0:cam.height, 0:cam.width]
        o, d = self.camera_rays(ii.ravel() + 0.5 + dx, jj.ravel() + 0.5 + dy)
        return self.trace(o, d).reshape(cam.height, cam.width, 3)

    def first_hit(self):
        cam = self.scene.camera
        jj, ii = np.mgrid[0:cam.height, 0:cam.width]
        o, d = self.camera_rays(ii.ravel() + 0.5, jj.ravel() + 0.5)
        t, sid = self.nearest(o, d, self.scene.render.t_min)
        return o, d, t, sid.reshape(cam.height, cam.width)

    def stable(self, delta=0.005, tol=2e-3):
        """Pixels whose reference value hardly changes when the raster point moves by ``delta`` px."""
        centre = self.image()
        worst = np.zeros(centre.shape[:2])
        for dx, dy in ((delta, delta), (-delta, delta), (delta, -delta), (-delta, -delta)):
            worst = np.maximum(worst, np.abs(self.image(dx, dy) - centre).max(axis=2))
        return centre, worst < tol


# --- fixtures -------------------------------------------------------------------------------------


def small(scene: warprt.Scene) -> warprt.Scene:
    """The scene at 32x24, one sample per pixel, at the pixel centres."""
    return scene.with_camera(width=W, height=H).with_settings(spp=1, sampler="regular")


_cache: dict[str, tuple] = {}


def lecture(name: str):
    """(scene at 32x24, rendered image, reference image, stable-pixel mask), computed once."""
    if name not in _cache:
        scene = small(warprt.load_scene(SCENES / f"{name}.toml"))
        image = warprt.render(scene, progress=False)
        ref, stable = Reference(scene).stable()
        _cache[name] = (scene, image, ref, stable)
    return _cache[name]


def assert_matches_reference(name, rtol, atol, min_stable=0.85):
    scene, image, ref, stable = lecture(name)
    assert image.shape == (H, W, 3) and image.dtype == np.float32
    assert stable.mean() >= min_stable, f"only {stable.mean():.0%} of the pixels are away from edges"
    bad = ~np.isclose(image, ref, rtol=rtol, atol=atol).all(axis=2) & stable
    if bad.any():
        j, i = np.argwhere(bad)[0]
        pytest.fail(f"{name}: {int(bad.sum())} pixels differ from the reference, e.g. ({i}, {j}): "
                    f"rendered {image[j, i]}, expected {ref[j, i]}")


# --- every scene file loads -------------------------------------------------------------------------


@pytest.mark.parametrize("path", sorted(SCENES.glob("*.toml")), ids=lambda p: p.name)
def test_every_scene_file_loads(path):
    scene = warprt.load_scene(path)
    assert scene.source == str(path)
    assert scene.shapes


@pytest.mark.parametrize("name", LECTURE)
def test_lecture_scene_is_small_and_documented(name):
    path = SCENES / f"{name}.toml"
    text = path.read_text()
    assert text.startswith("#"), "a lecture scene opens with a comment saying what it shows"
    scene = warprt.load_scene(path)
    assert scene.camera.width <= 240 and scene.camera.height <= 180
    assert scene.render.spp <= 4


# --- per-scene checks ---------------------------------------------------------------------------------


def test_ambient_every_pixel_is_ka_times_ia_exactly():
    scene, image, _, _ = lecture("ambient")
    assert not scene.lights
    _, _, _, sid = Reference(scene).first_hit()
    ia = np.float32(scene.ambient)
    expected = {i: np.asarray(scene.materials[s.material].ka, np.float32) * ia for i, s in enumerate(scene.shapes)}
    expected[-1] = np.asarray(scene.background, np.float32)
    # one flat colour per object: only these values occur
    allowed = np.stack(list(expected.values()))
    on_some = (image[:, :, None, :] == allowed[None, None]).all(axis=3).any(axis=2)
    assert on_some.all()
    # and each pixel has the one of the object its centre ray meets (away from silhouettes)
    _, stable = Reference(scene).stable()
    for i, value in expected.items():
        m = (sid == i) & stable
        assert m.sum() >= 4, f"shape {i} covers too few pixels at {W}x{H}"
        assert (image[m] == value).all(), f"shape {i}"
    # every object is visible, and the colours differ: the picture is of flat discs
    assert len({tuple(v) for v in expected.values()}) == len(expected)


def test_diffuse_matches_lambert_and_is_black_beyond_the_terminator():
    assert_matches_reference("diffuse", rtol=1e-4, atol=1e-5)
    scene, image, ref, stable = lecture("diffuse")
    r = Reference(scene)
    o, d, t, sid = r.first_hit()
    assert scene.ambient == (0.0, 0.0, 0.0)
    p = o + np.where(np.isfinite(t), t, 0.0)[:, None] * d
    ng = r.normal(p, sid.ravel())
    light = np.array(scene.lights[0].position)
    ndl = _dot(ng, _unit(light - p)).reshape(H, W)
    sphere = [i for i, s in enumerate(scene.shapes) if isinstance(s, Sphere)][0]
    dark_side = (sid == sphere) & (ndl < -0.05)
    lit_side = (sid == sphere) & (ndl > 0.05)
    assert dark_side.sum() >= 3 and lit_side.sum() >= 10
    assert (image[dark_side] == 0).all()
    assert (image[lit_side] > 0).all()
    # brightness increases with n.l on the lit side (a cosine law, no view dependence)
    lum = image[lit_side].mean(axis=1)
    order = np.argsort(ndl[lit_side])
    assert np.all(np.diff(lum[order]) >= -1e-6)
    # the ground in the sphere's shadow is black too
    ground = (sid != sphere) & (sid >= 0) & stable
    assert ((image == 0).all(axis=2) & ground).sum() >= 3


def test_specular_matches_blinn_phong_and_highlights_shrink_with_p():
    assert_matches_reference("specular", rtol=1e-4, atol=1e-5)
    scene, image, _, _ = lecture("specular")
    mats = [scene.materials[s.material] for s in scene.shapes]
    assert [m.p for m in mats] == sorted(m.p for m in mats) and len({m.p for m in mats}) == 3
    # the specular share alone: the same scene with ks = 0
    no_spec = scene.replace(materials={k: Material(kd=m.kd, ka=m.ka, p=m.p) for k, m in scene.materials.items()})
    spec = image - warprt.render(no_spec, progress=False)
    _, _, _, sid = Reference(scene).first_hit()
    ks_i = max(mats[0].ks) * max(scene.lights[0].intensity)
    assert spec.max() <= ks_i * (1 + 1e-5)  # the peak of ks*I*(n.h)^p is ks*I
    areas = [int(((sid == i) & (spec.max(axis=2) > 0.1 * ks_i)).sum()) for i in range(3)]
    assert areas[0] > areas[1] >= areas[2], areas
    assert (spec >= 0).all()


def test_mirror_matches_the_recursive_reference_and_shows_what_the_camera_cannot_see():
    assert_matches_reference("mirror", rtol=1e-4, atol=2e-5)
    scene, image, ref, stable = lecture("mirror")
    r = Reference(scene)
    o, d, t, sid = r.first_hit()
    mirror = [i for i, s in enumerate(scene.shapes) if any(scene.materials[s.material].mirror)]
    assert len(mirror) == 1
    on_mirror = (sid == mirror[0]).ravel()
    p = (o + t[:, None] * d)[on_mirror]
    n = r.normal(p, sid.ravel()[on_mirror])
    rd = d[on_mirror] - 2 * _dot(d[on_mirror], n)[:, None] * n
    _, seen = r.nearest(p + 1e-5 * n, rd)
    hidden = set(seen.tolist()) - set(sid.ravel().tolist()) - {-1}
    assert hidden, "the mirror should show a shape the camera does not see directly"
    # pixels of the mirror that show the hidden shape take its colour
    for h in hidden:
        kd = np.array(scene.materials[scene.shapes[h].material].kd)
        shows = np.zeros(H * W, bool)
        shows[np.flatnonzero(on_mirror)[seen == h]] = True
        shows = shows.reshape(H, W) & stable
        assert shows.sum() >= 1
        dominant = np.argmax(kd)
        assert (np.argmax(image[shows], axis=1) == dominant).all()


def test_refraction_matches_the_reference_and_the_ball_lens_swaps_left_and_right():
    assert_matches_reference("refraction", rtol=1e-4, atol=1e-4)
    scene, image, ref, stable = lecture("refraction")
    r = Reference(scene)
    _, _, _, sid = r.first_hit()
    glass = [i for i, s in enumerate(scene.shapes) if any(scene.materials[s.material].transparency)][0]
    coloured = {name: i for i, s in enumerate(scene.shapes) for name in ("red", "blue") if s.material == name}
    cols = np.mgrid[0:H, 0:W][1]

    def reddish(img):
        return (img[..., 0] > 1.5 * img[..., 2]) & (img[..., 0] > 0.1)

    def bluish(img):
        return (img[..., 2] > 1.5 * img[..., 0]) & (img[..., 2] > 0.1)

    # in the world, red is left of blue as the camera sees it (smaller u) ...
    cam = scene.camera
    w = _unit(np.subtract(cam.eye, cam.look_at))
    u = _unit(np.cross(cam.up, w))
    assert np.dot(scene.shapes[coloured["red"]].center, u) < np.dot(scene.shapes[coloured["blue"]].center, u)
    # ... seen through the glass, red is right of blue
    in_glass = sid == glass
    red_in, blue_in = in_glass & reddish(image), in_glass & bluish(image)
    assert red_in.sum() >= 2 and blue_in.sum() >= 2
    assert cols[red_in].mean() > cols[blue_in].mean()


def test_refraction_fresnel_dims_the_view_through_the_glass():
    """Head-on, (1 - F)^2 of the light behind comes through two surfaces (F = 0.04 for ior 1.5)."""
    scene, image, ref, stable = lecture("refraction")
    glass_name = [s.material for s in scene.shapes if any(scene.materials[s.material].transparency)][0]
    mats = dict(scene.materials)
    mats[glass_name] = Material(kd=0.0, ka=0.0, transparency=1.0, ior=mats[glass_name].ior, fresnel="none")
    clear = warprt.render(scene.replace(materials=mats), progress=False)
    r = Reference(scene)
    o, d, t, sid = r.first_hit()
    glass = [i for i, s in enumerate(scene.shapes) if s.material == glass_name][0]
    c = np.array(scene.shapes[glass].center)
    # the pixel whose ray passes nearest the centre of the ball: near-normal incidence
    miss_dist = np.linalg.norm(np.cross(c - o, d), axis=1).reshape(H, W)
    j, i = np.unravel_index(np.argmin(np.where(sid == glass, miss_dist, np.inf)), (H, W))
    f0 = ((scene.materials[glass_name].ior - 1) / (scene.materials[glass_name].ior + 1)) ** 2
    through = (1 - f0) ** 2 * clear[j, i]
    reflected = image[j, i] - through
    bg = np.array(scene.background)
    assert (reflected > 0).all()
    # what is added back is light reflected off the surfaces: about F times the sky, twice over
    assert np.all(reflected < 2.5 * f0 * bg + 1e-3), (image[j, i], clear[j, i])
    assert np.all(reflected > 0.8 * f0 * bg), (image[j, i], clear[j, i])


def test_shadows_two_lights_give_two_hard_shadows():
    assert_matches_reference("shadows", rtol=1e-4, atol=1e-5)
    scene, image, ref, stable = lecture("shadows")
    r = Reference(scene)
    o, d, t, sid = r.first_hit()
    p = o + t[:, None] * d
    ground = [i for i, s in enumerate(scene.shapes) if isinstance(s, Plane)][0]
    on_ground = (sid == ground).ravel()
    ng = r.normal(p, sid.ravel())
    origin = p + 1e-5 * ng
    visible = []
    for light in scene.lights:
        to = np.array(light.position) - origin
        dist = np.linalg.norm(to, axis=1)
        visible.append((r.transmittance(origin, to / dist[:, None], dist)[:, 0] > 0).reshape(H, W))
    g = on_ground.reshape(H, W) & stable
    only = [g & visible[0] & ~visible[1], g & ~visible[0] & visible[1]]
    neither = g & ~visible[0] & ~visible[1]
    assert only[0].sum() >= 2 and only[1].sum() >= 2 and neither.sum() >= 1
    kd = np.float32(scene.materials[scene.shapes[ground].material].kd)
    # in the core of both shadows only ambient light remains, exactly ka*Ia
    assert (image[neither] == kd * np.float32(scene.ambient)).all()
    # each half-shadow has the colour of the one light that still reaches it
    for k in range(2):
        tint = np.array(scene.lights[k].intensity)
        rgb = image[only[k]] - kd * np.array(scene.ambient)
        assert np.allclose(rgb / rgb.sum(axis=1, keepdims=True), tint / tint.sum(), atol=1e-4)
    # a hard edge: somewhere a shadowed ground pixel is darker than its lit neighbour
    lum = image.sum(axis=2)
    shadowed = g & ~(visible[0] & visible[1])
    lit = g & visible[0] & visible[1]
    left_edge = shadowed[:, 1:] & lit[:, :-1] & (lum[:, 1:] < 0.8 * lum[:, :-1])
    right_edge = shadowed[:, :-1] & lit[:, 1:] & (lum[:, :-1] < 0.8 * lum[:, 1:])
    assert left_edge.any() and right_edge.any()
