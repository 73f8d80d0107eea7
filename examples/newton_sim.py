"""Step a small Newton simulation and render every world with warprt each step: soft shadows from a
rectangle light, depth of field and motion blur in the synthetic data, poses straight from the
simulation's device arrays.

    pip install 'warprt[newton]'
    python examples/newton_sim.py                       # 4 worlds x 2 cameras, 160x120, 24 steps, into out/newton/
    python examples/newton_sim.py results --width 48 --height 32 --spp 2 --steps 3

Each world drops the same boxes and spheres from other heights onto a ground plane (Newton's
XPBD solver); frame f of world w through camera c is written as
``OUT/w{w}_c{c}_{f:04d}.png``. The loop copies nothing between host and device until the frame
is written: ``update(state)`` launches one kernel from ``state.body_q`` into the renderer's pose
array, and the counters printed at the end show no rebuild, recompile or host copy per step.
"""

from __future__ import annotations

import argparse
import os
import sys

import numpy as np


def build_model(worlds: int):
    import newton
    import warp as wp

    builder = newton.ModelBuilder()  # z up
    builder.add_ground_plane(color=(0.75, 0.75, 0.7))
    for w in range(worlds):
        builder.begin_world()
        for k in range(3):
            # (the axis normalised: quat_from_axis_angle does not, and a longer axis scales the box)
            tilt = wp.quat_from_axis_angle(wp.normalize(wp.vec3(1.0, 1.0, 0.0)), 0.4 * k)
            body = builder.add_body(xform=wp.transform((0.5 * k - 0.5, 0.2 * k, 0.8 + 0.3 * k + 0.25 * w), tilt))
            builder.add_shape_box(body, hx=0.15, hy=0.15, hz=0.15, color=(0.9, 0.35 + 0.2 * k, 0.2))
        body = builder.add_body(xform=wp.transform((0.2, -0.6, 1.5 + 0.2 * w), wp.quat_identity()))
        builder.add_shape_sphere(body, radius=0.2, color=(0.2, 0.45, 0.9))
        builder.end_world()
    return builder.finalize(device="cpu")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("out_dir", nargs="?", default=os.path.join("out", "newton"))
    ap.add_argument("--width", type=int, default=160)
    ap.add_argument("--height", type=int, default=120)
    ap.add_argument("--spp", type=int, default=16)
    ap.add_argument("--steps", type=int, default=24, help="frames (each 1/24 s of simulation)")
    ap.add_argument("--worlds", type=int, default=4)
    args = ap.parse_args(argv)
    try:
        import newton
    except ImportError:
        print("this example needs Newton: pip install 'warprt[newton]'", file=sys.stderr)
        return 2
    import warprt
    from warprt.newton_bridge import NewtonRenderer, look_at_pose

    model = build_model(args.worlds)
    camera = warprt.Camera(eye=(3, -3, 2), look_at=(0, 0, 0.3), up=(0, 0, 1), fov=40, width=args.width,
                           height=args.height, aperture=0.03, focus_distance=4.3, shutter=(0.0, 1.0))
    light = warprt.RectLight(corner=(-0.5, -0.5, 3.0), edge1=(0, 1, 0), edge2=(1, 0, 0), radiance=6.0, samples=1)
    renderer = NewtonRenderer(model, cameras=2, camera=camera, lights=(light,), ambient=0.05,
                              background=(0.55, 0.65, 0.8), motion_blur=True,
                              render=warprt.RenderSettings(spp=args.spp, sampler="sobol"))
    poses = np.array([[look_at_pose((3, -3, 2), (0, 0, 0.3)), look_at_pose((-2.5, -3.5, 1.2), (0, 0, 0.4))]] * args.worlds)
    renderer.set_camera_poses(poses)

    solver = newton.solvers.SolverXPBD(model, iterations=10)
    pipeline = newton.CollisionPipeline(model, soft_contact_max=0)
    contacts = pipeline.contacts()
    s0, s1, control = model.state(), model.state(), model.control()
    substeps = 10
    dt = 1.0 / 24.0 / substeps
    os.makedirs(args.out_dir, exist_ok=True)
    renderer.update(s0)
    first = None
    for frame in range(args.steps):
        pipeline.collide(s0, contacts)
        for _ in range(substeps):  # one frame of simulation
            s0.clear_forces()
            solver.step(s0, s1, control, contacts, dt)
            s0, s1 = s1, s0
        renderer.update(s0)  # the previous pose opens the shutter, this one closes it
        out = renderer.render(seed=frame)
        if first is None:
            first = dict(renderer.counters)
        images = out.numpy()  # the one host copy per frame: the images to write
        for w in range(images.shape[0]):
            for c in range(images.shape[1]):
                warprt.save_image(images[w, c], os.path.join(args.out_dir, f"w{w}_c{c}_{frame:04d}.png"))
    print(f"{args.steps} frames of {args.worlds} worlds x 2 cameras at {args.width}x{args.height}, {args.spp} spp")
    print(f"counters after the first frame {first} after the last {renderer.counters}")
    print(f"wrote {args.out_dir}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
