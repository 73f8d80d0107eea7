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
    # the pilots' errors: E_cam + E_light with one light sample, E_cam + E_light P^-rate with P
    rng = np.random.default_rng(0)
    p = splitting.PROBE
    for rate in (1.0, splitting.RATE):
        e_cam, e_light = rng.uniform(0, 1), rng.uniform(0, 3)
        got = splitting.error_split(e_cam + e_light, e_cam + e_light * p ** -rate, rate=rate)
        assert got == pytest.approx((e_cam, e_light), rel=1e-12)
    # noise in the estimates never makes either part negative
    assert splitting.error_split(1.0, 2.0) == (1.0, 0.0)
    assert splitting.error_split(1.0, 0.0, rate=1.0) == (0.0, p / (p - 1))
    # a pixel mean's error from two independent renders: Var(a - b) / 2, summed over the pixels
    a, b = rng.normal(size=(2, 4000))
    assert splitting.pixel_error(a, b) == pytest.approx(float(np.sum((a - b) ** 2)) / 2, rel=1e-12)
    assert splitting.pixel_error(a, a) == 0.0


def _least_error_at_equal_cost(e_cam, e_light, cost_ratio, rate):
    """The power of two of the least (1 + N / cost_ratio)^rate (e_cam + e_light N^-rate), found
    over a fine grid of real N first and then among the two powers of two around it."""
    grid = np.exp(np.linspace(0.0, np.log(splitting.MAX_SAMPLES), 20001))
    f = lambda n: (1.0 + n / cost_ratio) ** rate * (e_cam + e_light * n ** -rate)
    n_real = grid[np.argmin(f(grid))]
    lo = 2 ** int(np.floor(np.log2(n_real)))
    hi = min(2 * lo, splitting.MAX_SAMPLES)
    return lo if f(lo) <= f(hi) else hi


@pytest.mark.parametrize("ratio, expected", [(0.0, 1), (0.5, 1), (1.0, 1), (3.9, 2), (4.0, 2), (16.0, 4),
                                             (45.0, 8), (64.0, 8), (1e6, splitting.MAX_SAMPLES)])
def test_independent_samples_take_the_square_root_rule(ratio, expected):
    # rate 1 and equal costs: (1 + N)(1 + R / N) is least at N = sqrt(R)
    assert splitting.best_samples(1.0, ratio, cost_ratio=1.0, rate=1.0) == expected
    # with two "auto" lights a unit of N costs two light samples
    assert splitting.best_samples(1.0, 2.0 * ratio, n_lights=2, cost_ratio=2.0, rate=1.0) == expected
    assert splitting.best_samples(0.0, 1.0) == splitting.MAX_SAMPLES
    assert splitting.best_samples(1.0, 0.0) == 1


@pytest.mark.parametrize("ratio", [0.3, 1.0, 2.0, 5.0, 8.8, 15.7, 40.0, 200.0, 1e4])
def test_stratified_samples_take_the_least_error_at_equal_cost(ratio):
    """With a stratifying sampler both parts fall as samples^-1.5: the count is the power of two
    of least error at equal cost, found here by brute force over real N."""
    for cost_ratio in (1.0, splitting.COST_RATIO, 5.0):
        want = _least_error_at_equal_cost(1.0, ratio, cost_ratio, splitting.RATE)
        assert splitting.best_samples(1.0, ratio, cost_ratio=cost_ratio) == want
        assert splitting.best_samples(2.0, 2.0 * ratio, n_lights=2, cost_ratio=2.0 * cost_ratio) == want


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
    # (96 × 64 pixels: at 48 × 32 a pixel's footprint holds enough of the penumbra's detail that
    # its camera samples' part is a fifth of the noise, and auto takes 2)
    sharp = warprt.Renderer(_penumbra_scene("auto", width=96, height=64), device=device)
    # (the all-features kernel, which the suite compiles anyway: the pilot's images, and so the
    # choice, are the same bit for bit with any kernel)
    blurred = warprt.Renderer(_penumbra_scene("auto", aperture=0.6, width=96, height=64), device=device,
                              features=warprt.Features.full())
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


def test_the_light_rows_are_rewritten_only_when_the_count_changes():
    """Every render sets the "auto" lights' count; the table is written only when it changes
    (a row changed behind its back stays as it is until then)."""
    r = warprt.Renderer(_penumbra_scene("auto"), device="cpu")
    r.render(spp=1, seed=0, progress=False)
    n = r.light_samples()
    rows = r.built.data.alights.numpy()  # (a view of the CPU array)
    assert int(rows["samples"][0]) == n
    rows["samples"][0] = 99
    r.built.set_auto_light_samples(n)
    assert int(r.built.data.alights.numpy()["samples"][0]) == 99
    r.built.set_auto_light_samples(n + 1)
    assert int(r.built.data.alights.numpy()["samples"][0]) == n + 1
    r.render(spp=1, seed=0, progress=False)
    assert int(r.built.data.alights.numpy()["samples"][0]) == n
    # a fresh table holds 1 until a count is set, whichever comes first
    for k in (1, 2, 3, 4, 8, 16):
        built = warprt.Renderer(_penumbra_scene("auto"), device="cpu").built
        assert int(built.data.alights.numpy()["samples"][0]) == 1
        built.set_auto_light_samples(k)
        assert int(built.data.alights.numpy()["samples"][0]) == k


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


def test_the_regular_grid_has_no_error_to_split(device):
    """The regular sampler's points do not move with the seed: the pilot's two seeds agree, so
    there is no error to split and auto takes one shadow ray."""
    sc = _penumbra_scene("auto", width=96, height=64).with_settings(sampler="regular")
    assert warprt.Renderer(sc, device=device, features=warprt.Features.full()).light_samples() == 1
