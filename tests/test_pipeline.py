"""warprt inside simulation pipelines: AOVs, animation without recompiles, device images, batch
executors (Ray included), CUDA parity, the image-check helpers and interrupted renders."""

from __future__ import annotations

import _thread
import dataclasses
import importlib.metadata
import math
import os
import pathlib
import signal
import subprocess
import sys
import threading
import time

import numpy as np
import pytest
from PIL import Image
import warp as wp

import warprt
from warprt import integrator
from warprt.animation import frame_scene, render_sequence
from warprt.batch import ray_available, render_frames
from warprt.testing import ImageMismatch, assert_images_close, relative_mse

ROOT = pathlib.Path(__file__).resolve().parents[1]

pytest_plugins = ["pytester"]


def _scene(**kw) -> warprt.Scene:
    base = dict(camera=warprt.Camera(eye=(0, 0, 5), look_at=(0, 0, 0), fov=30, width=24, height=18),
                shapes=(warprt.Sphere(center=(0, 0, 0), radius=1.0, material="red"),
                        warprt.Plane(point=(0, -1, 0), material="floor")),
                materials={"red": warprt.Material(kd=(0.9, 0.1, 0.1)), "floor": warprt.Material(kd=0.5)},
                lights=(warprt.PointLight(position=(2, 4, 3), intensity=0.8),
                        warprt.RectLight(corner=(-0.5, 3, -0.5), edge1=(1, 0, 0), edge2=(0, 0, 1), radiance=2.0)),
                ambient=0.05)
    base.update(kw)
    return warprt.Scene(**base)


# --- AOVs ----------------------------------------------------------------------------------------


def test_aovs_match_closed_forms():
    scene = _scene(render=warprt.RenderSettings(sampler="regular"))  # 1 regular sample: the pixel centre
    result = warprt.Renderer(scene).render(spp=1, progress=False,
                                           aovs=["depth", "z", "normal", "albedo", "position", "object_id",
                                                 "material", "motion"])
    a = result.aovs
    o, d = warprt.camera_rays(scene)  # pixel centres, row-major
    o, d = o.reshape(18, 24, 3).astype(np.float64), d.reshape(18, 24, 3).astype(np.float64)
    # ray-sphere closed form (unit sphere at the origin)
    b = np.sum(o * d, axis=-1)
    disc = b * b - (np.sum(o * o, axis=-1) - 1.0)
    on_sphere = disc > 1e-6
    t_sphere = -b - np.sqrt(np.maximum(disc, 0))
    assert on_sphere.sum() > 50
    np.testing.assert_allclose(a["depth"][on_sphere], t_sphere[on_sphere], rtol=1e-5)
    p = o + t_sphere[..., None] * d
    np.testing.assert_allclose(a["position"][on_sphere], p[on_sphere], atol=1e-5)
    np.testing.assert_allclose(a["normal"][on_sphere], p[on_sphere], atol=1e-5)  # unit sphere: n = p
    np.testing.assert_allclose(a["z"][on_sphere], (t_sphere * -d[..., 2])[on_sphere], rtol=1e-5)
    np.testing.assert_array_equal(a["albedo"][on_sphere], np.broadcast_to(np.float32([0.9, 0.1, 0.1]),
                                                                          (int(on_sphere.sum()), 3)))
    assert (a["object_id"][on_sphere] == 0).all() and (a["material"][on_sphere] == 0).all()
    floor = ~on_sphere & (d[..., 1] < 0)
    assert (a["object_id"][floor] == 1).all() and (a["material"][floor] == 1).all()
    sky = ~on_sphere & (d[..., 1] > 1e-3)
    assert np.isinf(a["depth"][sky]).all() and (a["object_id"][sky] == -1).all()
    assert (a["motion"] == 0).all()  # nothing moves
    # integer ids, never blended
    assert a["object_id"].dtype == np.int32 and set(np.unique(a["object_id"])) <= {-1, 0, 1}


def test_area_light_ids_and_motion_vectors():
    scene = _scene(shapes=(warprt.Sphere(center=(0, 0, 0), center_end=(0.5, 0.2, 0), radius=1.0, material="red"),),
                   camera=warprt.Camera(eye=(0, 0, 5), look_at=(0, 0, 0), fov=60, width=24, height=18),
                   render=warprt.RenderSettings(sampler="regular"))  # the pixel centre, mid-shutter
    full = warprt.Features.full()  # the kernel most tests compile (the AOVs do not depend on it)
    a = warprt.Renderer(scene, features=full).render(spp=1, progress=False,
                                                     aovs=["object_id", "motion", "position"]).aovs
    # the rectangle light sits above; its id is len(shapes) + its index among the lights
    look_up = _scene(shapes=(warprt.Plane(point=(0, -1, 0), material="floor"),),
                     camera=warprt.Camera(eye=(0, 0, 2), look_at=(0, 3, 0), width=16, height=12))
    ids = warprt.Renderer(look_up, features=full).render(spp=1, progress=False, aovs=["object_id"]).aovs["object_id"]
    assert set(np.unique(ids)) == {-1, 1 + 1}  # sky and the light (lights[1] after one shape)
    # motion of a sphere point over the whole shutter: the displacement (0.5, 0.2, 0) projected by
    # the pinhole camera; the position is the point seen at the sample's time, mid-shutter
    sel = a["object_id"] == 0
    p0 = a["position"][sel].astype(np.float64) - 0.5 * np.array([0.5, 0.2, 0.0])
    p1 = p0 + np.array([0.5, 0.2, 0.0])
    top = math.tan(math.radians(30))
    right = top * 24 / 18

    def raster(p):
        zc = 5.0 - p[:, 2]
        return np.stack([(p[:, 0] / zc + right) / (2 * right) * 24, (top - p[:, 1] / zc) / (2 * top) * 18], 1)

    np.testing.assert_allclose(a["motion"][sel], raster(p1) - raster(p0), atol=1e-3)


def test_aovs_go_to_named_exr_layers(tmp_path):
    out = warprt.render(_scene(), spp=1, aovs=["depth", "normal", "object_id"])
    assert set(out) == {"color", "depth", "normal", "object_id"}
    path = tmp_path / "frame.exr"
    warprt.save_image(out, path)
    rgb, header, layers = warprt.read_exr(path, layers=True)
    np.testing.assert_array_equal(rgb, out["color"])
    np.testing.assert_array_equal(layers["depth"], out["depth"])
    np.testing.assert_array_equal(layers["normal"], out["normal"])
    np.testing.assert_array_equal(layers["object_id"].astype(np.int32), out["object_id"])
    with pytest.raises(warprt.RenderError, match="unknown AOV"):
        warprt.render(_scene(), spp=1, aovs=["depht"])


# --- animation without recompiling ---------------------------------------------------------------


@pytest.mark.parametrize("frames, words", [([4], "frame 4 is outside"), ([-1], "frame -1 is outside"),
                                           ([0.5], "integers"), ([], "no frames")])
def test_frames_outside_the_animation_are_refused_before_rendering(frames, words):
    scene = warprt.Scene(camera=warprt.Camera(width=4, height=3), animation=warprt.Animation(frames=4))
    for call in (lambda: render_sequence(scene, frames=frames, progress=False),
                 lambda: render_frames(scene, frames=frames, executor="thread")):
        with pytest.raises(warprt.RenderError, match=words):
            call()


def _animated() -> warprt.Scene:
    v = np.array([[-1, 0, -1], [1, 0, -1], [0, 1.5, -1.5], [0, 0.5, -0.5]], float)
    f = np.array([[0, 1, 2], [0, 2, 3], [1, 3, 2], [0, 3, 1]])
    return _scene(shapes=(warprt.Sphere(radius=0.5, material="red",
                                        keyframes=[{"time": 0, "center": [0, 0, 0]}, {"time": 1, "center": [1, 0, 0]}]),
                          warprt.Mesh(vertices=v, faces=f, material="floor",
                                      keyframes=[{"time": 0, "rotate": [0, 0, 0]}, {"time": 1, "rotate": [0, 90, 0]}]),
                          warprt.Plane(point=(0, -1, 0), material="floor")),
                  animation=warprt.Animation(frames=4, fps=4))


def test_keyframes_interpolate_linearly():
    scene = _animated()
    f2 = frame_scene(scene, 2)  # t = 0.5 s, end pose at 0.75 s
    assert f2.shapes[0].center == pytest.approx((0.5, 0, 0)) and f2.shapes[0].center_end == pytest.approx((0.75, 0, 0))
    # rotations are slerped (a quaternion); about one axis that is the Euler angle in proportion to time
    rot = warprt.Transform(rotate=(0, 45, 0)).rotation_matrix()
    np.testing.assert_allclose(f2.shapes[1].transform.rotation_matrix(), rot, atol=1e-12)
    rot_end = warprt.Transform(rotate=(0, 67.5, 0)).rotation_matrix()
    np.testing.assert_allclose(f2.shapes[1].transform_end.rotation_matrix(), rot_end, atol=1e-12)
    assert frame_scene(scene, 10).shapes[0].center == pytest.approx((1, 0, 0))  # clamped after the last key


def test_sequence_reuses_kernel_and_bvh_and_matches_fresh_renders():
    scene = _animated()
    renderer = warprt.Renderer(frame_scene(scene, 0))
    kernel, mesh = renderer.kernel, renderer.built.meshes[0]
    variants = len(integrator.kernels_for.built())
    images = []
    for f in range(scene.animation.frames):
        renderer.update(frame_scene(scene, f))
        images.append(renderer.render(spp=2, seed=f, progress=False).image)
        assert renderer.kernel is kernel and renderer.built.meshes[0] is mesh  # no recompile, no BVH rebuild
    assert len(integrator.kernels_for.built()) == variants
    for f in (1, 3):
        fresh = warprt.Renderer(frame_scene(scene, f)).render(spp=2, seed=f, progress=False).image
        assert fresh.tobytes() == images[f].tobytes()
    assert np.abs(images[0] - images[3]).max() > 0.1  # things moved
    seq = render_sequence(scene, spp=2, seed=0, progress=False)
    assert all(a.tobytes() == b.tobytes() for a, b in zip(seq, images))


def _grid_mesh(n: int):
    """An n × n grid of quads in z = 0 over [-1, 1]², two triangles each, bumped in z."""
    x, y = np.meshgrid(np.linspace(-1, 1, n + 1), np.linspace(-1, 1, n + 1))
    v = np.stack([x.ravel(), y.ravel(), 0.1 * np.sin(3 * x.ravel()) * np.cos(2 * y.ravel())], 1)
    k = np.arange(n * (n + 1)).reshape(n, n + 1)[:, :n].ravel()
    f = np.concatenate([np.stack([k, k + 1, k + n + 2], 1), np.stack([k, k + n + 2, k + n + 1], 1)])
    return v, f


@pytest.mark.parametrize("n_faces", [1, 128])
def test_mesh_points_from_numpy_or_warp_refit_without_rebuild(n_faces):
    # one triangle: Warp's query (a tree of one leaf); 128: the CPU's copy of the tree, rewritten
    # after the refit (accel.MeshTree)
    if n_faces == 1:
        v, f = np.array([[-1, -1, 0], [1, -1, 0], [0, 1, 0]], float), np.array([[0, 1, 2]])
    else:
        v, f = _grid_mesh(8)
    scene = _scene(shapes=(warprt.Mesh(vertices=v, faces=f, material="red"),), lights=(warprt.PointLight(),))
    renderer = warprt.Renderer(scene)
    mesh = renderer.built.meshes[0]
    moved = v + [0.3, 0.2, 0.0]
    renderer.set_mesh_points(0, moved)
    a = renderer.render(spp=1, progress=False).image
    expected = warprt.Renderer(scene.replace(shapes=(warprt.Mesh(vertices=moved, faces=f, material="red"),)))
    assert a.tobytes() == expected.render(spp=1, progress=False).image.tobytes()
    # points straight from a Warp simulation (a wp.array on the scene's device)
    renderer.set_mesh_points(0, wp.array(v.astype(np.float32), dtype=wp.vec3, device=renderer.device))
    b = renderer.render(spp=1, progress=False).image
    assert b.tobytes() == warprt.Renderer(scene).render(spp=1, progress=False).image.tobytes()
    assert renderer.built.meshes[0] is mesh
    with pytest.raises(warprt.RenderError, match="shape"):
        renderer.set_mesh_points(0, v[:2])
    with pytest.raises(warprt.RenderError, match="finite"):
        renderer.set_mesh_points(0, np.full_like(v, np.nan))
    # a simulation's array is checked on the device: the first bad vertex named
    bad = v.astype(np.float32)
    bad[-1, 1] = np.inf
    with pytest.raises(warprt.RenderError, match=rf"^points\[{len(v) - 1}\]: position \(.*inf.*\) is not finite"):
        renderer.set_mesh_points(0, wp.array(bad, dtype=wp.vec3, device=renderer.device))
    for points, words in (("abc", "points must be"), (None, "points must be"), ([["a", "b", "c"]], "numbers")):
        with pytest.raises(warprt.RenderError, match=words):
            renderer.set_mesh_points(0, points)
    for index in ("abc", 1, -1, 0.0, True):
        with pytest.raises(warprt.RenderError, match=r"shape_index must be an index into scene.shapes \(0 to 0\)"):
            renderer.set_mesh_points(index, v)


def test_camera_and_lights_change_between_frames():
    scene = _scene()
    renderer = warprt.Renderer(scene)
    a = renderer.render(spp=1, progress=False).image
    renderer.set_camera(warprt.Camera(eye=(0, 1, 5), look_at=(0, 0, 0), fov=30, width=24, height=18))
    b = renderer.render(spp=1, progress=False).image
    assert np.abs(a - b).max() > 0.05
    brighter = scene.replace(lights=(warprt.PointLight(position=(2, 4, 3), intensity=1.6),) + scene.lights[1:])
    renderer.update(brighter)
    c = renderer.render(spp=1, progress=False).image
    assert c.tobytes() == warprt.Renderer(brighter).render(spp=1, progress=False).image.tobytes()


def test_render_sequence_cli_writes_numbered_frames(tmp_path):
    from warprt.cli import main

    scene_file = tmp_path / "anim.toml"
    scene_file.write_text("""
[camera]
width = 16
height = 12
[animation]
frames = 3
fps = 3
[[shapes]]
type = "sphere"
keyframes = [{time = 0, center = [-1, 0, 0]}, {time = 1, center = [1, 0, 0]}]
[[lights]]
type = "point"
""")
    assert main(["render-sequence", str(scene_file), "-o", str(tmp_path / "f_###.png"), "--spp", "1",
                 "--no-progress"]) == 0
    assert sorted(p.name for p in tmp_path.glob("f_*.png")) == ["f_000.png", "f_001.png", "f_002.png"]
    assert main(["render-sequence", str(scene_file), "-o", str(tmp_path / "g.exr"), "--frames", "1:3",
                 "--no-progress"]) == 0
    assert sorted(p.name for p in tmp_path.glob("g_*.exr")) == ["g_0001.exr", "g_0002.exr"]


# --- device images and interop -------------------------------------------------------------------


def test_as_warp_keeps_the_image_on_the_device():
    r = warprt.Renderer(_scene())
    dev = r.render(spp=2, as_warp=True, progress=False).image
    assert isinstance(dev, wp.array) and dev.shape == (18, 24, 3) and dev.device == r.device
    assert dev.numpy().tobytes() == r.render(spp=2, progress=False).image.tobytes()


def test_dlpack_to_torch():
    torch = pytest.importorskip("torch")
    img = warprt.Renderer(_scene()).render(spp=1, as_warp=True, progress=False).image
    t = torch.utils.dlpack.from_dlpack(img)
    assert tuple(t.shape) == (18, 24, 3)
    np.testing.assert_array_equal(t.cpu().numpy(), img.numpy())


def test_dlpack_to_jax():
    jax = pytest.importorskip("jax")
    img = warprt.Renderer(_scene()).render(spp=1, as_warp=True, progress=False).image
    j = jax.dlpack.from_dlpack(img)
    np.testing.assert_array_equal(np.asarray(j), img.numpy())


def test_cpu_and_cuda_images_agree(cuda_device):
    scene = _scene()
    cpu = warprt.Renderer(scene, device="cpu").render(spp=4, progress=False).image
    gpu = warprt.Renderer(scene, device=cuda_device).render(spp=4, progress=False).image
    assert relative_mse(gpu, cpu) < 1e-6


# --- batches ---------------------------------------------------------------------------------------


@pytest.mark.parametrize("executor", ["thread", "process"])
def test_local_executors_match_sequential_frames(executor):
    scene = _animated()
    local = render_frames(scene, spp=2, executor="local")
    other = render_frames(scene, spp=2, executor=executor, max_workers=2, render_workers=1)
    assert len(other) == scene.animation.frames
    assert all(a.tobytes() == b.tobytes() for a, b in zip(local, other))


@pytest.mark.skipif(not ray_available(), reason="Ray is not installed (pip install 'warprt[ray]')")
def test_ray_executor_matches_local_frames():
    import ray

    scene = _animated()
    local = render_frames(scene, frames=[0, 2, 3], spp=2, executor="local")
    started = not ray.is_initialized()
    if started:
        ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    try:
        remote = render_frames(scene, frames=[0, 2, 3], spp=2, executor="ray", render_workers=1)
    finally:
        if started:
            ray.shutdown()
    assert all(a.tobytes() == b.tobytes() for a, b in zip(local, remote))


def test_bad_executor_is_a_clear_error():
    with pytest.raises(warprt.RenderError, match="executor"):
        render_frames(_animated(), executor="slurm")


# --- image checks for users' tests ------------------------------------------------------------------


def test_assert_images_close_passes_and_fails_with_a_difference_image(tmp_path, monkeypatch):
    monkeypatch.setenv("WARPRT_DIFF_DIR", str(tmp_path))
    img = warprt.render(_scene(), spp=1)
    assert_images_close(img, img.copy())
    assert_images_close(img * 1.001, img, rel_mse=1e-5)
    bad = img.copy()
    bad[3, 4] += 0.5
    with pytest.raises(ImageMismatch) as info:
        assert_images_close(bad, img, atol=1e-3, name="sphere")
    message = str(info.value)
    assert "(3, 4" in message and "1 of" in message or "values" in message
    assert info.value.diff_path and os.path.exists(info.value.diff_path)
    assert os.path.exists(tmp_path / "sphere-diff.exr")
    with pytest.raises(ImageMismatch, match="relative MSE"):
        assert_images_close(img * 1.5, img, rel_mse=1e-3)
    with pytest.raises(ImageMismatch, match="shape"):
        assert_images_close(img[:4], img)
    nan = img.copy()
    nan[0, 0, 0] = np.nan
    with pytest.raises(ImageMismatch, match="NaN"):
        assert_images_close(nan, img, rel_mse=1.0)


def _plugin_registered() -> bool:
    return any(ep.value == "warprt.testing" for ep in importlib.metadata.entry_points(group="pytest11"))


def test_the_installed_package_registers_its_pytest_plugin():
    """``pip install`` registers ``warprt.testing`` with pytest (the ``pytest11`` entry point in
    pyproject.toml), so the ``warprt_reference`` fixture needs no ``-p`` or conftest."""
    try:
        importlib.metadata.distribution("warprt")
    except importlib.metadata.PackageNotFoundError:
        pytest.skip("warprt is importable but not installed (e.g. through PYTHONPATH): no entry points")
    assert _plugin_registered()


def test_reference_fixture_writes_then_compares(pytester):
    # installed, the plugin comes from its entry point (the test above); from a source tree on
    # PYTHONPATH it is named here, as a user would with -p warprt.testing
    plugin = () if _plugin_registered() else ("-p", "warprt.testing")
    pytester.makepyfile(test_user="""
        import numpy as np
        def test_image(warprt_reference):
            warprt_reference(np.full((4, 4, 3), 0.25, np.float32))
    """)
    first = pytester.runpytest("-q", *plugin)
    first.assert_outcomes(failed=1)
    assert (pytester.path / "references" / "test_image.exr").exists()
    pytester.runpytest("-q", *plugin).assert_outcomes(passed=1)
    pytester.makepyfile(test_user="""
        import numpy as np
        def test_image(warprt_reference):
            warprt_reference(np.full((4, 4, 3), 0.5, np.float32))
    """)
    pytester.runpytest("-q", *plugin).assert_outcomes(failed=1)


# --- interruption ---------------------------------------------------------------------------------


def test_ctrl_c_returns_the_samples_accumulated_so_far():
    scene = _scene().with_camera(width=64, height=48)
    renderer = warprt.Renderer(scene)
    renderer.compile()
    done = threading.Event()

    def press_ctrl_c():
        # once render() has installed its handler (however long its set-up takes on a loaded
        # machine) and a few passes have run, press Ctrl-C, again until render() returns
        while not done.is_set() and signal.getsignal(signal.SIGINT) is signal.default_int_handler:
            time.sleep(0.01)
        while not done.wait(0.4):
            if signal.getsignal(signal.SIGINT) is not signal.default_int_handler:  # still rendering
                _thread.interrupt_main()

    presser = threading.Thread(target=press_ctrl_c, daemon=True)
    presser.start()
    try:
        result = renderer.render(spp=1_000_000, pass_spp=2, progress=False)
    finally:
        done.set()
        presser.join()
    assert result.interrupted and 1 <= result.spp < 1_000_000 and result.spp % 2 == 1  # 1 + whole passes of 2
    assert np.isfinite(result.image).all()
    full = renderer.render(spp=64, progress=False).image
    assert abs(float(result.image.mean() / full.mean()) - 1.0) < 0.05


@pytest.mark.skipif(sys.platform == "win32", reason="POSIX signals")
@pytest.mark.parametrize("during", ["passes", "light pilot"])
def test_ctrl_c_between_passes_is_not_lost_and_the_handler_is_restored(monkeypatch, during):
    """A SIGINT arriving outside a pass (here: while the device synchronises after one) only sets
    a flag read by the pass loop; it must not escape render() as a KeyboardInterrupt that throws
    the samples away. The handler is installed for the render only. The first render of a scene
    with an area light of ``samples = "auto"`` runs the light pilot first: a SIGINT there is held
    the same way (the render runs its first pass and returns it)."""
    scene = _scene().with_camera(width=16, height=12)
    scene = scene.replace(lights=(scene.lights[0], dataclasses.replace(scene.lights[1], samples="auto")))
    renderer = warprt.Renderer(scene)
    renderer.compile()
    if during == "passes":
        renderer.light_samples()  # (chosen once: the render's synchronisations are its passes')
    real_sync = wp.synchronize_device
    calls = []

    def slow_sync(*a, **k):
        real_sync(*a, **k)
        calls.append(1)
        if len(calls) == 3:  # after a pass, outside it
            os.kill(os.getpid(), signal.SIGINT)
            time.sleep(0.2)  # the signal is handled here, in the main thread

    monkeypatch.setattr(wp, "synchronize_device", slow_sync)
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
    try:
        result = renderer.render(spp=1_000_000, pass_spp=1, progress=False)
    except KeyboardInterrupt:
        pytest.fail("a Ctrl-C between passes escaped render() and lost the samples")
    assert result.interrupted and 1 <= result.spp <= 3 and np.isfinite(result.image).all()
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler


def test_a_render_outside_the_main_thread_leaves_signals_alone():
    scene = _scene().with_camera(width=8, height=6)
    seen = []

    def work():
        seen.append(warprt.Renderer(scene).render(spp=2, progress=False).spp)

    t = threading.Thread(target=work)
    t.start()
    t.join(120)
    assert seen == [2] and signal.getsignal(signal.SIGINT) is signal.default_int_handler


_REPEATED_CTRL_C = """
import sys, time
import numpy as np
import warprt
scene = warprt.scene_from_string('[camera]\\nwidth = 32\\nheight = 24\\n[[shapes]]\\ntype = "sphere"\\n'
                                 '[[lights]]\\ntype = "point"\\n')
renderer = warprt.Renderer(scene)
renderer.compile()
for i in range(int(sys.argv[1])):
    print("go", flush=True)
    start = time.perf_counter()
    try:
        r = renderer.render(spp=1 << 20, pass_spp=1 + i % 3, progress=False, workers=2)  # the spp limit
    except KeyboardInterrupt:
        print("escaped", flush=True)
        sys.exit(3)
    ok = r.interrupted and r.spp >= 1 and np.isfinite(r.image).all() and r.image.mean() > 0
    print("done", int(ok), r.spp, f"{time.perf_counter() - start:.2f}", flush=True)
"""


@pytest.mark.skipif(sys.platform == "win32", reason="POSIX signals")
def test_real_sigint_repeatedly_stops_a_render_promptly_with_its_samples():
    """A real SIGINT at a different moment of ten renders (one process, its persistent worker
    pool reused): each render stops within a pass and returns its partial image; none lets a
    KeyboardInterrupt escape."""
    import random

    runs = 10
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT), *filter(None, [env.get("PYTHONPATH")])])
    proc = subprocess.Popen([sys.executable, "-c", _REPEATED_CTRL_C, str(runs)], env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    rng = random.Random(7)
    try:
        for i in range(runs):
            assert proc.stdout.readline().strip() == "go", proc.stderr.read() if proc.poll() is not None else ""
            time.sleep(rng.uniform(0.05, 0.5))
            sent = time.perf_counter()
            proc.send_signal(signal.SIGINT)
            line = proc.stdout.readline().split()
            assert line[:2] == ["done", "1"], (i, line, proc.stderr.read() if proc.poll() is not None else "")
            assert time.perf_counter() - sent < 5.0, (i, line)  # within a pass (passes take ~0.5 s)
        assert proc.wait(timeout=60) == 0
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


@pytest.mark.skipif(sys.platform == "win32", reason="POSIX signals")
def test_cli_interrupted_writes_the_partial_image_with_its_spp(tmp_path):
    scene = tmp_path / "s.toml"
    scene.write_text('[camera]\nwidth = 64\nheight = 48\n[[shapes]]\ntype = "sphere"\n[[lights]]\ntype = "point"\n')
    out = tmp_path / "partial.exr"
    png = tmp_path / "partial.png"
    png.write_bytes(b"the previous complete image")
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT), *filter(None, [env.get("PYTHONPATH")])])
    proc = subprocess.Popen([sys.executable, "-m", "warprt", "render", str(scene), "-o", str(out), "-o", str(png),
                             "--spp", "1048576"], env=env,  # the spp limit, 2^20; with a progress bar
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    # the progress bar shows half a second into the render, whatever the import and load took
    from test_faults import progress_reader, wait_for

    seen = progress_reader(proc)
    wait_for(proc, lambda: "spp" in "".join(seen), "the progress bar")
    sent = time.monotonic()
    proc.send_signal(signal.SIGINT)
    stdout, stderr = proc.communicate(timeout=120)
    assert time.monotonic() - sent < 5.0  # within a pass (about half a second) and the writes
    assert proc.returncode == 130, stderr
    _, header = warprt.read_exr(out)
    assert 1 <= int(header["warprt_spp"]) < 1048576 and int(header["warprt_interrupted"]) == 1
    assert "interrupted" in stdout
    # the partial image is marked as such: in the output line, the EXR header and a PNG text chunk
    assert "partial image" in stdout.strip().splitlines()[-1]
    assert header["warprt:partial"] == "true"
    text = Image.open(png).text
    assert text["warprt:partial"] == "true" and text["warprt_spp"] == str(header["warprt_spp"])
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]  # no temporary file left
