"""Every feature through every path that can render it: the image and the AOVs agree.

Paths: a single render (``Renderer``, camera packets), the same with camera rays one by one
(``packets=False``: the same image and AOVs bit for bit, as promised), every world and camera of
a ``BatchRenderer``, animation frames (``render_sequence``), the Newton bridge, and CUDA against
the CPU (where a GPU is present). Features: every shape kind and every light kind in each scene
(tests/paths.py), poses of each kind in a batch's second world, objects and camera still,
translating or turning over the shutter, the thin lens, each sampler, adaptive sampling, and all
nine AOVs. The cases are a pairwise covering design over those factors (``paths.pairwise``):
every two levels of every two factors meet in some case.

How two paths must agree (tests/paths.py): the same samples (world 0 camera 0 of a batch, any
world with the ``regular`` sampler, an animation frame against the single render of its poses, a
Newton world against the single render of its bodies' poses) to float32 rounding except where a
sample flips; other samples (a randomised sampler's other worlds and cameras, adaptive against
uniform sampling) statistically.

Kernels: the single renders and the batches use ``Features.full()`` (the batch's one module for
the whole file); the animation and Newton paths take their scenes' own variants, which the rest
of the suite builds too (meshes+area_lights+motion+analytic_bvh and its still form; the Newton
batches' solids+analytic_bvh, motion+solids+analytic_bvh, meshes+solids+analytic_bvh).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import warp as wp

import warprt
from warprt.animation import render_sequence
from warprt.scene.transform import euler_quaternion, quaternion_product, slerp
from warprt.worlds import BatchRenderer

import paths
from paths import AOV_NAMES, FULL, IDENTITY, pose, posed_scene, render, same_distribution, same_samples

SAMPLERS = ("regular", "independent", "stratified", "sobol")
CASES = paths.pairwise({"sampler": SAMPLERS, "camera": ("still", "translate", "turn"),
                        "objects": ("still", "translate", "turn"), "lens": (False, True),
                        "adaptive": (False, True)})
SPP = 8
SEED = 3


def _world1_poses(scene, objects: str):
    """World 1's shape poses at open and close: each shape moved and turned its own way (the
    floor only tilted a little), and at close moved or turned further when the objects move."""
    rng = np.random.default_rng(17)
    n = len(scene.shapes)
    p0, p1 = np.zeros((n, 7)), np.zeros((n, 7))
    for i in range(n):
        small = 3.0 if isinstance(scene.shapes[i], warprt.Plane) else 25.0
        p0[i] = pose(rng.uniform(-0.15, 0.15, 3) * (0 if i == 0 else 1), rng.normal(size=3), rng.uniform(-small, small))
        p1[i] = p0[i]
        if objects == "translate" and i > 0:
            p1[i, :3] += (0.1, 0.0, 0.12)
        elif objects == "turn" and i > 0:
            p1[i, 3:] = quaternion_product(paths.quat(rng.normal(size=3), 20.0), p0[i, 3:])
    return p0, p1


TURN_BATCH = 8.0  # degrees: the batch's other cameras turn the other way


def _camera_poses(scene, motion: str, eye, look):
    p0 = paths.camera_pose(eye, look, scene.camera.up)
    if motion == "translate":
        p1 = p0.copy()
        p1[:3] += (0.3, 0.1, 0.0)
    elif motion == "turn":
        p1 = paths.camera_pose(eye, np.asarray(eye) + paths.yaw(-TURN_BATCH) @ np.subtract(look, eye), scene.camera.up)
        p1[3:] = p1[3:] if np.dot(p1[3:], p0[3:]) >= 0 else -p1[3:]
    else:
        p1 = p0
    return p0, p1


@pytest.mark.parametrize("case", CASES, ids=[paths.case_id(c) for c in CASES])
def test_single_batch_and_scalar_paths_agree(case):
    """One scene of every shape and light kind: a single render, the same with camera rays one by
    one (bit for bit, adaptive sampling included; an adaptive image against a uniform one by its
    mean), and a batch of 2 worlds x 2 cameras whose world 0 camera 0 keeps the scene's poses (the
    same samples: to float32 rounding) while the other three are posed shape by shape, light by
    light and camera by camera, at shutter open and close (the single render of the same poses
    set on the host: the same samples with ``regular``, else statistically). The scene states
    its settings (uniform unless told, fixed shadow rays: a batch's); in the adaptive cases the
    defaults a user gets (adaptive, ``samples = "auto"``) are checked against the batch by noise."""
    scene = paths.every_kind_scene(case["sampler"], case["camera"], case["objects"], case["lens"], SPP)
    single = warprt.Renderer(scene, device="cpu", features=FULL)
    ref = single.render(spp=SPP, seed=SEED, progress=False, aovs=AOV_NAMES)
    adaptive = case["adaptive"]
    # camera rays one by one (CUDA's kernel) and packets: the same bits, adaptive sampling too
    ours = ref
    if adaptive:
        ours = single.render(spp=SPP, seed=SEED, progress=False, aovs=AOV_NAMES, adaptive=True)
    lone = warprt.Renderer(scene, device="cpu", features=FULL, packets=False).render(
        spp=SPP, seed=SEED, progress=False, aovs=AOV_NAMES, adaptive=adaptive)
    assert lone.image.tobytes() == ours.image.tobytes()
    for name in AOV_NAMES:
        assert lone.aovs[name].tobytes() == ours.aovs[name].tobytes(), name
    if adaptive:  # unbiased: the same pixel means as uniform sampling
        z = paths.z_mean(ours.image, single.render(spp=SPP, seed=11, progress=False).image)
        assert abs(z) < paths.Z_LIMIT, z

    # a batch of 2 worlds x 2 cameras: world 0 camera 0 keeps the scene's own poses (the
    # defaults), camera 1 and world 1 are posed
    br = BatchRenderer(scene, worlds=2, cameras=2, device="cpu", features=FULL, motion_blur=True)
    shapes0 = np.tile(IDENTITY, (2, len(scene.shapes), 1))
    shapes1 = shapes0.copy()
    shapes0[1], shapes1[1] = _world1_poses(scene, case["objects"])
    lights = np.array([[(2.0, 4.0, 3.0), (-0.3, -1.0, -0.2)], [(-1.0, 3.5, 2.5), (0.2, -1.0, -0.4)]])
    cams0 = br.camera_poses.numpy().astype(np.float64)
    cams1 = br.camera_poses_end.numpy().astype(np.float64)
    cam = scene.camera
    for w, c, eye, look in ((0, 1, (-0.8, 1.2, 3.6), (0.2, 0.5, -0.2)), (1, 0, (0.6, 2.0, 3.8), (-0.1, 0.3, 0.0)),
                            (1, 1, (1.5, 1.0, 3.0), (0.0, 0.6, 0.0))):
        cams0[w, c], cams1[w, c] = _camera_poses(scene, case["camera"], eye, look)
    fov = (cam.fov, 35.0)
    paths.set_batch(br, shapes0, shapes1, lights, cams0, cams1, fov)
    out = br.render(spp=SPP, seed=SEED, aovs=AOV_NAMES)
    color, aovs = out.numpy(), out.aovs_numpy()
    assert np.abs(color[1, 0] - color[0, 0]).max() > 0.05 and np.abs(color[0, 1] - color[0, 0]).max() > 0.05
    same_samples(color[0, 0], {k: v[0, 0] for k, v in aovs.items()}, ref.image, ref.aovs, "batch world 0", cam.eye)
    if adaptive and case["sampler"] != "regular":
        # what a user gets by default (adaptive sampling, the area lights' shadow rays chosen by the
        # pilot) estimates the batch's pixels too (another seed: independent of the batch's samples)
        scene_defaults = paths.every_kind_scene(case["sampler"], case["camera"], case["objects"], case["lens"], SPP,
                                                defaults=True)
        got = warprt.Renderer(scene_defaults, device="cpu", features=FULL).render(spp=SPP, seed=31, progress=False)
        assert got.adaptive
        same_distribution(got.image, color[0, 0], *(single.render(spp=SPP, seed=s, progress=False).image
                                                    for s in (32, 33)), "the defaults' single render against the batch")
    for w, c in ((0, 1), (1, 0), (1, 1)):
        posed = posed_scene(scene, shapes0[w], shapes1[w], lights[w], cams0[w, c], cams1[w, c], fov[c])
        r = warprt.Renderer(posed, device="cpu", features=FULL)
        what = f"batch world {w} camera {c}"
        if case["sampler"] == "regular":  # the same samples in every pixel, whatever its key
            got = r.render(spp=SPP, seed=SEED, progress=False, aovs=AOV_NAMES)
            same_samples(color[w, c], {k: v[w, c] for k, v in aovs.items()}, got.image, got.aovs, what,
                         cams0[w, c, :3])
        else:
            refs = [r.render(spp=SPP, seed=s, progress=False).image for s in (21, 22, 23)]
            same_distribution(color[w, c], *refs, what)


# --- animation frames -----------------------------------------------------------------------

FPS = 2.0
ANIM_KEYS = {
    "camera": {"still": [], "translate": [{"time": 0.0, "eye": (0.0, 1.5, 4.0), "look_at": (0.0, 0.5, 0.0)},
                                          {"time": 2.0, "eye": (1.0, 1.75, 4.0), "look_at": (1.0, 0.75, 0.0)}],
               "turn": [{"time": 0.0, "look_at": (-0.5, 0.5, 0.0)}, {"time": 2.0, "look_at": (1.5, 0.25, 0.0)}]},
    "objects": {"still": ([], []),
                "translate": ([{"time": 0.0, "center": (-1.0, 0.4, 0.25)}, {"time": 2.0, "center": (0.5, 0.4, 0.5)}],
                              [{"time": 0.0, "translate": (0.5, 0.75, -0.25)},
                               {"time": 2.0, "translate": (1.5, 0.5, -0.25)}]),
                "turn": ([{"time": 0.0, "center": (-1.0, 0.4, 0.25)}, {"time": 2.0, "center": (-1.0, 0.4, 1.25)}],
                         [{"time": 0.0, "rotate": (0.0, 0.0, 0.0)}, {"time": 2.0, "rotate": (20.0, 120.0, 0.0)}])},
}


def _lerp(keys, t, name, default):
    ks = [k for k in keys if name in k]
    if not ks:
        return default
    a, b = ks[0], ks[-1]
    f = min(max((t - a["time"]) / (b["time"] - a["time"]), 0.0), 1.0)
    return tuple(float(x + (y - x) * f) for x, y in zip(a[name], b[name]))


def _animated(camera_motion: str, objects: str, sampler: str) -> warprt.Scene:
    v, f = paths.closed_mesh()
    cam_keys = ANIM_KEYS["camera"][camera_motion]
    sphere_keys, mesh_keys = ANIM_KEYS["objects"][objects]
    base_mesh = warprt.Transform(translate=(0.5, 0.75, -0.25), scale=(1.2, 0.8, 1.0))
    return warprt.Scene(
        camera=warprt.Camera(eye=(0.0, 1.5, 4.0), look_at=(0.0, 0.5, 0.0), width=paths.W, height=paths.H,
                             keyframes=tuple(cam_keys)),
        shapes=(warprt.Plane(material="floor"),
                warprt.Sphere(center=(-1.0, 0.4, 0.25), radius=0.4, material="red", keyframes=tuple(sphere_keys)),
                warprt.Rectangle(corner=(-1.5, 0.0, -1.0), edge1=(2.0, 0.0, 0.0), edge2=(0.0, 1.2, -0.2)),
                warprt.Mesh(vertices=v, faces=f, material="red", transform=base_mesh, keyframes=tuple(mesh_keys))),
        materials={"floor": warprt.Material(kd=0.6), "red": warprt.Material(kd=(0.8, 0.2, 0.2), ks=0.3, p=20)},
        lights=(warprt.PointLight(position=(2.0, 4.0, 3.0), intensity=0.6),
                warprt.RectLight(corner=(-0.5, 2.0, -0.5), edge1=(1.0, 0.0, 0.0), edge2=(0.0, 0.0, 1.0),
                                 radiance=1.5, samples=2)),
        ambient=0.05, background=(0.2, 0.25, 0.3), animation=warprt.Animation(frames=4, fps=FPS),
        render=warprt.RenderSettings(sampler=sampler, spp=SPP))


def _frame_by_hand(scene: warprt.Scene, frame: int) -> warprt.Scene:
    """Frame ``frame`` posed here, in float64: keyframes interpolated at the frame's time and at
    the next frame's (the shutter spans one frame), rotations by slerp of the keys' quaternions."""
    from dataclasses import replace

    t0, t1 = frame / FPS, (frame + 1) / FPS
    cam = scene.camera
    keys = cam.keyframes
    cam = replace(cam, keyframes=(), eye=_lerp(keys, t0, "eye", cam.eye),
                  look_at=_lerp(keys, t0, "look_at", cam.look_at),
                  eye_end=_lerp(keys, t1, "eye", cam.eye), look_at_end=_lerp(keys, t1, "look_at", cam.look_at))
    shapes = []
    for s in scene.shapes:
        if isinstance(s, warprt.Sphere) and s.keyframes:
            s = replace(s, keyframes=(), center=_lerp(s.keyframes, t0, "center", s.center),
                        center_end=_lerp(s.keyframes, t1, "center", s.center))
        elif isinstance(s, warprt.Mesh) and s.keyframes:
            base = s.transform

            def at(t):
                translate = _lerp(s.keyframes, t, "translate", base.translate)
                rot = [k for k in s.keyframes if "rotate" in k]
                q = base.quaternion()
                if rot:
                    f = min(max(t / rot[-1]["time"], 0.0), 1.0)
                    q = slerp(euler_quaternion(rot[0]["rotate"]), euler_quaternion(rot[-1]["rotate"]), f)
                return warprt.Transform.from_quaternion(q, translate=translate, scale=base.scale)

            s = replace(s, keyframes=(), transform=at(t0), transform_end=at(t1))
        shapes.append(s)
    return scene.replace(camera=cam, shapes=tuple(shapes))


ANIM_CASES = paths.pairwise({"camera": ("still", "translate", "turn"), "objects": ("still", "translate", "turn"),
                             "sampler": ("stratified", "sobol", "independent")})


@pytest.mark.parametrize("case", ANIM_CASES, ids=[paths.case_id(c) for c in ANIM_CASES])
def test_animation_frames_equal_single_renders_of_their_poses(case):
    scene = _animated(case["camera"], case["objects"], case["sampler"])
    frames = [1, 2]
    seq = render_sequence(scene, frames=frames, spp=SPP, seed=SEED, progress=False, aovs=AOV_NAMES)
    for f, got in zip(frames, seq):
        by_hand = _frame_by_hand(scene, f)
        ref = render(by_hand, SPP, seed=SEED + f)  # frame f takes seed + f wherever it is rendered
        same_samples(got["color"], got, ref.image, ref.aovs, f"frame {f}", by_hand.camera.eye)
        if by_hand.camera.moves or case["objects"] != "still":  # the blur is there: not the frame's still pose
            sharp = render(by_hand.with_camera(shutter=(0.0, 0.0)), SPP, seed=SEED + f, aovs=()).image
            assert np.abs(sharp - got["color"]).max() > 0.05


# --- the Newton bridge ------------------------------------------------------------------------

def _newton_model(newton, worlds: int, cone: bool):
    b = newton.ModelBuilder()
    b.add_ground_plane(color=(0.8, 0.8, 0.75))
    sub = newton.ModelBuilder()
    body = sub.add_body(xform=wp.transform((0.0, 0.0, 0.3), wp.quat_identity()))
    sub.add_shape_box(body, hx=0.25, hy=0.2, hz=0.3, color=(0.9, 0.2, 0.2))
    body = sub.add_body(xform=wp.transform((0.8, 0.5, 0.35), wp.quat_identity()))
    sub.add_shape_sphere(body, radius=0.35, color=(0.2, 0.4, 0.9),
                         xform=wp.transform((0.0, 0.0, 0.1), wp.quat_identity()))
    body = sub.add_body(xform=wp.transform((-0.7, 0.4, 0.3), wp.quat_identity()))
    sub.add_shape_capsule(body, radius=0.15, half_height=0.25, color=(0.3, 0.8, 0.3))
    body = sub.add_body(xform=wp.transform((0.2, -0.8, 0.3), wp.quat_identity()))
    sub.add_shape_cylinder(body, radius=0.2, half_height=0.3, color=(0.8, 0.7, 0.2),
                           xform=wp.transform((0.0, 0.0, 0.0), wp.quat_from_axis_angle(wp.vec3(1, 0, 0), 0.5)))
    if cone:
        body = sub.add_body(xform=wp.transform((-0.5, -0.7, 0.3), wp.quat_identity()))
        sub.add_shape_cone(body, radius=0.25, half_height=0.3, color=(0.6, 0.3, 0.8))
    b.replicate(sub, worlds)
    return b.finalize(device="cpu")


def _body_poses(model, rng, spread: float):
    q = model.state().body_q.numpy().astype(np.float64)
    for i in range(len(q)):
        q[i, :2] += rng.uniform(-spread, spread, size=2)
        q[i, 3:] = paths.quat(rng.normal(size=3), rng.uniform(0, 60.0))
    return q


def _shape_pose(model, s: int, body_q: np.ndarray) -> np.ndarray:
    """Newton's world pose of shape s: its body's pose times its own transform, in float64."""
    x = model.shape_transform.numpy()[s].astype(np.float64)
    b = int(model.shape_body.numpy()[s])
    if b < 0:
        return x
    q = quaternion_product(body_q[b, 3:], x[3:])
    return np.concatenate([paths.apply(body_q[b], x[:3]), q])


NEWTON_CASES = [dict(motion_blur=False, cone=True, sampler="regular"),
                dict(motion_blur=False, cone=True, sampler="sobol"),
                dict(motion_blur=True, cone=False, sampler="regular"),
                dict(motion_blur=True, cone=False, sampler="stratified")]


@pytest.mark.parametrize("case", NEWTON_CASES, ids=[paths.case_id(c) for c in NEWTON_CASES])
def test_newton_worlds_equal_single_renders_of_their_bodies(case):
    newton = pytest.importorskip("newton")
    from warprt.newton_bridge import NewtonRenderer, look_at_pose

    worlds, cams = 2, 2
    m = _newton_model(newton, worlds, case["cone"])
    camera = warprt.Camera(fov=40.0, width=paths.W, height=paths.H)
    lights = (warprt.DirectionalLight(direction=(-1, 1, -1), intensity=0.8), warprt.PointLight(position=(1, -2, 3)))
    r = NewtonRenderer(m, cameras=cams, camera=camera, lights=lights, ambient=0.05, background=(0.3, 0.35, 0.4),
                       render=warprt.RenderSettings(sampler=case["sampler"], spp=SPP, adaptive=False),
                       motion_blur=case["motion_blur"])
    rng = np.random.default_rng(9)
    states = [_body_poses(m, rng, 0.3)]
    if case["motion_blur"]:
        moved = states[0].copy()
        moved[:, 0] += 0.15
        for i in range(len(moved)):
            moved[i, 3:] = quaternion_product(paths.quat((0, 0, 1), 25.0), moved[i, 3:])
        states.append(moved)
    for q in states:
        state = m.state()
        state.body_q.assign(q.astype(np.float32))
        r.update(state)
    cam0 = np.array([[look_at_pose((3.0 - w, -3.0 + c, 2.0), (0.0, 0.0, 0.3)) for c in range(cams)]
                     for w in range(worlds)])
    cam1 = cam0.copy()
    if case["motion_blur"]:  # the cameras turn too
        for w in range(worlds):
            for c in range(cams):
                cam1[w, c] = look_at_pose((3.0 - w, -3.0 + c, 2.0), (0.4, 0.3, 0.3))
    r.set_camera_poses(cam0, end=cam1)
    out = r.render(spp=SPP, seed=SEED, aovs=AOV_NAMES)
    color, aovs = out.numpy(), out.aovs_numpy()
    scene, smap = r.scene, r.shape_map
    light_positions = [lights[0].direction, lights[1].position]
    for w in range(worlds):
        p0 = np.array([_shape_pose(m, s, states[0]) for s in smap.newton_shape[w]])
        p1 = np.array([_shape_pose(m, s, states[-1]) for s in smap.newton_shape[w]])
        for c in range(cams):
            posed = paths.posed_scene(scene, p0, p1, light_positions, cam0[w, c], cam1[w, c], 40.0)
            what = f"newton world {w} camera {c}"
            if case["sampler"] == "regular" or (w, c) == (0, 0):
                ref = render(posed, SPP, seed=SEED)
                same_samples(color[w, c], {k: v[w, c] for k, v in aovs.items()}, ref.image, ref.aovs, what,
                             cam0[w, c, :3], height=2.0)
            else:
                rr = warprt.Renderer(posed, device="cpu", features=FULL)
                refs = [rr.render(spp=SPP, seed=s, progress=False).image for s in (21, 22, 23)]
                same_distribution(color[w, c], *refs, what)


# --- CUDA against the CPU ----------------------------------------------------------------------


def rel_mse(a, b) -> float:
    return float(np.mean((a - b) ** 2 / (b * b + 1e-2)))


@pytest.mark.parametrize("case", CASES[:4], ids=[paths.case_id(c) for c in CASES[:4]])
def test_cuda_renders_what_the_cpu_renders(case, cuda_device):
    """CUDA rounds its sin, exp and the like differently (docs/pipelines.md: relative MSE below
    1e-6 on the peer scenes); single renders, adaptive ones, their AOVs and a batch."""
    scene = paths.every_kind_scene(case["sampler"], case["camera"], case["objects"], case["lens"], SPP)
    kw = dict(spp=SPP, seed=SEED, progress=False, aovs=AOV_NAMES, adaptive=case["adaptive"])
    cpu = warprt.Renderer(scene, device="cpu", features=FULL).render(**kw)
    gpu = warprt.Renderer(scene, device=cuda_device, features=FULL).render(**kw)
    assert rel_mse(gpu.image, cpu.image) < 1e-6
    assert (gpu.aovs["object_id"] == cpu.aovs["object_id"]).mean() > 0.98
    batches = [BatchRenderer(scene, worlds=2, cameras=1, device=d, features=FULL, motion_blur=True).render(
        spp=SPP, seed=SEED).numpy() for d in ("cpu", cuda_device)]
    assert rel_mse(batches[1], batches[0]) < 1e-6
