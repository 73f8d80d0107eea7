"""Light samples per camera sample from the variance split (``samples = "auto"``,
``warprt.splitting``): the split's arithmetic against its closed form, the choice on scenes whose
noise is all in the light or all in the camera, its determinism, and that the image it gives
converges to the same answer as one shadow ray per sample."""

from __future__ import annotations

import dataclasses
import functools
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
        # (uniform renders: they take the split map; an adaptive render, asked for, the one count)
        render=warprt.RenderSettings(sampler="sobol", adaptive=False))


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
    assert np.array_equal(r2.light_map, r.light_map)
    # it is the fixed counts' image: each block's pixels those of its count (one count: all of them)
    counts = _pixel_counts(r.light_map, n, a.shape)
    for k in np.unique(counts):
        fixed = warprt.Renderer(_penumbra_scene(int(k)), device=device).render(spp=2, seed=3, workers=1, progress=False)
        assert np.array_equal(fixed.image[counts == k], a[counts == k])


def _pixel_counts(light_map, n, shape):
    """Each pixel's count of shadow rays per camera sample under a split map (or n without one)."""
    if light_map is None:
        return np.full(shape[:2], n)
    t = splitting.MAP_TILE
    return np.repeat(np.repeat(light_map, t, 0), t, 1)[:shape[0], :shape[1]]


@pytest.mark.parametrize("packets", [True, False])
def test_a_split_map_gives_each_pixel_its_blocks_count(monkeypatch, packets):
    """Under a split map every pixel is, bit for bit, the pixel of the render whose "auto" light
    takes its block's count, with camera packets and one by one: with the renderer's blocks of
    MAP_TILE pixels (a multiple of a packet's 8 lanes: a packet's lanes share a block) and with
    blocks of 3 pixels, set by hand, whose packets at 3 spp take lanes from pixels of different
    blocks. An adaptive render takes the one count throughout, and the next uniform render the
    map again (the recorded launches see the scene's record as it is now)."""
    counts = np.array([[1, 16, 2], [8, 4, 1]], np.int32)  # 40 × 24 pixels: partial blocks right and below
    monkeypatch.setattr(splitting, "light_map", lambda *args, **kwargs: counts)
    # (the kernel variants of scenes/soft_shadows.toml, which test_features renders both ways)
    renderer = functools.partial(warprt.Renderer, device="cpu", packets=packets,
                                 features=warprt.Features(meshes=True, area_lights=True, analytic_bvh=True))
    r = renderer(_penumbra_scene("auto", width=40, height=24))
    n = r.light_samples()
    assert np.array_equal(r.light_map, counts)
    r.render(spp=1, seed=0, progress=False)  # (timed: the next render is one pass)
    fixed = {int(k): renderer(_penumbra_scene(int(k), width=40, height=24)).render(spp=3, seed=5, progress=False).image
             for k in 2 ** np.arange(5)}
    img = r.render(spp=3, seed=5, progress=False).image
    per_pixel = _pixel_counts(counts, n, img.shape)
    for k in np.unique(counts):
        assert np.array_equal(fixed[k][per_pixel == k], img[per_pixel == k]), k
    one = renderer(_penumbra_scene(n, width=40, height=24))
    adaptive = r.render(spp=4, seed=5, progress=False, adaptive=True).image
    assert adaptive.tobytes() == one.render(spp=4, seed=5, progress=False, adaptive=True).image.tobytes()
    assert r.render(spp=3, seed=5, progress=False).image.tobytes() == img.tobytes()
    with pytest.raises(warprt.RenderError, match=r"8 × 14 counts of 1 to 1024, got int32 \(8, 13\)"):
        r.built.set_light_map(np.ones((8, 13), np.int32), 3)
    with pytest.raises(warprt.RenderError, match="counts of 1 to 1024"):
        r.built.set_light_map(np.zeros((8, 14), np.int32), 3)
    # blocks of 3 pixels (14 × 8 of them), every count somewhere
    small = 2 ** np.random.default_rng(2).integers(0, 5, size=(8, 14)).astype(np.int32)
    r.built.set_light_map(small, 3)
    img = r.render(spp=3, seed=5, progress=False).image
    per_pixel = np.repeat(np.repeat(small, 3, 0), 3, 1)[:24, :40]
    for k in np.unique(small):
        assert np.array_equal(fixed[k][per_pixel == k], img[per_pixel == k]), k


def test_tile_errors_sum_each_blocks_pilot_rows():
    rng = np.random.default_rng(3)
    width, height, tile = 37, 45, 16
    rows = np.arange(4, height, 8)
    a, b = rng.normal(size=(2, len(rows) * width))
    got = splitting.tile_errors(a, b, rows, width, height, tile)
    d2 = ((a - b) ** 2 / 2).reshape(len(rows), width)
    assert got.shape == (3, 3)
    for i in range(3):
        for j in range(3):
            mine = rows // tile == i
            block_rows = min(tile, height - i * tile)
            want = d2[mine][:, j * tile:(j + 1) * tile].sum() * block_rows / mine.sum()
            assert got[i, j] == pytest.approx(want, rel=1e-12)


def _objective(e_cam, e_light, pixels, n, cost_ratio=splitting.COST_RATIO, rate=splitting.RATE):
    return float((e_cam + e_light * n ** -rate).sum() * (pixels * (cost_ratio + n)).sum() ** rate)


def test_a_split_map_moves_shadow_rays_to_the_blocks_whose_noise_is_the_lights():
    """Blocks alike get no map (one count does as well); a penumbra's blocks (light noise only)
    get more shadow rays than the blocks of edges (camera noise only), which get 1; and the map's
    cost in the model is below the best single count's and near the least over every map (brute
    force over the 5^4 maps of 2 × 2 blocks: the sweep finds it)."""
    w = h = 32
    pixels = np.full((2, 2), 256.0)
    same = np.full((2, 2), 1.0)
    assert splitting.light_map(same, same * 0.5, w, h) is None
    e_cam = np.array([[1.0, 0.0], [1.0, 0.0]])
    e_light = np.array([[0.0, 4.0], [0.0, 4.0]])
    p = splitting.PROBE ** -splitting.RATE
    m = splitting.light_map(e_cam + e_light, e_cam + e_light * p, w, h)
    assert m is not None and m.dtype == np.int32
    assert (m[:, 0] == 1).all() and (m[:, 1] > 1).all()
    rng = np.random.default_rng(7)
    choices = 2 ** np.arange(5)
    grids = np.stack(np.meshgrid(*[choices] * 4, indexing="ij"), -1).reshape(-1, 2, 2)
    for _ in range(20):
        e_cam, e_light = rng.exponential(size=(2, 2, 2)) * rng.uniform(0, 1, size=(2, 1, 1)) ** 3
        m = splitting.light_map(e_cam + e_light, e_cam + e_light * p, w, h)
        one = splitting.best_samples(e_cam.sum(), e_light.sum())
        uniform = _objective(e_cam, e_light, pixels, np.full((2, 2), one))
        least = min(_objective(e_cam, e_light, pixels, g) for g in grids)
        if m is None:  # one count is within 1% of the best map
            assert uniform * 0.99 <= least * (1 + 1e-12)
            continue
        got = _objective(e_cam, e_light, pixels, m)
        assert got < 0.99 * uniform
        assert got == pytest.approx(least, rel=1e-12)  # (2000 such draws: the sweep found the least in each)


def test_the_light_rows_are_rewritten_only_when_the_count_changes():
    """Every render sets the "auto" lights' count; the table is written only when it changes
    (a row changed behind its back stays as it is until then)."""
    r = warprt.Renderer(_penumbra_scene("auto"), device="cpu")
    r.render(spp=2, seed=0, progress=False, adaptive=True)  # (an adaptive render: no split map)
    n = r.light_samples()
    rows = r.built.data.alights.numpy()  # (a view of the CPU array)
    assert int(rows["samples"][0]) == n
    rows["samples"][0] = 99
    r.built.set_auto_light_samples(n)
    assert int(r.built.data.alights.numpy()["samples"][0]) == 99
    r.built.set_auto_light_samples(n + 1)
    assert int(r.built.data.alights.numpy()["samples"][0]) == n + 1
    r.render(spp=2, seed=0, progress=False, adaptive=True)
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
