"""Light samples per camera sample from the variance split (``samples = "auto"``,
``warprt.splitting``): the split's arithmetic against its closed form, the choice on scenes whose
noise is all in the light or all in the camera, its determinism, and that the image it gives
converges to the same answer as one shadow ray per sample."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

import warprt
from warprt import splitting
from warprt.scene.loader import scene_from_string as load_scene


def test_the_split_is_recovered_from_the_two_pilots():
    # per pixel: V_cam + V_light with one light sample, V_cam + V_light / P with P
    rng = np.random.default_rng(0)
    v_cam, v_light = rng.uniform(0, 1, 500), rng.uniform(0, 3, 500)
    p = splitting.PROBE
    got = splitting.variance_split(v_cam + v_light, v_cam + v_light / p)
    assert got == pytest.approx((v_cam.sum(), v_light.sum()), rel=1e-12)
    # noise in the estimates never makes either part negative
    assert splitting.variance_split(np.ones(3), 2 * np.ones(3)) == (3.0, 0.0)
    assert splitting.variance_split(np.ones(3), np.zeros(3)) == (0.0, 3.0 * p / (p - 1))


@pytest.mark.parametrize("ratio, expected", [(0.0, 1), (0.5, 1), (1.0, 1), (3.9, 2), (4.0, 2), (16.0, 4),
                                             (45.0, 8), (64.0, 8), (1e6, splitting.MAX_SAMPLES)])
def test_the_best_count_is_the_nearest_power_of_two_to_the_square_root(ratio, expected):
    assert splitting.best_samples(1.0, ratio) == expected
    # with two "auto" lights a unit of N costs two light samples
    assert splitting.best_samples(1.0, 2.0 * ratio, n_lights=2) == expected
    assert splitting.best_samples(0.0, 1.0) == splitting.MAX_SAMPLES
    assert splitting.best_samples(1.0, 0.0) == 1


def _penumbra_scene(samples, aperture=0.0, width=48, height=32):
    return warprt.Scene(
        camera=warprt.Camera(eye=(0.0, 3.0, 3.0), look_at=(0.0, 0.0, 0.0), width=width, height=height,
                             aperture=aperture, focus_distance=4.2 if aperture else None),
        shapes=(warprt.Plane(point=(0, 0, 0), normal=(0, 1, 0), material="m"),
                warprt.Sphere(center=(0.0, 0.6, 0.0), radius=0.5, material="m")),
        materials={"m": warprt.Material(kd=0.7, ka=0.0)},
        lights=(warprt.RectLight(corner=(-1.0, 2.0, -1.0), edge1=(2.0, 0.0, 0.0), edge2=(0.0, 0.0, 2.0),
                                 radiance=2.0, samples=samples),),
        render=warprt.RenderSettings(sampler="sobol"))


def test_auto_follows_where_the_noise_is(device):
    """A big light close over a sphere: the noise is the penumbra's, so auto takes several shadow
    rays per camera sample; the same light seen through a wide defocused lens, whose blur is the
    noise, gets fewer."""
    sharp = warprt.Renderer(_penumbra_scene("auto"), device=device)
    # (the all-features kernel, which the suite compiles anyway: the pilot's images, and so the
    # choice, are the same bit for bit with any kernel)
    blurred = warprt.Renderer(_penumbra_scene("auto", aperture=0.6), device=device, features=warprt.Features.full())
    n_sharp, n_blur = sharp.light_samples(), blurred.light_samples()
    assert n_sharp >= 4 and n_blur < n_sharp
    # without "auto" there is nothing to choose
    assert warprt.Renderer(_penumbra_scene(1), device=device).light_samples() is None


def test_auto_is_chosen_once_and_the_same_for_any_workers_and_seed(device):
    r = warprt.Renderer(_penumbra_scene("auto"), device=device)
    a = r.render(spp=2, seed=3, workers=1, progress=False).image
    n = r.light_samples()
    r2 = warprt.Renderer(_penumbra_scene("auto"), device=device)
    assert r2.light_samples(workers=2) == n
    b = r2.render(spp=2, seed=3, workers=2, slices=5, progress=False).image
    assert a.tobytes() == b.tobytes()
    # it is the fixed count's image
    fixed = warprt.Renderer(_penumbra_scene(n), device=device).render(spp=2, seed=3, workers=1, progress=False)
    assert fixed.image.tobytes() == a.tobytes()


def test_auto_converges_to_the_one_shadow_ray_image(device):
    """Splitting changes the noise, not the answer: the mean over the image with auto equals the
    one-ray image's within 4 standard errors (estimated from independent seeds of each)."""
    means = {}
    for samples in (1, "auto"):
        r = warprt.Renderer(_penumbra_scene(samples), device=device)
        means[samples] = [float(r.render(spp=8, seed=s, progress=False).image.mean()) for s in range(6)]
    a, b = np.array(means[1]), np.array(means["auto"])
    se = math.sqrt(a.var(ddof=1) / a.size + b.var(ddof=1) / b.size)
    assert abs(a.mean() - b.mean()) < 4 * se + 1e-6 * abs(a.mean())


def test_scene_files_say_auto_and_bad_values_are_named(tmp_path):
    text = """
[camera]
width = 8
height = 8
[[lights]]
type = "rectangle"
samples = "auto"
"""
    scene = load_scene(text)
    assert scene.lights[0].samples == "auto"
    with pytest.raises(warprt.SceneError, match=r'lights\[0\]\.samples: .*"auto"'):
        load_scene(text.replace('"auto"', '"many"'))
    with pytest.raises(warprt.SceneError, match="samples"):
        load_scene(text.replace('"auto"', "0"))
    assert dataclasses.replace(scene.lights[0], samples=4).samples == 4
