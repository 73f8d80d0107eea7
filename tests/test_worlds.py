"""Batched rendering (warprt.worlds.BatchRenderer): each world and camera of a batch against a
single render of the same scene posed on the host, determinism, independence of worlds, motion
blur from pose arrays, and an update loop that copies nothing to or from the host, rebuilds
nothing and compiles nothing (counted at Warp's own entry points).

Images are rendered with the "regular" sampler at one sample per pixel (the pixel-centre ray,
whatever the pixel's noise key), so a batch image and the single render must agree to float32
rounding: the poses are applied in float32 on the device and in float64 on the host, and the
camera frame comes from a quaternion rather than from eye/look-at. The tolerance below is the
measured worst case on lit pixels away from silhouettes and shadow edges (a few 1e-6) times ~10;
pixels where a float32 rounding flips which surface is seen are counted, and few are allowed.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import warp as wp

import warprt
from warprt.checks import BATCH_SLOTS
from warprt.errors import RenderError
from warprt.worlds import BatchRenderer

REGULAR = warprt.RenderSettings(sampler="regular", spp=1, adaptive=False)  # uniform, as a batch renders
MESH_TRANSFORM = warprt.Transform(translate=(0.1, 0.0, -0.1), rotate=(20, 35, -10), scale=(1.0, 1.4, 0.7))
W, C, H, X = 3, 2, 24, 32


def quat(axis, angle):
    axis = np.asarray(axis, np.float64) / np.linalg.norm(axis)
    return np.concatenate([axis * math.sin(angle / 2), [math.cos(angle / 2)]])


def rot(q):
    x, y, z, w = q
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def box(half=0.35):
    v = np.array([[x, y, z] for x in (-half, half) for y in (-half, half) for z in (-half, half)], np.float64)
    f = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1], [2, 3, 7], [2, 7, 6],
                  [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]])
    return v, f


def base_scene(mesh_vertices=None, camera=None, lights=None):
    v, f = box()
    transform = MESH_TRANSFORM  # the batch composes the pose with the mesh's own transform
    if mesh_vertices is not None:
        v, transform = mesh_vertices, None
    return warprt.Scene(
        camera=camera or warprt.Camera(eye=(0, 2.0, 5.0), look_at=(0, 0.5, 0), fov=45, width=X, height=H),
        shapes=(warprt.Plane(point=(0, 0, 0), normal=(0, 1, 0), material="floor"),
                warprt.Sphere(center=(0.0, 0.0, 0.0), radius=0.45, material="red"),
                warprt.Mesh(vertices=v, faces=f, material="blue", transform=transform)),
        materials={"floor": warprt.Material(kd=0.7), "red": warprt.Material(kd=(0.8, 0.2, 0.2), ks=0.3, p=20),
                   "blue": warprt.Material(kd=(0.2, 0.3, 0.8))},
        lights=lights or (warprt.PointLight(position=(2, 4, 3), intensity=0.9),
                          warprt.DirectionalLight(direction=(-0.3, -1, -0.2), intensity=0.4)),
        ambient=0.1, background=(0.3, 0.4, 0.5), render=REGULAR)


def random_poses(rng, worlds):
    """(W, 3, 7) shape poses: the plane stays, the sphere and the box move and turn."""
    out = np.zeros((worlds, 3, 7))
    out[..., 6] = 1.0
    for w in range(worlds):
        out[w, 1, :3] = [rng.uniform(-1, 1), 0.45, rng.uniform(-1, 0.5)]
        out[w, 1, 3:] = quat(rng.normal(size=3), rng.uniform(0, math.pi))
        out[w, 2, :3] = [rng.uniform(-1.2, 1.2), rng.uniform(0.4, 1.0), rng.uniform(-1, 0.5)]
        out[w, 2, 3:] = quat(rng.normal(size=3), rng.uniform(0, math.pi))
    return out


def camera_pose(eye, look_at, up=(0, 1, 0)):
    eye, look_at, up = (np.asarray(a, np.float64) for a in (eye, look_at, up))
    w = (eye - look_at) / np.linalg.norm(eye - look_at)
    u = np.cross(up, w)
    u /= np.linalg.norm(u)
    v = np.cross(w, u)
    m = np.eye(4)
    m[:3, :3] = np.stack([u, v, w], axis=1)
    m[:3, 3] = eye
    return m


def posed_scene(poses_w, lights_w, cam_m, fov):
    """The single-render scene equal to world poses ``poses_w`` seen from camera matrix ``cam_m``."""
    v, f = box()
    r_mesh, t_mesh = rot(poses_w[2, 3:]), poses_w[2, :3]
    vm = np.array([MESH_TRANSFORM.apply_point(p) for p in v]) @ r_mesh.T + t_mesh
    eye = cam_m[:3, 3]
    cam = warprt.Camera(eye=tuple(eye), look_at=tuple(eye - cam_m[:3, 2]), up=tuple(cam_m[:3, 1]), fov=fov,
                        width=X, height=H)
    lights = (warprt.PointLight(position=tuple(lights_w[0]), intensity=0.9),
              warprt.DirectionalLight(direction=tuple(lights_w[1]), intensity=0.4))
    s = base_scene(mesh_vertices=vm, camera=cam, lights=lights)
    shapes = list(s.shapes)
    shapes[1] = warprt.Sphere(center=tuple(poses_w[1, :3]), radius=0.45, material="red")
    return s.replace(shapes=tuple(shapes))


def test_every_world_and_camera_equals_the_single_render_of_that_world():
    rng = np.random.default_rng(7)
    scene = base_scene()
    br = BatchRenderer(scene, worlds=W, cameras=C, device="cpu")
    poses = random_poses(rng, W)
    br.set_shape_poses(poses)
    lights = np.array([[[2 + w, 4, 3 - w], [-0.3 + 0.2 * w, -1, -0.2]] for w in range(W)], np.float32)
    wp.copy(br.light_positions, wp.array(lights, dtype=wp.vec3, device="cpu"))
    cams = np.array([[camera_pose((0.5 * w - 0.5, 2.0 + c, 5.0 - c), (0.2 * c, 0.4, 0)) for c in range(C)]
                     for w in range(W)])
    br.set_camera_poses(cams)
    fovs = np.array([45.0, 30.0], np.float32)
    wp.copy(br.fov, wp.array(fovs, dtype=float, device="cpu"))
    result = br.render(spp=1)
    batch = result.numpy()
    assert batch.shape == (W, C, H, X, 3)
    worst, flipped, rays = 0.0, 0, 0
    for w in range(W):
        for c in range(C):
            single = warprt.Renderer(posed_scene(poses[w], lights[w], cams[w, c], float(fovs[c])), device="cpu")
            out = single.render(spp=1, progress=False)
            ref, rays = out.image, rays + out.rays
            diff = np.abs(batch[w, c] - ref).max(axis=2)
            bad = diff > 5e-5 + 5e-5 * ref.max(axis=2)
            flipped += int(bad.sum())
            worst = max(worst, float(diff[~bad].max()))
            # the views really differ: a wrong world or camera index would not pass
            if w or c:
                assert np.abs(batch[w, c] - batch[0, 0]).max() > 0.05
    assert flipped <= 3, f"{flipped} pixels see another surface than the single render"
    assert worst < 5e-5, worst
    if flipped == 0:  # the same rays, camera, secondary and shadow, as the single renders together
        assert result.rays == rays


def test_batches_are_bit_identical_for_any_thread_or_slice_count_and_worlds_are_independent():
    scene = base_scene().with_settings(sampler="sobol")
    rng = np.random.default_rng(3)
    poses = random_poses(rng, W)
    br = BatchRenderer(scene, worlds=W, cameras=C, device="cpu")
    br.set_shape_poses(poses)
    a = br.render(spp=3, seed=5, workers=1, slices=1).numpy()
    b = br.render(spp=3, seed=5, workers=2, slices=7).numpy()
    assert np.array_equal(a, b)
    # a fresh batch, a slice per row (a reused film would hide rows a slicing leaves out: they keep
    # the last sums)
    fresh = BatchRenderer(scene, worlds=W, cameras=C, device="cpu")
    fresh.set_shape_poses(poses)
    assert np.array_equal(fresh.render(spp=3, seed=5, workers=2, slices=W * C * fresh.height).numpy(), a)
    # and fresh batches whose workers claim blocks of rows (the default), one worker and two
    for workers in (1, 2):
        fresh = BatchRenderer(scene, worlds=W, cameras=C, device="cpu")
        fresh.set_shape_poses(poses)
        for _ in range(2):  # (the second render claims the blocks from the first again)
            assert np.array_equal(fresh.render(spp=3, seed=5, workers=workers).numpy(), a)
            assert fresh.film.data.claims.numpy()[0] == workers * -(-W * C * fresh.height // 4)
    poses2 = poses.copy()
    poses2[1, 1, :3] += [0.3, 0.0, 0.0]  # world 1's sphere moves
    br.set_shape_poses(poses2)
    c = br.render(spp=3, seed=5).numpy()
    assert np.array_equal(c[0], a[0]) and np.array_equal(c[2], a[2])
    assert not np.array_equal(c[1], a[1])


def test_batch_aovs_are_bit_identical_for_any_thread_or_slice_count():
    """A batch's AOVs come from its own camera samples, added in sample order by the thread that
    owns the pixel: the same bit for bit for any worker and slice count, and the colour of the
    same render is the colour without AOVs."""
    scene = base_scene().with_settings(sampler="sobol")
    poses = random_poses(np.random.default_rng(3), W)
    names = ["depth", "normal", "coverage", "object_id", "material", "albedo"]
    br = BatchRenderer(scene, worlds=W, cameras=C, device="cpu")
    br.set_shape_poses(poses)
    plain = br.render(spp=3, seed=5, workers=1).numpy()
    a = br.render(spp=3, seed=5, workers=1, slices=1, aovs=names)
    assert np.array_equal(a.numpy(), plain)
    first = a.aovs_numpy()
    assert 0 < first["coverage"].mean() < 1
    for options in (dict(workers=2, slices=7), dict(workers=2), dict(workers=1)):
        got = br.render(spp=3, seed=5, aovs=names, **options).aovs_numpy()
        for name in names:
            assert got[name].tobytes() == first[name].tobytes(), (name, options)


def test_analytic_bvh_over_worlds_agrees_with_the_loop():
    """Enough spheres for the grouped BVH: the same images as a batch below the threshold plus the
    rest of the spheres... compared as the same batch rendered with each world's spheres checked
    one by one on the host (float64) for which sphere a centre ray sees."""
    spheres = tuple(warprt.Sphere(center=(x - 2.0, 0.3, z - 2.0), radius=0.25)
                    for x in range(5) for z in range(4))
    scene = warprt.Scene(camera=warprt.Camera(eye=(0, 5, 6), look_at=(0, 0, -0.5), fov=50, width=X, height=H),
                         shapes=spheres, lights=(warprt.PointLight(position=(0, 6, 2)),), render=REGULAR)
    rng = np.random.default_rng(11)
    poses = np.zeros((W, len(spheres), 7))
    poses[..., 6] = 1.0
    poses[..., :3] = rng.uniform(-0.6, 0.6, size=(W, len(spheres), 3))
    br = BatchRenderer(scene, worlds=W, cameras=1, device="cpu")
    assert br.bvh is not None
    br.set_shape_poses(poses)
    batch = br.render(spp=1).numpy()
    # the worlds' lights, posed, have no light buffer (accel.light_buffer), which a single render
    # of the scene has
    assert (br.tables.plights.numpy()["lb_cell0"] == -1).all()
    assert int(warprt.Renderer(scene, device="cpu").built.data.plights.numpy()["lb_cell0"][0]) >= 0
    for w in range(W):
        moved = tuple(warprt.Sphere(center=tuple(np.add(s.center, poses[w, i, :3])), radius=0.25)
                      for i, s in enumerate(spheres))
        ref = warprt.Renderer(scene.replace(shapes=moved), device="cpu").render(spp=1, progress=False).image
        diff = np.abs(batch[w, 0] - ref).max(axis=2)
        assert (diff > 1e-4).sum() <= 3 and np.median(diff) < 1e-6


def test_update_loop_makes_no_host_copy_no_rebuild_and_no_compile(monkeypatch):
    scene = base_scene()
    br = BatchRenderer(scene, worlds=W, cameras=C, device="cpu")
    br.render(spp=1)  # loads the kernels
    before = dict(br.counters)

    @wp.kernel
    def step(poses: wp.array2d(dtype=wp.transform), t: float):
        w, s = wp.tid()
        if s > 0:
            poses[w, s] = wp.transform(wp.vec3(0.3 * wp.sin(t + float(w)), 0.5, 0.2 * float(s)),
                                       wp.quat_from_axis_angle(wp.vec3(0.0, 1.0, 0.0), t))

    wp.launch(step, dim=(W, 3), inputs=[br.shape_poses, 0.0], device="cpu")  # (compiled before counting)
    calls = {"numpy": 0, "assign": 0, "from_host": 0, "loads": 0, "check_reads": 0}
    originals = {}

    def wrap(owner, name, key, condition=None):
        fn = getattr(owner, name)
        originals[(owner, name)] = fn

        def counted(*args, **kwargs):
            if condition is None or condition(*args, **kwargs):
                calls[key] += 1
            return fn(*args, **kwargs)

        monkeypatch.setattr(owner, name, counted)

    # the device check of the inputs (warprt.checks) reads back its answer, nine integers, once a render
    wrap(wp.array, "numpy", "check_reads", lambda self: self.size == BATCH_SLOTS and self.dtype == wp.int32)
    wrap(wp.array, "numpy", "numpy", lambda self: not (self.size == BATCH_SLOTS and self.dtype == wp.int32))
    wrap(wp.array, "assign", "assign")
    wrap(wp.array, "__init__", "from_host",
         lambda self, data=None, *a, **k: data is not None and not isinstance(data, wp.array))
    from warp._src.context import Module
    load = Module.load

    def counting_load(self, device, *args, **kwargs):
        key = (wp.get_device(device).context, kwargs.get("block_dim", args[0] if args else None)
               or self.options["block_dim"])
        if key not in self.execs:
            calls["loads"] += 1
        return load(self, device, *args, **kwargs)

    monkeypatch.setattr(Module, "load", counting_load)
    images = []
    for k in range(4):
        wp.launch(step, dim=(W, 3), inputs=[br.shape_poses, 0.4 * k], device="cpu")
        images.append(wp.clone(br.render(spp=1).color))
    monkeypatch.undo()
    assert calls == {"numpy": 0, "assign": 0, "from_host": 0, "loads": 0, "check_reads": 4}, calls
    assert br.counters == before
    # and the poses really were used: the frames differ
    assert not np.array_equal(images[0].numpy(), images[3].numpy())


def test_motion_blur_between_pose_arrays_matches_a_moving_sphere():
    """A sphere posed at shutter open and close renders as the single-scene sphere with
    ``center_end`` (same samples: world 0, camera 0 has the single image's noise keys)."""
    sphere = warprt.Sphere(center=(0, 0.5, 0), radius=0.5)
    scene = warprt.Scene(camera=warprt.Camera(eye=(0, 1, 4), look_at=(0, 0.5, 0), fov=40, width=X, height=H),
                         shapes=(sphere,), lights=(warprt.PointLight(position=(1, 3, 3)),),
                         render=warprt.RenderSettings(sampler="stratified", spp=16, adaptive=False))
    br = BatchRenderer(scene, worlds=1, cameras=1, device="cpu", motion_blur=True)
    start = np.array([[[0, 0, 0, 0, 0, 0, 1]]], np.float64)
    end = np.array([[[0.8, 0, 0, 0, 0, 0, 1]]], np.float64)
    br.set_shape_poses(start, end=end)
    blurred = br.render(spp=16, seed=2).numpy()[0, 0]
    moving = scene.replace(shapes=(warprt.Sphere(center=(0, 0.5, 0), center_end=(0.8, 0.5, 0), radius=0.5),))
    ref = warprt.Renderer(moving, device="cpu").render(spp=16, seed=2, progress=False).image
    sharp = warprt.Renderer(scene, device="cpu").render(spp=16, seed=2, progress=False).image
    # equal up to camera-frame rounding (a sample near an edge may flip): the mean over the image
    # agrees to float32 sums, and the blurred image is far from the sharp one
    assert abs(blurred.mean() - ref.mean()) < 2e-4 * ref.mean()
    assert np.mean(np.abs(blurred - ref) > 1e-4) < 0.01
    assert np.abs(blurred - sharp).mean() > 20 * np.abs(blurred - ref).mean()


def test_pose_inputs_are_checked():
    scene = base_scene()
    br = BatchRenderer(scene, worlds=2, cameras=1, device="cpu")
    with pytest.raises(RenderError, match=r"shape_poses: expected values shaped \(2, 3, 7\)"):
        br.set_shape_poses(np.zeros((2, 2, 7)))
    with pytest.raises(RenderError, match=r"shape_poses\[0, 0\]: a quaternion is zero"):
        br.set_shape_poses(np.zeros((2, 3, 7)))
    for bad in ("abc", None, [["x"]], {"a": 1}):
        with pytest.raises(RenderError, match="shape_poses: expected"):
            br.set_shape_poses(bad)
    huge = np.zeros((2, 1, 7))
    huge[..., 6] = 1.0
    huge[1, 0, 2] = 1e39  # finite in float64, infinite in float32
    with pytest.raises(RenderError, match=r"camera_poses\[1, 0\]: position \(0, 0, 1e\+39\) is beyond 1e\+19"):
        br.set_camera_poses(huge)
    huge[1, 0, 2] = np.nan
    with pytest.raises(RenderError, match=r"camera_poses\[1, 0\]: position \(0, 0, nan\) is not finite"):
        br.set_camera_poses(huge)
    shear = np.tile(np.eye(4), (2, 3, 1, 1))
    shear[0, 0, 0, 1] = 0.5
    with pytest.raises(RenderError, match="rotation and a translation"):
        br.set_shape_poses(shear)
    with pytest.raises(RenderError, match="worlds must be a positive integer"):
        BatchRenderer(scene, worlds=0)
    with pytest.raises(RenderError, match="expected a wp.array of wp.transform or wp.mat44"):
        br.set_camera_poses(wp.zeros((2, 1), dtype=wp.vec3, device="cpu"))
    # matrices (rigid) are accepted, as numpy and as wp.mat44 arrays, and give the same pose
    m = np.tile(camera_pose((1, 2, 3), (0, 0, 0)), (2, 1, 1, 1))
    br.set_camera_poses(m)
    from_numpy = br.camera_poses.numpy().copy()
    br.set_camera_poses(wp.array(m.astype(np.float32), dtype=wp.mat44, device="cpu"))
    np.testing.assert_allclose(br.camera_poses.numpy(), from_numpy, atol=1e-6)


def test_batch_aovs_equal_the_single_render_aovs_of_each_world():
    rng = np.random.default_rng(5)
    scene = base_scene().with_settings(sampler="regular")
    br = BatchRenderer(scene, worlds=2, cameras=2, device="cpu")
    poses = random_poses(rng, 2)
    br.set_shape_poses(poses)
    cams = np.array([[camera_pose((0.4 * w, 2.0 + c, 5.0), (0, 0.4, 0)) for c in range(2)] for w in range(2)])
    br.set_camera_poses(cams)
    names = ["depth", "normal", "coverage", "object_id", "material"]
    out = br.render(spp=4, aovs=names)
    got = out.aovs_numpy()
    assert isinstance(out.aovs["depth"], wp.array) and got["normal"].shape == (2, 2, H, X, 3)
    lights = np.array([[[2, 4, 3], [-0.3, -1, -0.2]]] * 2, np.float32)
    for w in range(2):
        for c in range(2):
            ref = warprt.Renderer(posed_scene(poses[w], lights[w], cams[w, c], 45.0), device="cpu").render(
                spp=4, progress=False, aovs=names).aovs
            same_id = got["object_id"][w, c] == ref["object_id"]
            assert same_id.mean() > 0.99  # a float32 flip at an edge aside
            np.testing.assert_array_equal(got["coverage"][w, c][same_id], ref["coverage"][same_id])
            np.testing.assert_array_equal(got["material"][w, c][same_id], ref["material"][same_id])
            hit = same_id & np.isfinite(ref["depth"]) & (ref["coverage"] == 1)
            np.testing.assert_allclose(got["depth"][w, c][hit], ref["depth"][hit], rtol=2e-5)
            np.testing.assert_allclose(got["normal"][w, c][hit], ref["normal"][hit], atol=2e-4)
    assert len(set(np.unique(got["object_id"]))) == 4  # sky, floor, sphere, box


# --- device inputs checked on the device (warprt.checks) --------------------------------------------


def _set(array: "wp.array", index, value) -> None:
    a = array.numpy()
    a[index] = value
    array.assign(a)


@pytest.mark.parametrize("name, index, value, words", [
    ("shape_poses", (1, 2, 0), np.nan, "shape_poses[1, 2] (world 1, scene.shapes[2]): position (nan, 0, 0) is not finite"),
    ("shape_poses", (0, 1, 6), 1.01, "shape_poses[0, 1] (world 0, scene.shapes[1]): quaternion (0, 0, 0, 1.01) has "
                                     "squared length 1.0201"),
    ("shape_poses", (1, 1, 3), np.inf, "quaternion (inf, 0, 0, 1) is not finite"),
    ("camera_poses", (1, 1, 5), np.nan, "camera_poses[1, 1] (world 1, camera 1): quaternion"),
    ("camera_poses", (0, 1, 0), 3e19, "camera_poses[0, 1] (world 0, camera 1): position (3e+19"),
    ("light_positions", (1, 0, 1), np.nan, "light_positions[1, 0] (world 1, scene.lights[0]): position"),
    ("light_positions", (0, 1), 0.0, "light_positions[0, 1] (world 0, scene.lights[1]): direction (0, 0, 0) is zero"),
    ("fov", 1, 0.0, "fov[1] (camera 1): 0 degrees is outside (0, 180)"),
    ("fov", 0, 180.0, "fov[0] (camera 0): 180 degrees"),
    ("fov", 0, np.nan, "fov[0] (camera 0): nan degrees"),
])
def test_device_inputs_are_checked_on_the_device_before_each_render(name, index, value, words):
    """A NaN, a non-unit quaternion, a huge coordinate, a zero direction or a zero field of view
    written into a pose array (as a simulation kernel would) is named, world, camera, shape or
    light, before anything renders; check_inputs=False lets it through (and the render then
    goes on as before, e.g. a black view or a vanished body)."""
    br = BatchRenderer(base_scene(), worlds=2, cameras=2, device="cpu")
    good = br.render(spp=1).numpy()
    before = getattr(br, name).numpy().copy()
    _set(getattr(br, name), index, value)
    with pytest.raises(RenderError) as info:
        br.render(spp=1)
    assert words in str(info.value) and str(info.value).endswith("(check_inputs=False skips this check)")
    br.check_inputs = False
    br.render(spp=1)
    br.check_inputs = True
    getattr(br, name).assign(before)
    assert np.array_equal(br.render(spp=1).numpy(), good)  # (the check changes no image)


def test_a_quaternion_normalised_in_float32_passes_and_the_end_poses_are_checked_with_motion_blur():
    # (the motion-blur test's scene: its kernel variant is built anyway)
    scene = warprt.Scene(camera=warprt.Camera(eye=(0, 1, 4), look_at=(0, 0.5, 0), fov=40, width=X, height=H),
                         shapes=(warprt.Sphere(center=(0, 0.5, 0), radius=0.5),),
                         lights=(warprt.PointLight(position=(1, 3, 3)),))
    br = BatchRenderer(scene, worlds=2, cameras=1, device="cpu", motion_blur=True)
    poses = random_poses(np.random.default_rng(2), 2)[:, 1:2].astype(np.float32)  # |q| off 1 by float32 rounding
    assert np.abs((poses[..., 3:].astype(np.float64) ** 2).sum(-1) - 1).max() > 0
    wp.copy(br.shape_poses, wp.array(poses, dtype=wp.transform, device="cpu"))
    wp.copy(br.shape_poses_end, wp.array(poses, dtype=wp.transform, device="cpu"))
    br.render(spp=1)
    _set(br.shape_poses_end, (1, 0, 0), np.nan)
    with pytest.raises(RenderError, match=r"^shape_poses_end\[1, 0\]"):
        br.render(spp=1)


def test_replaced_pose_arrays_are_named():
    br = BatchRenderer(base_scene(), worlds=2, cameras=1, device="cpu")
    br.fov = wp.zeros(3, dtype=float, device="cpu")
    with pytest.raises(RenderError, match=r"^fov: expected a contiguous wp.array of float shaped \(1,\)"):
        br.render(spp=1)
    br.fov = np.array([45.0], np.float32)
    with pytest.raises(RenderError, match="^fov: expected .* got ndarray"):
        br.render(spp=1)
    br.fov = wp.full(1, 45.0, dtype=float, device="cpu")
    br.shape_poses = wp.zeros((2, 3), dtype=wp.vec3, device="cpu")
    with pytest.raises(RenderError, match="^shape_poses: expected a contiguous wp.array of transformf"):
        br.render(spp=1)
