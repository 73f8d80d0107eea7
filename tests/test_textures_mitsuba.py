"""Textured renders against an independent reference: Mitsuba 3 (scalar_rgb) with the same
bitmap texture (``bitmap``, bilinear filtering) on the same scene converges to the same image,
pixel by pixel within the two renderers' noise. Skipped where Mitsuba (the ``peers`` extra) is
not installed."""

from __future__ import annotations

import numpy as np
import pytest

import warprt
from benchmarks import corpus_scenes as cs
from benchmarks import mitsuba_export as mx
from tests.test_corpus import _mitsuba_batches, _same_within_noise, mi  # noqa: F401 (mi: the fixture)


def textured_scene(wrap: str) -> warprt.Scene:
    """A tilted rectangle with a 7 × 5 bitmap (texels several pixels wide: the bilinear ramps
    show) repeated 1.5 times, over a grey ground, under a point light and the sun."""
    rng = np.random.default_rng(3)
    tex = warprt.Texture(image=rng.integers(0, 256, size=(5, 7, 3), dtype=np.uint8), scale=1.5, wrap=wrap)
    return warprt.Scene(
        camera=cs.camera((0.0, 1.2, 3.0), (0.0, 0.5, 0.0), 40.0, (32, 24)),
        shapes=(cs.ground(), warprt.Rectangle(corner=(-0.9, 0.05, -0.4), edge1=(1.8, 0.0, 0.3), edge2=(0.1, 1.2, -0.5),
                                             material="t")),
        materials={"ground": cs.lambert(0.5), "t": warprt.Material(kd=(0.9, 0.8, 0.7), texture=tex)},
        lights=(cs.point_light((0.5, 2.0, 2.0), 3.0), cs.sun((0.3, -1.0, -0.4), 0.6)))


@pytest.mark.slow
@pytest.mark.parametrize("wrap", ["repeat", "clamp"])
def test_bitmap_texture_converges_to_mitsubas(mi, tmp_path, wrap):
    scene = textured_scene(wrap)
    d = mx.to_mitsuba(scene, mi, sampler="independent", mesh_dir=tmp_path)
    m = _mitsuba_batches(mi, d, 128, seeds=range(10, 18))
    r = warprt.Renderer(scene.with_settings(sampler="sobol"), device="cpu")
    w = [r.render(spp=64, seed=k, workers=2, progress=False).image.astype(np.float64) for k in range(1, 9)]
    outliers, median, mean_z = _same_within_noise(m, w)
    print(f"wrap={wrap}: |z| > 4 in {outliers:.4f} of the values, median |z| {median:.3f}, image mean z {mean_z:.2f}")
    assert outliers < 0.01 and median < 1.0 and mean_z < 4, (outliers, median, mean_z)
    # the comparison can see a texture error: the same scene with the texture's rows the wrong way
    # up (what a v convention mistake would give) is far outside the noise
    flipped = scene.replace(materials={**scene.materials, "t": warprt.Material(
        kd=(0.9, 0.8, 0.7), texture=warprt.Texture(image=scene.materials["t"].texture.texels[::-1], scale=1.5,
                                                    wrap=wrap))})
    wf = [warprt.Renderer(flipped.with_settings(sampler="sobol"), device="cpu").render(
        spp=64, seed=k, workers=2, progress=False).image.astype(np.float64) for k in range(1, 9)]
    assert _same_within_noise(m, wf)[0] > 0.05


@pytest.mark.parametrize("wrap", ["repeat", "clamp"])
def test_the_exported_bitmap_is_mitsubas_lookup_of_the_same_uv(mi, wrap):
    """The texture term itself, without noise: Mitsuba's ``bitmap`` texture (as exported: the
    linear texels flipped to Mitsuba's v, bilinear, the wrap mode and scale) evaluated at 500
    random uv in [-0.3, 1.3]² equals warprt's float64 bilinear reference to float32 rounding, and
    Mitsuba's rectangle puts uv = (a, b) at corner + a·edge1 + b·edge2 as warprt's does."""
    from tests.test_textures import bilinear_ref

    rng = np.random.default_rng(5)
    tex = warprt.Texture(image=rng.integers(0, 256, size=(5, 7, 3), dtype=np.uint8), scale=1.5, wrap=wrap)
    t = mi.load_dict(mx.bitmap(tex, (0.9, 0.8, 0.7)))
    si = mi.SurfaceInteraction3f()
    uv = rng.uniform(-0.3, 1.3, size=(500, 2))
    got = []
    for u, v in uv:
        si.uv = mi.Point2f(u, v)
        got.append(np.array(t.eval(si)))
    want = bilinear_ref(tex.texels, uv[:, 0] * 1.5, uv[:, 1] * 1.5, wrap) * (0.9, 0.8, 0.7)
    np.testing.assert_allclose(np.array(got), want, atol=3e-6, rtol=0)
    corner, e1, e2 = np.array((-0.9, 0.05, -0.4)), np.array((1.8, 0.0, 0.3)), np.array((0.1, 1.2, -0.5))
    scene = mi.load_dict({"type": "scene", "r": {"type": "rectangle",
                                                 "to_world": mi.ScalarTransform4f(mx.rect_frame(corner, e1, e2).tolist())}})
    for a, b in rng.uniform(0.01, 0.99, size=(50, 2)):
        p = corner + a * e1 + b * e2
        o = p + np.array([0.2, 0.3, 2.0])
        hit = scene.ray_intersect(mi.Ray3f(mi.Point3f(*o), mi.Vector3f(*((p - o) / np.linalg.norm(p - o)))))
        np.testing.assert_allclose(np.array(hit.uv), (a, b), atol=1e-6)
