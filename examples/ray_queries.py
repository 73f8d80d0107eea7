"""warprt as a ray caster: a depth camera and a spinning lidar, with camera_rays and trace_rays.

No shading happens here: ``camera_rays`` gives the rays the renderer would shoot through the
pixel centres, ``trace_rays`` the nearest hit of any batch of rays (distance, point, normal, which
shape). Two sensors look at a scene (by default scenes/showcase.toml):

* a depth camera with the scene's own camera (``--spp`` rays per pixel, depth averaged over the
  returns): writes ``depth.png`` (8-bit grey, inverse depth normalised: near is white, far is
  dark grey, no return is black) and ``depth.exr`` (float32 planar depth in scene units, 0 where
  nothing was hit);
* a 360-degree lidar with ``--height`` beams and ``--width`` azimuth steps: writes
  ``lidar.png``, its range image normalised the same way, and ``lidar_points.npy``, the point
  cloud (N, 3) of its returns.

    python examples/ray_queries.py                       # 320x240, into out/
    python examples/ray_queries.py results --width 64 --height 48 --spp 2

The query kernels form one Warp module, compiled on first use (a few seconds) and cached on disk.
"""

from __future__ import annotations

import argparse
import math
import os
from pathlib import Path

import numpy as np
from PIL import Image

import warprt

ROOT = Path(__file__).resolve().parents[1]


def normalised_grey(values: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """8-bit grey image of distances: inverse distance normalised over the valid pixels, so that
    the nearest is white (255) and the farthest dark grey (32); invalid pixels are black."""
    out = np.zeros(values.shape, np.uint8)
    if valid.any():
        inv = 1.0 / np.maximum(values[valid], 1e-12)
        lo, hi = float(inv.min()), float(inv.max())
        x = (inv - lo) / (hi - lo) if hi > lo else np.ones_like(inv)
        out[valid] = np.round(32.0 + 223.0 * x).astype(np.uint8)
    return out


def lidar_directions(beams: int, steps: int, elevation=(-25.0, 15.0)) -> np.ndarray:
    """Unit directions (beams, steps, 3): rows from the highest beam down, columns a full turn
    about +y starting behind the sensor, so the middle column looks along -z."""
    el = np.radians(np.linspace(elevation[1], elevation[0], beams))[:, None]
    az = (np.arange(steps) + 0.5) / steps * 2.0 * math.pi - math.pi
    az = az[None, :]
    return np.stack(np.broadcast_arrays(np.sin(az) * np.cos(el), np.sin(el) + 0 * az, -np.cos(az) * np.cos(el)),
                    axis=-1)


def describe(scene: warprt.Scene, hits: dict, label: str) -> None:
    hit = hits["hit"]
    print(f"{label}: {hit.size} rays, {int(hit.sum())} returns ({100.0 * hit.mean():.1f}%)", end="")
    if hit.any():
        print(f", range {hits['t'][hit].min():.3f} .. {hits['t'][hit].max():.3f}")
    else:
        print()
    kinds: dict[str, int] = {}
    for index in hits["shape"][hit]:
        name = type(scene.shapes[index]).__name__ if index >= 0 else "area light"
        kinds[name] = kinds.get(name, 0) + 1
    print("  returns by shape type: " + ", ".join(f"{k} {v}" for k, v in sorted(kinds.items())))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out_dir", nargs="?", default="out", help="folder for the outputs (default out/)")
    parser.add_argument("--scene", default=str(ROOT / "scenes" / "showcase.toml"), help="TOML scene file")
    parser.add_argument("--width", type=int, default=320, help="depth image width = lidar azimuth steps")
    parser.add_argument("--height", type=int, default=240, help="depth image height = lidar beams")
    parser.add_argument("--spp", type=int, default=1, help="depth samples per pixel (1: the pixel centre)")
    parser.add_argument("--max-range", type=float, default=20.0, help="farthest return, scene units")
    parser.add_argument("--sensor", type=float, nargs=3, default=(0.0, 1.2, 3.2), help="lidar position x y z")
    args = parser.parse_args(argv)
    os.makedirs(args.out_dir, exist_ok=True)

    scene = warprt.load_scene(args.scene).with_camera(width=args.width, height=args.height)
    # A Renderer holds the scene's device tables: passing it to trace_rays avoids rebuilding them.
    renderer = warprt.Renderer(scene)

    # --- depth camera: rays through raster points (x right, y down from the top-left corner)
    h, w_px, n = args.height, args.width, max(args.spp, 1)
    if n == 1:
        origins, directions = warprt.camera_rays(scene)  # pixel centres, row-major
    else:  # n points per pixel on a rank-1 lattice; depth is averaged over the returns (mixed pixels)
        k = np.arange(n)
        offsets = np.stack([(k + 0.5) / n, np.mod(0.5 + k * 0.6180339887, 1.0)], axis=1)
        jj, ii = np.mgrid[0:h, 0:w_px]
        points = (np.stack([ii.ravel(), jj.ravel()], axis=1)[:, None, :] + offsets[None]).reshape(-1, 2)
        origins, directions = warprt.camera_rays(scene, points)
    hits = warprt.trace_rays(renderer, origins, directions, t_max=args.max_range)
    describe(scene, hits, "depth camera")
    _, _, w = scene.camera.basis()  # the camera looks along -w
    z = np.where(hits["hit"], hits["t"] * (directions @ -w), 0.0).reshape(h, w_px, n)
    count = hits["hit"].reshape(h, w_px, n).sum(axis=2)
    hit = count > 0
    # no return: inf, warprt's one miss value (trace_rays' t, AOV depth and z)
    depth = np.where(hit, z.sum(axis=2) / np.maximum(count, 1), np.inf)
    Image.fromarray(normalised_grey(depth, hit)).save(os.path.join(args.out_dir, "depth.png"))
    warprt.save_image(depth.astype(np.float32), os.path.join(args.out_dir, "depth.exr"),
                      metadata={"depth": "planar, scene units; inf = no return"})

    # --- spinning lidar: arbitrary rays from one point
    dirs = lidar_directions(args.height, args.width).reshape(-1, 3)
    sensor = np.broadcast_to(np.asarray(args.sensor, np.float32), dirs.shape)
    scan = warprt.trace_rays(renderer, sensor, dirs, t_max=args.max_range)
    describe(scene, scan, "lidar")
    returns = scan["hit"]
    grazing = np.abs(np.sum(scan["normal"][returns] * dirs[returns], axis=1))  # |cos| of incidence
    if returns.any():
        print(f"  mean |cos incidence| {grazing.mean():.3f}")
    rng = np.where(returns, scan["t"], np.inf).reshape(args.height, args.width)
    Image.fromarray(normalised_grey(rng, returns.reshape(rng.shape))).save(os.path.join(args.out_dir, "lidar.png"))
    np.save(os.path.join(args.out_dir, "lidar_points.npy"), scan["position"][returns])

    for name in ("depth.png", "depth.exr", "lidar.png", "lidar_points.npy"):
        print(f"wrote {os.path.join(args.out_dir, name)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
