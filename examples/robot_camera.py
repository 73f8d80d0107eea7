"""Synthetic robot-camera data from a Newton simulation: randomised, textured scenes, every world
at once, through a calibrated camera with lens distortion, colour with a stereo depth camera's
noisy depth beside the exact one.

    pip install 'warprt[newton]'
    python examples/robot_camera.py                      # 2 episodes x 4 worlds, 128x96, 6 steps, into out/robot/
    python examples/robot_camera.py results --width 48 --height 32 --spp 1 --steps 2 --worlds 2 --episodes 2

Each episode draws new looks for every world at once (domain randomisation on the device: no
rebuild, no recompile): each shape's colour and texture (a few procedural and bitmap textures
projected triplanar or cubic, since Newton's boxes, spheres and capsules carry no UVs), the
sun's intensity and direction, and the camera's pose around the table. Objects fall onto the
table (Newton's XPBD solver) and every step renders every world through a head-mounted camera
with lens distortion (OpenCV's model, as a calibration gives it) and a RealSense-like depth
sensor (``warprt.DepthSensor``: stereo noise σ_Z = Z²·σ_d/(f·b), range limits, dropouts at
grazing angles), the noise seeded by the step. For episode e, world w
and step s it writes ``OUT/e{e}_w{w}_{s:03d}.png`` (colour), ``..._depth.png`` (the sensor's
depth, near bright, no value black) and ``....exr`` (colour, exact ``Z`` and the sensor's
``sensor_z`` layer). The scene is made in :func:`make_scene` (textures, lights, the sensor), the
camera in :func:`make_camera` and the looks in :func:`randomise_worlds`: each is one place to
change for other sensors or looks.
"""

from __future__ import annotations

import argparse
import os
import sys

import numpy as np

SENSOR = dict(baseline=0.05, focal_length=640.0, disparity_sigma=0.08, min_range=0.2, max_range=4.0,
              dropout_start=70.0, dropout_end=87.0)  # a RealSense D435-like stereo pair at 1280 x 720
HEAD = (0.85, -0.7, 0.95)  # the camera's nominal place (m, z up) and what it looks at
TARGET = (0.0, 0.0, 0.45)


def build_model(worlds: int, rng):
    """A table (static) and a few objects above it in each world (their start poses differ per
    world)."""
    import newton
    import warp as wp

    builder = newton.ModelBuilder()  # z up
    builder.add_ground_plane(color=(0.5, 0.5, 0.5))
    for w in range(worlds):
        builder.begin_world()
        builder.add_shape_box(-1, xform=wp.transform((0.0, 0.0, 0.2), wp.quat_identity()), hx=0.5, hy=0.35, hz=0.2)
        for k in range(4):
            x, y = rng.uniform(-0.3, 0.3), rng.uniform(-0.2, 0.2)
            tilt = wp.quat_from_axis_angle(wp.normalize(wp.vec3(*rng.normal(size=3))), float(rng.uniform(0, 3)))
            body = builder.add_body(xform=wp.transform((x, y, 0.55 + 0.15 * k), tilt))
            if k % 3 == 0:
                builder.add_shape_box(body, hx=0.06, hy=0.05, hz=0.04)
            elif k % 3 == 1:
                builder.add_shape_sphere(body, radius=0.05)
            else:
                builder.add_shape_capsule(body, radius=0.03, half_height=0.06)
        builder.end_world()
    return builder.finalize(device="cpu")


def make_textures(rng) -> list:
    """A few textures for the shapes to wear: checkers and two bitmaps made here (a striped and a
    speckled one), all projected in the shape's own frame (Newton's shapes have no UVs)."""
    import warprt

    stripes = np.zeros((16, 16, 3), np.float32)
    stripes[:, ::4] = stripes[:, 1::4] = 0.8  # linear floats: no sRGB decode
    stripes[:, 2::4] = stripes[:, 3::4] = 0.15
    speckle = rng.uniform(0.3, 1.0, size=(32, 32, 1)).astype(np.float32).repeat(3, axis=-1)
    return [
        warprt.Texture(checker=[(0.9, 0.9, 0.9), (0.1, 0.1, 0.1)], scale=20.0, projection="cubic"),
        warprt.Texture(checker=[(0.8, 0.2, 0.2), (0.9, 0.8, 0.2)], scale=30.0, projection="triplanar"),
        warprt.Texture(image=stripes, scale=8.0, projection="triplanar"),
        warprt.Texture(image=speckle, scale=4.0, projection="cubic"),
    ]


def make_camera(width: int, height: int):
    """The head camera as its calibration gives it: OpenCV's intrinsics (a 58° vertical field of
    view, the principal point a little off centre) and its distortion coefficients (k1, k2, p1,
    p2, k3: a mild barrel, as a wide-angle lens has), for the image size asked for; its pose is
    set per world."""
    import warprt

    f = 0.5 * height / np.tan(np.radians(29.0))
    return warprt.Camera(model="opencv", fx=f, fy=f, cx=0.5 * (width - 1) + 0.02 * width,
                         cy=0.5 * (height - 1) - 0.01 * height, distortion=[-0.12, 0.03, 0.001, -0.0005, 0.0],
                         width=width, height=height)


def make_scene(model, camera, rng, spp: int):
    """The renderer: the model's shapes, a sun, some ambient light, the depth sensor and the
    textures the worlds draw from."""
    import warprt
    from warprt.newton_bridge import NewtonRenderer

    sun = warprt.DirectionalLight(direction=(-0.4, 0.3, -1.0), intensity=1.0)
    return NewtonRenderer(model, cameras=1, camera=camera, lights=(sun,), ambient=0.12,
                          background=(0.6, 0.7, 0.85), render=warprt.RenderSettings(spp=spp, sampler="sobol"),
                          depth_sensor=warprt.DepthSensor(**SENSOR), textures=make_textures(rng))


def randomise_worlds(renderer, rng) -> None:
    """New looks for every world: each shape's colour (sRGB drawn, linear given) and texture (or
    none; the ground keeps its grey and no texture), the sun's intensity and direction, and the
    camera's pose (jittered about HEAD, levelled with the model's up axis)."""
    import warprt

    W, S = renderer.batch.worlds, len(renderer.scene.shapes)
    colours = warprt.srgb_to_linear(rng.uniform(0.1, 0.95, size=(W, S, 3)))
    textures = rng.integers(-1, len(renderer.textures), size=(W, S))
    ground = renderer.shape_map.newton_shape[0] == 0  # Newton's shape 0, in every world
    colours[:, ground] = 0.2
    textures[:, ground] = -1
    renderer.set_shape_colors(colours)
    renderer.set_shape_textures(textures)
    renderer.set_light_intensities(rng.uniform(0.6, 1.4, size=(W, 1, 1)) * np.ones((1, 1, 3)))
    sun = np.column_stack([rng.uniform(-0.6, 0.6, W), rng.uniform(-0.6, 0.6, W), -np.ones(W)])
    renderer.batch.light_positions.assign(sun[:, None, :].astype(np.float32))  # (W, 1): the direction of travel
    eyes = np.asarray(HEAD) + rng.normal(scale=(0.08, 0.08, 0.05), size=(W, 3))
    targets = np.asarray(TARGET) + rng.normal(scale=0.03, size=(W, 3))
    renderer.set_camera_poses(warprt.look_at(eyes, targets, renderer.up_axis)[:, None, :])


def depth_preview(z: np.ndarray, far: float) -> np.ndarray:
    """A grey image of a depth map: near bright, far dark, no value (NaN) black."""
    import warprt

    v = np.where(np.isfinite(z), 1.0 - np.clip(z / far, 0.0, 1.0), 0.0).astype(np.float32)
    return warprt.srgb_to_linear(np.repeat(v[..., None], 3, axis=-1))  # (saved as sRGB: a linear ramp on screen)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("out_dir", nargs="?", default=os.path.join("out", "robot"))
    ap.add_argument("--width", type=int, default=128)
    ap.add_argument("--height", type=int, default=96)
    ap.add_argument("--spp", type=int, default=4)
    ap.add_argument("--steps", type=int, default=6, help="frames per episode (each 1/10 s of simulation)")
    ap.add_argument("--worlds", type=int, default=4)
    ap.add_argument("--episodes", type=int, default=2, help="looks drawn (colours, textures, lights and cameras randomised)")
    ap.add_argument("--seed", type=int, default=0, help="the randomisation's and the noise's seed")
    args = ap.parse_args(argv)
    try:
        import newton
    except ImportError:
        print("this example needs Newton: pip install 'warprt[newton]'", file=sys.stderr)
        return 2
    import warprt

    rng = np.random.default_rng(args.seed)
    model = build_model(args.worlds, rng)
    camera = make_camera(args.width, args.height)
    solver = newton.solvers.SolverXPBD(model, iterations=8)
    pipeline = newton.CollisionPipeline(model, soft_contact_max=0)
    contacts = pipeline.contacts()
    substeps, dt = 8, 1.0 / 10.0 / 8
    os.makedirs(args.out_dir, exist_ok=True)
    valid = []
    renderer = make_scene(model, camera, rng, args.spp)
    first = None
    for episode in range(args.episodes):
        randomise_worlds(renderer, rng)
        s0, s1, control = model.state(), model.state(), model.control()
        for step in range(args.steps):
            pipeline.collide(s0, contacts)
            for _ in range(substeps):
                s0.clear_forces()
                solver.step(s0, s1, control, contacts, dt)
                s0, s1 = s1, s0
            renderer.update(s0)
            seed = args.seed + episode * args.steps + step  # new noise every frame, reproducible
            out = renderer.render(seed=seed, aovs=["z", "sensor_z"])
            if first is None:
                first = dict(renderer.counters)
            for w in range(args.worlds):
                frame = out.frame(w, 0)  # numpy copies: colour, z, sensor_z and the camera's matrices
                name = os.path.join(args.out_dir, f"e{episode}_w{w}_{step:03d}")
                warprt.save_image(frame, name + ".exr")
                warprt.save_image(frame.image, name + ".png")
                warprt.save_image(depth_preview(frame.aovs["sensor_z"], SENSOR["max_range"]), name + "_depth.png")
                valid.append(float(np.isfinite(frame.aovs["sensor_z"]).mean()))
    renderer.batch.close()
    print(f"{args.episodes} episodes x {args.worlds} worlds x {args.steps} steps at {args.width}x{args.height}, "
          f"{args.spp} spp; depth sensor: {np.mean(valid):.0%} of the pixels valid")
    print(f"counters after the first frame {first} after the last {renderer.counters}")
    print(f"wrote {args.out_dir}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
