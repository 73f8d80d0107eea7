"""Contact shadows of small objects on large grounds: spawn offsets must follow the error of the
hit point, not the size of the shape it lies on.

Failure mode: a ray leaving a surface starts from the hit point moved off the surface by an
offset. If that offset is one scalar taken from the magnitude of every coordinate the hit was
computed from (|corner| + |edge1| + |edge2| for a rectangle of side L), a ground 800 units wide
lifts the origin by ~1.5e-2 although the hit point's error along the normal is many orders
smaller (the ground's y coordinates are all 0). A shadow ray then starts above the bottom of a
small sphere resting on the ground: the contact shadow shrinks, and a mirror ground's reflection
loses the sphere's underside.

Scene: a sphere of radius 0.06 resting on the ground y = 0, seen from close by. The ground is an
infinite ``Plane``, a ``Rectangle``, a ``Disk`` or a two-triangle ``Mesh`` of side L (L = 1 … 1e4).
Near the sphere all of them are the same surface, so

* hard shadows (one point light, pixel centres) must match the shadow test done in float64 on
  every pixel whose answer is decidable (it does not change when the light moves by 1e-4);
* soft shadows (a rectangle light, the same sample sequence for every ground) and a mirror
  ground must give the ``Plane`` image, up to the few samples whose shadow ray grazes the sphere.

``naive`` below re-renders with the old scalar rule (``spawn_offset_naive``) and shows it failing
on the same scenes.
"""

from __future__ import annotations

import numpy as np
import pytest

import warprt

from ._util import image, pixel_hits, unit

R = 0.06  # sphere radius
CENTER = (0.0, R, 0.0)
LIGHT = np.array([0.25, 0.6, 0.15])
SIZES = [1.0, 80.0, 800.0, 1e4]
KINDS = ["plane", "rectangle", "disk", "mesh", "mesh_scaled"]
SHIFTS = [(0.0, 0.0), (27.0, -23.0)]  # where the sphere rests: at the origin, and off it
KD = 0.8


def ground(kind: str, L: float, material: str = "g"):
    h = L / 2
    if kind == "mesh_scaled":  # a unit quad made L wide by its instance transform
        v = np.array([[-1, 0, -1], [1, 0, -1], [1, 0, 1], [-1, 0, 1]], np.float64)
        return warprt.Mesh(vertices=v, faces=[[0, 2, 1], [0, 3, 2]], material=material,
                           transform=warprt.Transform(scale=h))
    if kind == "plane":
        return warprt.Plane(material=material)
    if kind == "rectangle":
        return warprt.Rectangle(corner=(-h, 0.0, -h), edge1=(0.0, 0.0, L), edge2=(L, 0.0, 0.0), material=material)
    if kind == "disk":
        return warprt.Disk(center=(0.0, 0.0, 0.0), radius=h, material=material)
    v = np.array([[-h, 0, -h], [h, 0, -h], [h, 0, h], [-h, 0, h]], np.float64)
    return warprt.Mesh(vertices=v, faces=[[0, 2, 1], [0, 3, 2]], material=material)


def _at(p, shift):
    return (p[0] + shift[0], p[1], p[2] + shift[1])


def scene(kind: str, L: float, light: str = "point", mirror: bool = False, shift=(0.0, 0.0), width: int = 96):
    ground_mat = warprt.Material(kd=0.0, ka=0.0, mirror=0.9) if mirror else warprt.Material(kd=KD, ka=0.0)
    if light == "point":
        lights = (warprt.PointLight(position=_at(LIGHT, shift), intensity=1.0),)
    else:
        lights = (warprt.RectLight(corner=_at((0.15, 0.6, 0.05), shift), edge1=(0.2, 0.0, 0.0), edge2=(0.0, 0.0, 0.2),
                                   radiance=8.0, samples=1),)
    return warprt.Scene(
        camera=warprt.Camera(eye=_at((-0.2, 0.26, 0.14), shift), look_at=_at((-0.03, 0.0, -0.01), shift), fov=40,
                             width=width, height=width),
        materials={"g": ground_mat, "s": warprt.Material(kd=(0.7, 0.5, 0.3), ka=0.0)},
        shapes=(ground(kind, L), warprt.Sphere(center=_at(CENTER, shift), radius=R, material="s")),
        lights=lights, background=0.3 if mirror else 0.0,
        render=warprt.RenderSettings(sampler="regular" if light == "point" else "sobol"))


def _sphere_blocks(o, l, dist, c, r=R):
    """float64: does the segment o + s·l, s in (0, dist), meet the sphere; and its clearance
    (closest distance of the segment's line to the centre, minus r)."""
    f = o - c
    b = np.sum(f * l, 1)
    perp = np.linalg.norm(f - b[:, None] * l, axis=1)
    disc = b * b - (np.sum(f * f, 1) - r * r)
    sq = np.sqrt(np.maximum(disc, 0.0))
    hit = np.zeros(len(o), bool)
    for t in (-b - sq, -b + sq):
        hit |= (disc > 0) & (t > 0) & (t < dist)
    return hit, perp - r


def hard_shadow_reference(sc, L: float, shift=(0.0, 0.0)):
    """Per pixel centre on the ground: lit value kd·I·cosθ (the lecture point light, no falloff)
    or 0 in shadow, from the exact ground hit y = 0 in float64; and which pixels are decidable."""
    o, d, h = pixel_hits(sc)
    c = np.array(_at(CENTER, shift))
    light = np.array(_at(LIGHT, shift))
    t = -o[:, 1] / d[:, 1]
    p = o + t[:, None] * d
    sphere_first, _ = _sphere_blocks(o, d, np.where(t > 0, t, np.inf), c)
    near = (np.abs(p[:, 0] - c[0]) < 8 * R) & (np.abs(p[:, 2] - c[2]) < 8 * R)
    inside = (np.abs(p[:, 0]) < 0.45 * L) & (np.abs(p[:, 2]) < 0.45 * L)
    on_ground = (t > 0) & ~sphere_first & near & inside  # ground pixels within 8 radii of the contact
    to_l = light - p
    dist = np.linalg.norm(to_l, axis=1)
    l = to_l / dist[:, None]
    blocked, clearance = _sphere_blocks(p, l, dist, c)
    value = np.where(blocked, 0.0, KD * np.clip(l[:, 1], 0.0, None))
    decidable = on_ground & (np.abs(clearance) > 1e-4)
    return value, decidable


CASES = [(L, (0.0, 0.0)) for L in SIZES] + [(L, SHIFTS[1]) for L in SIZES[1:]]
CASE_IDS = [f"L={L:g}" + ("" if s == (0.0, 0.0) else "-offcentre") for L, s in CASES]


def hard_shadow_errors(kind, L, shift):
    sc = scene(kind, L, shift=shift)
    value, ok = hard_shadow_reference(sc, L, shift)
    got = image(sc, spp=1).reshape(-1, 3)[:, 0]
    # float32 hit point vs the exact one: cosθ moves by ~1e-6; 1e-4 covers it 100 times over
    return ok & (np.abs(got - value) > 1e-4), ok, value


@pytest.mark.parametrize("L,shift", CASES, ids=CASE_IDS)
@pytest.mark.parametrize("kind", KINDS)
def test_hard_contact_shadow_matches_float64(kind, L, shift):
    bad, ok, value = hard_shadow_errors(kind, L, shift)
    assert ok.sum() > 2000  # the test looks at a real contact shadow
    assert (ok & (value == 0)).sum() > 500
    assert bad.sum() == 0, f"{bad.sum()} of {ok.sum()} ground pixels off"


@pytest.mark.parametrize("L", [800.0, 1e4])
def test_the_scalar_offset_rule_loses_the_contact_shadow(L):
    """Naive versus ours, on the shadow rays of the rectangle ground (float64): lifting each
    ground point by the old scalar offset, 2^-17·(max|corner| + max|edge1| + max|edge2|) on
    every axis, frees hundreds of shadowed pixels near the contact; the per-component bound
    projected on the normal, 2^-17·(|n|·(|corner| + |edge1| + |edge2|)), is 0 here and frees none."""
    sc = scene("rectangle", L)
    rect = sc.shapes[0]
    c, e1, e2 = (np.abs(np.asarray(a, np.float64)) for a in (rect.corner, rect.edge1, rect.edge2))
    n = np.array([0.0, 1.0, 0.0])
    o, d, _ = pixel_hits(sc)
    t = -o[:, 1] / d[:, 1]
    p = o + t[:, None] * d
    value, ok = hard_shadow_reference(sc, L)
    shadowed = ok & (value == 0)
    light, centre = np.array(LIGHT), np.array(CENTER)

    def freed(offset):
        q = p + offset * n
        to_l = light - q
        dist = np.linalg.norm(to_l, axis=1)
        blocked, _ = _sphere_blocks(q, to_l / dist[:, None], dist, centre)
        return int((shadowed & ~blocked).sum())

    naive = 2.0 ** -17 * (c.max() + e1.max() + e2.max())
    ours = 2.0 ** -17 * float(n @ (c + e1 + e2))
    assert freed(naive) > 20
    assert ours == 0.0 and freed(ours) == 0


@pytest.mark.parametrize("L", SIZES[1:], ids=[f"L={s:g}" for s in SIZES[1:]])
@pytest.mark.parametrize("kind", KINDS[1:])
@pytest.mark.parametrize("effect", ["soft", "mirror"])
def test_large_grounds_give_the_plane_image(kind, L, effect):
    """Soft shadows and a mirror ground: every ground kind and size renders the Plane's image with
    the same samples. A pixel may differ only where a sample's ray grazes the sphere (its answer
    flips on a float32 rounding): at most one sample's worth, on a handful of pixels."""
    spp = 16 if effect == "soft" else 4
    kw = dict(light="rect") if effect == "soft" else dict(mirror=True)
    ref = image(scene("plane", 1.0, **kw), spp=spp)
    img = image(scene(kind, L, **kw), spp=spp)
    diff = np.abs(img - ref).max(axis=2)
    one_sample = 1.0 / spp * max(float(ref.max()), 1e-6)
    assert (diff > one_sample).sum() == 0, f"{(diff > one_sample).sum()} pixels beyond one sample (max {diff.max():.3g})"
    assert (diff > 1e-4).sum() <= 0.002 * diff.size, f"{(diff > 1e-4).sum()} pixels differ"
