"""Ray queries outside rendering: camera rays and nearest hits for arbitrary rays.

``camera_rays(scene)`` returns the rays the renderer shoots through pixel centres (or any raster
points), and ``trace_rays(scene, origins, directions)`` the nearest hit of each ray, with the
shape it belongs to. Both run on the device with the same device functions as the render kernel,
so tests can check the renderer's geometry against closed forms, and pipelines can use warprt as
a ray caster (lidar-like sensors, picking).

The query kernels live in one Warp module of their own (``warprt_query``), built for every
feature (compiled once per process when first used, then loaded from Warp's cache).
"""

from __future__ import annotations

import numpy as np
import warp as wp

from . import _warp
from ._warp import build_once
from .build import DeviceScene
from .camera import camera_data, camera_ray
from .errors import RenderError
from .records import KIND_NONE, CameraData, Features, SceneData
from .sampling import SAMPLER_IDS, sample_1d, sample_2d
from .scene.description import Scene
from .trace import make_trace


@build_once
def _query_kernels() -> dict:
    closest_hit = make_trace(Features.full()).closest_hit

    @wp.kernel(module="warprt_query", enable_backward=False)
    def camera_kernel(cam: CameraData, fx: wp.array(dtype=float), fy: wp.array(dtype=float),
                      lens: wp.array(dtype=wp.vec2), time: float,
                      origins: wp.array(dtype=wp.vec3), dirs: wp.array(dtype=wp.vec3)):
        i = wp.tid()
        r = camera_ray(cam, fx[i], fy[i], lens[i], time)
        origins[i] = r.o
        dirs[i] = r.d

    @wp.kernel(module="warprt_query", enable_backward=False)
    def trace_kernel(scene: SceneData, origins: wp.array(dtype=wp.vec3), dirs: wp.array(dtype=wp.vec3),
                     t_min: float, t_max: float, time: float,
                     out_t: wp.array(dtype=float), out_p: wp.array(dtype=wp.vec3),
                     out_n: wp.array(dtype=wp.vec3), out_ns: wp.array(dtype=wp.vec3),
                     out_kind: wp.array(dtype=int), out_index: wp.array(dtype=int)):
        i = wp.tid()
        d = dirs[i]
        h = closest_hit(scene, origins[i], wp.normalize(d), t_min, t_max, time)
        out_t[i] = h.t
        out_kind[i] = h.kind
        out_index[i] = h.index
        if h.kind != KIND_NONE:
            out_p[i] = h.p
            out_n[i] = h.ng
            out_ns[i] = h.ns

    @wp.kernel(module="warprt_query", enable_backward=False)
    def samples_kernel(sampler: int, seed: wp.uint32, pixels: wp.array(dtype=int), spp: int,
                       dim: wp.uint32, out: wp.array2d(dtype=wp.vec2)):
        i, s = wp.tid()
        out[i, s] = sample_2d(sampler, seed, pixels[i], s, spp, dim)

    @wp.kernel(module="warprt_query", enable_backward=False)
    def samples_1d_kernel(sampler: int, seed: wp.uint32, pixels: wp.array(dtype=int), spp: int,
                          dim: wp.uint32, out: wp.array2d(dtype=float)):
        i, s = wp.tid()
        out[i, s] = sample_1d(sampler, seed, pixels[i], s, spp, dim)

    return {"camera": camera_kernel, "trace": trace_kernel, "samples": samples_kernel, "samples_1d": samples_1d_kernel}


def _built(scene, device) -> DeviceScene:
    """A built scene: a Scene is built on ``device``; a Renderer (anything holding a built
    scene as ``.built``) lends its own."""
    built = getattr(scene, "built", None)
    if isinstance(built, DeviceScene):
        return built
    if not isinstance(scene, Scene):
        raise RenderError(f"expected a warprt.Scene or Renderer, got {type(scene).__name__}")
    return DeviceScene(scene, _warp.resolve_device(device))


def camera_rays(scene: Scene, points=None, lens=None, time: float = 0.0, device: str | None = None):
    """Camera rays (origins, unit directions), each (N, 3) float32 numpy.

    ``points`` are raster positions (N, 2) in pixels, x right and y down from the top-left corner;
    by default every pixel centre in row-major order (pixel (i, j) at (i + 0.5, j + 0.5)).
    ``lens`` are (N, 2) lens samples in [0, 1)^2 (ignored by a pinhole camera).
    """
    _warp.init()
    dev = _warp.resolve_device(device)
    cam = scene.camera
    if points is None:
        jj, ii = np.mgrid[0:cam.height, 0:cam.width]
        points = np.stack([ii.ravel() + 0.5, jj.ravel() + 0.5], axis=1)
    points = np.asarray(points, dtype=np.float32).reshape(-1, 2)
    n = len(points)
    lens = np.full((n, 2), 0.5, np.float32) if lens is None else np.asarray(lens, np.float32).reshape(n, 2)
    camera_kernel = _query_kernels()["camera"]
    origins = wp.zeros(n, dtype=wp.vec3, device=dev)
    dirs = wp.zeros(n, dtype=wp.vec3, device=dev)
    wp.launch(camera_kernel, dim=n, device=dev,
              inputs=[camera_data(scene), wp.array(points[:, 0].copy(), dtype=float, device=dev),
                      wp.array(points[:, 1].copy(), dtype=float, device=dev), wp.array(lens, dtype=wp.vec2, device=dev),
                      float(time), origins, dirs])
    return origins.numpy(), dirs.numpy()


def trace_rays(scene, origins, directions, t_min: float = 0.0, t_max: float = np.inf, time: float = 0.0,
               device: str | None = None) -> dict[str, np.ndarray]:
    """Nearest hit of each ray (directions need not be unit: they are normalised, so t is a distance).

    Returns a dict of numpy arrays: ``hit`` (bool), ``t`` (inf for a miss), ``position``,
    ``normal`` (unit geometric normal as the shape defines it, not turned to the ray),
    ``shading_normal``, and ``shape`` (index into ``scene.shapes``; -1 for a miss or an area
    light's own surface).
    """
    _warp.init()
    built = _built(scene, device)
    dev = built.device
    o = np.asarray(origins, dtype=np.float32).reshape(-1, 3)
    d = np.asarray(directions, dtype=np.float32).reshape(-1, 3)
    if o.shape != d.shape:
        raise RenderError(f"origins and directions differ in shape: {o.shape} vs {d.shape}")
    if not (np.isfinite(o).all() and np.isfinite(d).all()):
        raise RenderError("origins and directions must be finite")
    if (np.linalg.norm(d, axis=1) == 0).any():
        raise RenderError("every direction must be non-zero")
    n = len(o)
    trace_kernel = _query_kernels()["trace"]
    out = [wp.zeros(n, dtype=t, device=dev) for t in (float, wp.vec3, wp.vec3, wp.vec3, int, int)]
    wp.launch(trace_kernel, dim=n, device=dev,
              inputs=[built.data, wp.array(o, dtype=wp.vec3, device=dev), wp.array(d, dtype=wp.vec3, device=dev),
                      float(t_min), float(min(t_max, 3.0e38)), float(time), *out])
    t, p, ng, ns, kind, index = (a.numpy() for a in out)
    hit = kind != KIND_NONE
    lookup = {ki: i for i, ki in enumerate(built.shape_ids)}
    shape = np.array([lookup.get((int(k), int(j)), -1) if h else -1 for k, j, h in zip(kind, index, hit)],
                     dtype=np.int64)
    return {"hit": hit, "t": np.where(hit, t, np.inf).astype(np.float32), "position": p, "normal": ng,
            "shading_normal": ns, "shape": shape}


def pixel_samples(sampler: str, pixels, spp: int, dim: int = 0, seed: int = 0, count: int | None = None,
                  device: str | None = None) -> np.ndarray:
    """The 2D samples a sampler gives: array (len(pixels), count, 2) in [0, 1)^2.

    ``dim`` is the dimension key (0 film, 1 lens; other keys are light and lobe samples; time
    is a 1D dimension: see :func:`pixel_samples_1d`), ``spp`` the planned samples per pixel,
    ``count`` how many to draw (default ``spp``).
    """
    return _pixel_samples("samples", wp.vec2, sampler, pixels, spp, dim, seed, count, device)


def pixel_samples_1d(sampler: str, pixels, spp: int, dim: int = 2, seed: int = 0, count: int | None = None,
                     device: str | None = None) -> np.ndarray:
    """The 1D samples a sampler gives: array (len(pixels), count) in [0, 1]. The renderer draws
    the shutter time (``dim`` 2) this way: ``regular`` and ``stratified`` put one sample in each
    of spp equal strata (a 2D grid's first coordinate would fill only nx of them)."""
    return _pixel_samples("samples_1d", float, sampler, pixels, spp, dim, seed, count, device)


def _pixel_samples(kernel, dtype, sampler, pixels, spp, dim, seed, count, device) -> np.ndarray:
    if sampler not in SAMPLER_IDS:
        raise RenderError(f"unknown sampler {sampler!r}; expected one of {', '.join(SAMPLER_IDS)}")
    dev = _warp.resolve_device(device)
    pix = np.atleast_1d(np.asarray(pixels, dtype=np.int32))
    count = spp if count is None else count
    out = wp.zeros((len(pix), count), dtype=dtype, device=dev)
    wp.launch(_query_kernels()[kernel], dim=(len(pix), count), device=dev,
              inputs=[SAMPLER_IDS[sampler], wp.uint32(seed & 0xFFFFFFFF), wp.array(pix, dtype=int, device=dev),
                      int(spp), wp.uint32(dim & 0xFFFFFFFF), out])
    return out.numpy()
