"""Build a scene in Python (no scene file), render it and write a PNG and an EXR.

The scene uses every kind of object the Python API offers for a still image: analytic spheres, a
triangle mesh given as inline numpy arrays, a ground plane, diffuse/specular, mirror and glass
materials, a point light and a rectangular area light (soft shadows).

    python examples/build_scene.py                 # 320x240, 16 spp, into out/
    python examples/build_scene.py results --width 64 --height 48 --spp 1

The first run compiles the render kernel for this scene's features (a few seconds of CPU; Warp
caches it on disk, see WARP_CACHE_PATH); later runs load it from the cache.
"""

from __future__ import annotations

import argparse
import os

import numpy as np

import warprt


def pyramid(base: float = 1.0, height: float = 1.2) -> tuple[np.ndarray, np.ndarray]:
    """A square pyramid standing on y = 0: 5 vertices, 6 triangles wound counter-clockwise seen
    from outside (so the geometric normals point out)."""
    h = base / 2.0
    vertices = np.array([
        [-h, 0.0, -h], [h, 0.0, -h], [h, 0.0, h], [-h, 0.0, h],  # base corners
        [0.0, height, 0.0],  # apex
    ])
    faces = np.array([
        [0, 1, 2], [0, 2, 3],  # base, facing down
        [3, 2, 4], [2, 1, 4], [1, 0, 4], [0, 3, 4],  # sides
    ])
    return vertices, faces


def make_scene(width: int, height: int, spp: int) -> warprt.Scene:
    vertices, faces = pyramid()
    materials = {
        "floor": warprt.Material(kd=(0.7, 0.68, 0.64), mirror=0.05),
        "red": warprt.Material(kd=(0.8, 0.15, 0.1), ks=0.5, p=60),
        "mirror": warprt.Material(kd=0.02, mirror=0.9),
        "glass": warprt.Material(kd=0.0, ka=0.0, transparency=1.0, ior=1.5, fresnel="schlick"),
        "teal": warprt.Material(kd=(0.1, 0.55, 0.5), ks=0.3, p=30),
    }
    shapes = (
        warprt.Plane(point=(0, 0, 0), normal=(0, 1, 0), material="floor"),
        warprt.Sphere(center=(-1.3, 0.5, 0.0), radius=0.5, material="red"),
        warprt.Sphere(center=(1.3, 0.6, -0.6), radius=0.6, material="mirror"),
        warprt.Sphere(center=(0.1, 0.45, 1.0), radius=0.45, material="glass"),
        warprt.Mesh(vertices=vertices, faces=faces, material="teal",
                    transform=warprt.Transform(translate=(-0.1, 0.0, -1.2), rotate=(0, 30, 0), scale=1.1)),
    )
    lights = (
        warprt.PointLight(position=(-3.0, 5.0, 4.0), intensity=0.5),
        # one-sided: edge1 x edge2 = (1,0,0) x (0,0,1) points down (-y), onto the scene
        warprt.RectLight(corner=(-0.75, 3.5, -0.75), edge1=(1.5, 0, 0), edge2=(0, 0, 1.5), radiance=1.5, samples=2),
    )
    return warprt.Scene(
        camera=warprt.Camera(eye=(0.0, 1.8, 5.5), look_at=(0.0, 0.5, 0.0), fov=40, width=width, height=height),
        shapes=shapes,
        materials=materials,
        lights=lights,
        ambient=0.05,
        background=(0.5, 0.65, 0.9),
        render=warprt.RenderSettings(spp=spp, sampler="stratified", max_depth=5),
    )


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out_dir", nargs="?", default="out", help="folder for the images (default out/)")
    parser.add_argument("--width", type=int, default=320)
    parser.add_argument("--height", type=int, default=240)
    parser.add_argument("--spp", type=int, default=16, help="samples per pixel")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)

    scene = make_scene(args.width, args.height, args.spp)
    renderer = warprt.Renderer(scene)  # builds the device tables and picks the specialised kernel
    print(f"kernel features: {renderer.features.key}")
    print(f"kernel load/compile: {renderer.compile():.2f} s")
    result = renderer.render(seed=args.seed, progress=False)  # spp from scene.render.spp

    h, w = result.image.shape[:2]
    print(f"image: {w}x{h}, {result.spp} spp on {result.device}{' (interrupted)' if result.interrupted else ''}")
    print(f"render time: {result.wall_time:.3f} s")
    print(f"rays: {result.rays} ({result.mrays_per_s:.2f} Mrays/s)")
    print(f"stack overflows: {result.stack_overflows}")
    mean = result.image.reshape(-1, 3).mean(axis=0)
    print(f"mean radiance (linear RGB): {mean[0]:.4f} {mean[1]:.4f} {mean[2]:.4f}")

    os.makedirs(args.out_dir, exist_ok=True)
    for name in ("build_scene.png", "build_scene.exr"):
        path = os.path.join(args.out_dir, name)
        warprt.save_image(result, path)  # with its metadata: spp, seed, the camera's matrices
        print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
