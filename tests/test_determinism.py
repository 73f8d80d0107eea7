"""Replayable rendering: the image is a pure function of (scene, spp, seed), bit for bit, whatever
the worker count, tile size or pass split; and a full ray stack is counted, never undefined.

The scenes use mirrors and glass (the recursive ray stack, Fresnel splits) and the jittered
samplers, so every random dimension and every branch of the integrator takes part.
"""

from __future__ import annotations

import numpy as np
import pytest

import warprt


def glass_scene(sampler: str = "stratified") -> warprt.Scene:
    return warprt.Scene(
        camera=warprt.Camera(eye=(0.0, 1.2, 4.0), look_at=(0.0, 0.5, 0.0), fov=45, width=24, height=20),
        shapes=(warprt.Plane(point=(0, 0, 0), normal=(0, 1, 0), material="floor"),
                warprt.Sphere(center=(-0.7, 0.5, 0.0), radius=0.5, material="glass"),
                warprt.Sphere(center=(0.6, 0.45, -0.3), radius=0.45, material="chrome"),
                warprt.Sphere(center=(0.1, 0.25, 0.9), radius=0.25, material="matte")),
        materials={"floor": warprt.Material(kd=(0.6, 0.6, 0.5), mirror=0.2),
                   "glass": warprt.Material(kd=0.0, transparency=0.9, ior=1.5, fresnel="exact"),
                   "chrome": warprt.Material(kd=0.1, ks=0.5, p=50, mirror=0.8),
                   "matte": warprt.Material(kd=(0.8, 0.2, 0.1))},
        lights=(warprt.PointLight(position=(2.0, 4.0, 3.0), intensity=0.9),
                warprt.PointLight(position=(-3.0, 2.0, 1.0), intensity=(0.2, 0.3, 0.5))),
        ambient=0.05, background=(0.3, 0.4, 0.6),
        render=warprt.RenderSettings(sampler=sampler, spp=8))


@pytest.fixture(scope="module")
def renderer() -> warprt.Renderer:
    return warprt.Renderer(glass_scene(), device="cpu")


def test_the_scene_uses_the_recursive_kernel(renderer):
    assert renderer.features.secondary and renderer.features.refraction


@pytest.mark.parametrize("options", [
    dict(workers=2),
    dict(workers=1, slices=5),
    dict(workers=2, slices=7),
    dict(workers=2, slices=64),
    dict(workers=1, pass_spp=1),
    dict(workers=2, pass_spp=3, slices=3),
    dict(workers=2, pass_spp=7),  # a first pass of one sample, then the other seven at once
], ids=lambda o: ",".join(f"{k}={v}" for k, v in o.items()))
def test_bit_identical_for_any_workers_slices_and_passes(renderer, options):
    base = renderer.render(spp=8, seed=3, workers=1, slices=16, pass_spp=1, progress=False)
    other = renderer.render(spp=8, seed=3, progress=False, **options)
    assert base.spp == other.spp == 8
    assert base.image.tobytes() == other.image.tobytes()
    assert base.rays == other.rays  # the same rays were traced, not just the same sums


AOV_NAMES = ("depth", "z", "normal", "albedo", "position", "coverage", "object_id", "material", "motion")


@pytest.mark.parametrize("options", [
    dict(workers=2),
    dict(workers=2, slices=7),
    dict(workers=1, pass_spp=1),
    dict(workers=2, pass_spp=3, slices=3),
], ids=lambda o: ",".join(f"{k}={v}" for k, v in o.items()))
def test_aovs_bit_identical_for_any_workers_slices_and_passes(renderer, options):
    """The AOVs come from the camera samples of the recursive kernel (its ray stack's first
    entry), added in sample order: the same bit for bit whatever the split, like the image."""
    base = renderer.render(spp=8, seed=3, workers=1, slices=16, pass_spp=1, progress=False, aovs=AOV_NAMES)
    other = renderer.render(spp=8, seed=3, progress=False, aovs=AOV_NAMES, **options)
    assert base.image.tobytes() == other.image.tobytes()
    for name in AOV_NAMES:
        assert base.aovs[name].tobytes() == other.aovs[name].tobytes(), name
    assert 0 < base.aovs["coverage"].mean() < 1 and len(np.unique(base.aovs["object_id"])) == 5


def test_every_row_rendered_for_any_slices():
    # fresh renderers (a reused film would hide rows a slicing leaves out: they keep the last sums);
    # slices=None: the workers claim blocks of rows (two passes: the counter starts again)
    a = warprt.Renderer(glass_scene(), device="cpu").render(spp=2, seed=5, workers=1, slices=1, progress=False)
    for options in (dict(slices=3), dict(slices=7), dict(), dict(pass_spp=1)):
        for workers in (1, 2):
            b = warprt.Renderer(glass_scene(), device="cpu").render(spp=2, seed=5, workers=workers, progress=False,
                                                                   **options)
            assert a.image.tobytes() == b.image.tobytes() and a.rays == b.rays, (options, workers)


def test_a_default_cpu_pass_claims_its_blocks():
    # without slices, each of a pass's launches (one per worker) has a thread per block of 4 rows,
    # and every thread claims one from the film's counter (the 20 rows' 5 blocks, then nothing)
    r = warprt.Renderer(glass_scene(), device="cpu")
    for workers in (1, 2, 3):
        r.render(spp=2, seed=1, workers=workers, progress=False)
        assert r._film.data.claims.numpy()[0] == workers * 5


def test_threads_of_single_pixels_take_fixed_slices(monkeypatch):
    # a thread per pixel (as tests comparing packets with lone samples render) cannot take a block
    # of rows: such passes are cut into fixed slices, and the image is the same
    import importlib

    render_module = importlib.import_module("warprt.render")  # (warprt.render is also the function)
    a = warprt.Renderer(glass_scene(), device="cpu").render(spp=2, seed=1, workers=2, progress=False)
    monkeypatch.setattr(render_module, "pixels_per_thread", lambda dev, width: 1)
    r = warprt.Renderer(glass_scene(), device="cpu")
    b = r.render(spp=2, seed=1, workers=2, progress=False)
    assert r._film.data.claims.numpy()[0] == 0
    assert a.image.tobytes() == b.image.tobytes() and a.rays == b.rays


def test_blocks_are_claimed_once_each_by_concurrent_launches():
    # film.claim_block from two threads' launches at once: every number handed out exactly once
    # (several rounds: the two launches overlap for most of a round, but not in every one)
    import threading

    import warp as wp

    from warprt.film import claim_block

    @wp.kernel(module="unique", enable_backward=False)
    def claims(counter: wp.array(dtype=int), out: wp.array(dtype=int)):
        out[wp.tid()] = claim_block(counter)

    n = 4_000_000
    counter = wp.zeros(1, dtype=int, device="cpu")
    outs = [wp.empty(n, dtype=int, device="cpu") for _ in range(2)]
    wp.launch(claims, dim=1, inputs=[counter, outs[0]], device="cpu")  # (compiled before the race)
    for _ in range(6):
        counter.zero_()
        start = threading.Barrier(2)

        def run(out):
            start.wait()
            wp.launch(claims, dim=n, inputs=[counter, out], device="cpu")

        threads = [threading.Thread(target=run, args=(o,)) for o in outs]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        assert counter.numpy()[0] == 2 * n
        seen = np.bincount(np.concatenate([o.numpy() for o in outs]), minlength=2 * n)
        assert seen.size == 2 * n and np.all(seen == 1)


def mesh_scene() -> warprt.Scene:
    """A mesh over a plane, 10 rows: two blocks of 4 rows and one of 2 (render._slices)."""
    import trimesh
    ico = trimesh.creation.icosphere(subdivisions=2, radius=0.6)
    return warprt.Scene(
        camera=warprt.Camera(eye=(0.3, 1.2, 3.0), look_at=(0.0, 0.5, 0.0), fov=40, width=14, height=10),
        shapes=(warprt.Plane(point=(0, 0, 0), normal=(0, 1, 0), material="ground"),
                warprt.Mesh(vertices=np.asarray(ico.vertices) + [0.0, 0.6, 0.0], faces=np.asarray(ico.faces),
                            material="ball")),
        materials={"ground": warprt.Material(kd=0.6), "ball": warprt.Material(kd=(0.8, 0.4, 0.3), ks=0.3)},
        lights=(warprt.PointLight(position=(2.0, 4.0, 2.0), intensity=20.0),),
        render=warprt.RenderSettings(sampler="sobol", spp=3))


def test_mesh_kernels_blocks_column_by_column_equal_row_by_row():
    # with meshes a CPU thread takes a block of 4 rows column by column (packets over several
    # pixels cover patches); one-row blocks (a slice a row) go row by row
    rows = warprt.Renderer(mesh_scene(), device="cpu")
    assert rows.features.meshes
    a = rows.render(spp=3, seed=4, workers=1, slices=10, progress=False)
    for options in (dict(workers=1, slices=1), dict(workers=2, slices=3), dict(workers=1), dict(workers=2),
                    dict(workers=2, pass_spp=1)):
        b = warprt.Renderer(mesh_scene(), device="cpu").render(spp=3, seed=4, progress=False, **options)
        assert a.image.tobytes() == b.image.tobytes() and a.rays == b.rays
        assert np.all(np.isfinite(b.image)) and b.image.max() > 0.0


def test_mesh_kernels_aovs_column_by_column_equal_row_by_row():
    # the AOVs of a block of 4 rows taken column by column (render_pixels' patches of pixels in a
    # packet) are those of one-row blocks, bit for bit
    names = ("depth", "normal", "coverage", "object_id")
    a = warprt.Renderer(mesh_scene(), device="cpu").render(spp=3, seed=4, workers=1, slices=10, progress=False,
                                                           aovs=names)
    for options in (dict(workers=1), dict(workers=2, pass_spp=1)):
        b = warprt.Renderer(mesh_scene(), device="cpu").render(spp=3, seed=4, progress=False, aovs=names, **options)
        for name in names:
            assert a.aovs[name].tobytes() == b.aovs[name].tobytes(), (name, options)
    assert set(np.unique(a.aovs["object_id"])) == {-1, 0, 1}


def test_slices_cover_every_row_once():
    # each slice's k-th row as the render kernels place it: blocks of consecutive rows
    from warprt.render import _slices
    for height in range(1, 70):
        for count in range(1, 13):
            rows = []
            for row0, stride, block, pixels in _slices(3, height, count):
                assert pixels % 3 == 0 and 1 <= block
                rows += [row0 + (k // block) * stride + k % block for k in range(pixels // 3)]
            assert sorted(rows) == list(range(height)), (height, count)


def test_same_seed_twice_is_identical_across_renderers(device):
    a = warprt.Renderer(glass_scene(), device=device).render(spp=8, seed=11, progress=False).image
    b = warprt.Renderer(glass_scene(), device=device).render(spp=8, seed=11, progress=False).image
    assert a.tobytes() == b.tobytes()


@pytest.mark.parametrize("sampler", ["stratified", "independent", "sobol"])
def test_different_seeds_give_different_noise(device, sampler):
    r = warprt.Renderer(glass_scene(sampler), device=device)
    a = r.render(spp=8, seed=0, progress=False).image
    b = r.render(spp=8, seed=1, progress=False).image
    c = r.render(spp=8, seed=0, progress=False).image
    assert a.tobytes() == c.tobytes()
    differ = np.any(a != b, axis=2)
    assert differ.mean() > 0.05, f"only {differ.mean():.1%} of the pixels changed with the seed"
    # ... but only by noise: the two estimates of the same image agree on average
    assert abs(float(a.mean()) - float(b.mean())) < 0.02 * float(a.mean())


def test_regular_sampler_ignores_the_seed(device):
    """The regular sampler has no randomness in this scene (no area lights, no glossy lobes)."""
    r = warprt.Renderer(glass_scene("regular"), device=device)
    a = r.render(spp=4, seed=0, progress=False).image
    b = r.render(spp=4, seed=12345, progress=False).image
    assert a.tobytes() == b.tobytes()


# --- the ray stack ----------------------------------------------------------------------------


def hall_of_mirrors(max_depth: int) -> warprt.Scene:
    """The camera at the centre of three concentric glass spheres (km = 0.99, kt = 0.005, no
    Fresnel). Every camera ray meets the inner sphere at normal incidence and is reflected back
    through the centre again and again, each hit also pushing a faint refracted ray: the main
    path's pending refractions fill the stack, while each of them, when popped, continues as a
    single chain (its own refraction, 2.5e-5, falls below min_weight 1e-4). Only ambient light
    (ka Ia at every hit) reaches the camera.

    So the stack needs depth + 1 entries at depth ``max_depth``: at most 16 (the stack size) for
    max_depth <= 15, and exactly one push per camera ray is dropped for max_depth = 16."""
    glass = warprt.Material(kd=0.0, ka=0.1, mirror=0.99, transparency=0.005, ior=1.5)
    return warprt.Scene(
        camera=warprt.Camera(eye=(0, 0, 0), look_at=(0, 0, -1), fov=60, width=8, height=6),
        shapes=tuple(warprt.Sphere(center=(0, 0, 0), radius=r, material="glass") for r in (1.0, 2.0, 3.0)),
        materials={"glass": glass}, ambient=0.5, background=1.0,  # every hit adds ka Ia times its weight
        render=warprt.RenderSettings(sampler="regular", max_depth=max_depth, min_weight=1e-4))


def hall_radiance(max_depth: int) -> float:
    """ka Ia times the summed weight of every hit in the tree above: the main chain (0.99^k at
    depth k = 0..D) and, from each of its nodes but the last, a refracted chain starting with
    weight 0.005 0.99^k and losing a factor 0.99 per bounce down to depth D."""
    main = sum(0.99 ** k for k in range(max_depth + 1))
    side = sum(0.005 * 0.99 ** k * sum(0.99 ** m for m in range(max_depth - k)) for k in range(max_depth))
    return 0.1 * 0.5 * (main + side)


@pytest.mark.parametrize("max_depth", [1, 10, 15])
def test_no_stack_overflow_up_to_depth_15(device, max_depth):
    res = warprt.Renderer(hall_of_mirrors(max_depth), device=device).render(spp=2, progress=False)
    assert res.stack_overflows == 0
    assert np.isfinite(res.image).all()
    # every ray of the tree was traced: the closed-form sum over the tree
    np.testing.assert_allclose(res.image, hall_radiance(max_depth), rtol=1e-5)


def test_stack_overflow_at_depth_16_drops_exactly_one_ray_per_camera_ray(device):
    res = warprt.Renderer(hall_of_mirrors(16), device=device).render(spp=2, progress=False)
    assert res.stack_overflows == 8 * 6 * 2
    assert np.isfinite(res.image).all()
    # the dropped ray is the main chain's last reflection (weight 0.99^16, a leaf at depth 16)
    np.testing.assert_allclose(res.image, hall_radiance(16) - 0.05 * 0.99 ** 16, rtol=1e-5)


def test_deep_recursion_overflows_are_counted_and_pixels_stay_finite(device):
    shallow = warprt.Renderer(hall_of_mirrors(15), device=device).render(spp=1, progress=False)
    deep = warprt.Renderer(hall_of_mirrors(40), device=device).render(spp=1, progress=False)
    assert deep.stack_overflows > 0
    assert np.isfinite(deep.image).all() and (deep.image >= 0).all()
    assert deep.rays > shallow.rays
    # more bounces add light, but less than the whole tree would (some rays were dropped)
    assert np.all(deep.image > shallow.image)
    assert np.all(deep.image < hall_radiance(40) * (1 - 1e-4))


def test_a_renderer_reusing_its_film_gives_what_a_new_renderer_gives(device):
    """The renderer keeps its film between renders without clearing it (the first pass starts
    every pixel's sums), and its recorded launches while scene, camera and film stay the same:
    whatever came before on the same renderer (an adaptive render with its per-pixel caps, more
    samples, another resolution, another camera or scene, a render in another thread holding the
    film), each render equals a new renderer's, image and ray count, bit for bit."""
    import dataclasses
    import threading

    scene = glass_scene("sobol")
    small = dataclasses.replace(scene.camera, width=16, height=12)

    def fresh(camera=None, **options):
        s = scene if camera is None else scene.replace(camera=camera)
        return warprt.Renderer(s, device=device).render(progress=False, **options)

    r = warprt.Renderer(scene, device=device)
    steps = [dict(spp=8, seed=1, adaptive=True), dict(spp=4, seed=2), dict(spp=2, seed=2, adaptive=True),
             dict(spp=3, seed=5)]
    for options in steps:
        got, want = r.render(progress=False, **options), fresh(**options)
        assert got.image.tobytes() == want.image.tobytes(), options
        assert got.rays == want.rays and got.spp == want.spp, options
    r.set_camera(small)
    got, want = r.render(spp=4, seed=7, progress=False), fresh(small, spp=4, seed=7)
    assert got.image.shape == (12, 16, 3) and got.image.tobytes() == want.image.tobytes()
    r.set_camera(scene.camera)
    got, want = r.render(spp=4, seed=7, progress=False), fresh(spp=4, seed=7)
    assert got.image.tobytes() == want.image.tobytes()
    # the kept launches (of that render) follow a new camera of the same size and a changed scene
    moved = dataclasses.replace(scene.camera, eye=(0.3, 1.4, 3.8))
    r.set_camera(moved)
    got, want = r.render(spp=4, seed=7, progress=False), fresh(moved, spp=4, seed=7)
    assert got.image.tobytes() == want.image.tobytes()
    r.set_camera(scene.camera)
    brighter = scene.replace(ambient=0.2)
    r.update(brighter)
    got = r.render(spp=4, seed=7, progress=False)
    want = warprt.Renderer(brighter, device=device).render(spp=4, seed=7, progress=False)
    assert got.image.tobytes() == want.image.tobytes()
    r.update(scene)

    # two threads rendering with one renderer at once: one of them takes a film of its own
    results = {}
    gate = threading.Barrier(2)

    def run(seed):
        gate.wait()
        results[seed] = r.render(spp=6, seed=seed, workers=1, progress=False)

    threads = [threading.Thread(target=run, args=(seed,)) for seed in (11, 12)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    for seed in (11, 12):
        want = fresh(spp=6, seed=seed)
        assert results[seed].image.tobytes() == want.image.tobytes() and results[seed].rays == want.rays
