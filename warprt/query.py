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
from .scene.values import FLT_MAX
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


def _rows(values, name: str, columns: int, what: str) -> np.ndarray:
    """``values`` as an (N, columns) float32 array of finite numbers within float32's range
    (one row may be given alone), else a RenderError naming ``name``."""
    if isinstance(values, (str, bytes)) or values is None or isinstance(values, wp.array):
        raise RenderError(f"{name}: expected {what} shaped (N, {columns}) (numpy or a list), got {values!r:.60}")
    try:
        a = np.asarray(values, dtype=np.float64)
    except (TypeError, ValueError):
        raise RenderError(f"{name}: expected numbers shaped (N, {columns}) ({what}), got {type(values).__name__}") \
            from None
    if a.ndim == 1 and a.shape[0] == columns:
        a = a[None]
    if a.ndim != 2 or a.shape[1] != columns:
        raise RenderError(f"{name}: expected {what} shaped (N, {columns}), got shape {a.shape}")
    bad = ~np.isfinite(a).all(axis=1) | (np.abs(np.nan_to_num(a)) > FLT_MAX).any(axis=1)
    if bad.any():
        i = int(np.argmax(bad))
        raise RenderError(f"{name}[{i}]: {tuple(float(x) for x in a[i])} is not finite in float32")
    return a.astype(np.float32)


def _number(value, name: str, *, minimum: float | None = None, infinite: bool = False) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise RenderError(f"{name} must be a number, got {value!r:.60}")
    value = float(value)
    if np.isnan(value) or (np.isinf(value) and not (infinite and value > 0)):
        raise RenderError(f"{name} must be finite, got {value}")
    if minimum is not None and value < minimum:
        raise RenderError(f"{name} must be >= {minimum:g}, got {value:g}")
    return value


def _integer(value, name: str, minimum: int, maximum: int | None = None) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < minimum or (
            maximum is not None and value > maximum):
        bounds = f"from {minimum}" + (f" to {maximum}" if maximum is not None else "")
        raise RenderError(f"{name} must be an integer {bounds}, got {value!r:.60}")
    return int(value)


def _built(scene, device) -> DeviceScene:
    """A built scene: a Scene is built on ``device``; a Renderer (anything holding a built
    scene as ``.built``) lends its own."""
    built = getattr(scene, "built", None)
    if isinstance(built, DeviceScene):
        return built
    if not isinstance(scene, Scene):
        raise RenderError(f"trace_rays expects a warprt.Scene or Renderer, got {type(scene).__name__}")
    return DeviceScene(scene, _warp.resolve_device(device))


def camera_rays(scene: Scene, points=None, lens=None, time: float = 0.0, device: str | None = None):
    """Camera rays (origins, unit directions), each (N, 3) float32 numpy.

    ``points`` are raster positions (N, 2) in pixels, x right and y down from the top-left corner;
    by default every pixel centre in row-major order (pixel (i, j) at (i + 0.5, j + 0.5); OpenCV's
    pixel (i, j) is raster point (i + 0.5, j + 0.5) too). ``lens`` are (N, 2) lens samples in
    [0, 1)^2 (ignored by a pinhole camera). Every camera model gives its rays (the orthographic
    one from points on the plane through the eye); a raster point the model has no ray for (beyond
    a distortion's monotonic range, see ``warprt.camera``) gets the direction (0, 0, 0).
    """
    _warp.init()
    if not isinstance(scene, Scene):
        scene = getattr(scene, "scene", None) if isinstance(getattr(scene, "built", None), DeviceScene) else scene
        if not isinstance(scene, Scene):
            raise RenderError(f"camera_rays expects a warprt.Scene or Renderer, got {type(scene).__name__}")
    dev = _warp.resolve_device(device)
    cam = scene.camera
    time = _number(time, "time")
    if points is None:
        jj, ii = np.mgrid[0:cam.height, 0:cam.width]
        points = np.stack([ii.ravel() + 0.5, jj.ravel() + 0.5], axis=1)
    points = _rows(points, "points", 2, "raster points (x, y) in pixels")
    n = len(points)
    if lens is None:
        lens = np.full((n, 2), 0.5, np.float32)
    else:
        lens = _rows(lens, "lens", 2, "lens samples in [0, 1)^2")
        if len(lens) != n:
            raise RenderError(f"lens: {len(lens)} samples for {n} points")
        if (lens < 0).any() or (lens > 1).any():
            i = int(np.argmax(((lens < 0) | (lens > 1)).any(axis=1)))
            raise RenderError(f"lens[{i}]: {tuple(float(x) for x in lens[i])} is outside [0, 1]^2")
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
    t_min = _number(t_min, "t_min", minimum=0.0)
    t_max = _number(t_max, "t_max", infinite=True)
    if not t_max > t_min:
        raise RenderError(f"t_max ({t_max:g}) must exceed t_min ({t_min:g})")
    time = _number(time, "time")
    o = _rows(origins, "origins", 3, "ray origins (x, y, z)")
    d = _rows(directions, "directions", 3, "ray directions (x, y, z)")
    if o.shape != d.shape:
        raise RenderError(f"origins and directions differ in shape: {o.shape} vs {d.shape}")
    zero = np.einsum("ij,ij->i", d.astype(np.float64), d.astype(np.float64)) < np.finfo(np.float32).tiny
    if zero.any():
        raise RenderError(f"directions[{int(np.argmax(zero))}]: every direction must be non-zero (and its squared "
                          "length a normal float32)")
    built = _built(scene, device)
    dev = built.device
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
    from .render import check_seed
    from .scene.description import SPP_LIMIT

    if not isinstance(sampler, str) or sampler not in SAMPLER_IDS:
        raise RenderError(f"unknown sampler {sampler!r}; expected one of {', '.join(SAMPLER_IDS)}")
    spp = _integer(spp, "spp", 1, SPP_LIMIT)
    dim = _integer(dim, "dim", 0, (1 << 32) - 1)
    check_seed(seed)
    count = spp if count is None else _integer(count, "count", 1)
    dev = _warp.resolve_device(device)
    if isinstance(pixels, (str, bytes)) or pixels is None:
        raise RenderError(f"pixels: expected pixel indices (integers), got {pixels!r:.60}")
    try:
        pix = np.atleast_1d(np.asarray(pixels))
    except (TypeError, ValueError):
        raise RenderError(f"pixels: expected pixel indices (integers), got {type(pixels).__name__}") from None
    if pix.ndim != 1 or (pix.size and not np.issubdtype(pix.dtype, np.integer)):
        raise RenderError(f"pixels: expected a 1-D list of integer pixel indices, got {pix.dtype} {pix.shape}")
    if pix.size and (pix.min() < 0 or pix.max() > np.iinfo(np.int32).max):
        raise RenderError(f"pixels: indices must be in [0, 2^31 - 1], found {int(pix.min())}..{int(pix.max())}")
    pix = pix.astype(np.int32)
    out = wp.zeros((len(pix), count), dtype=dtype, device=dev)
    wp.launch(_query_kernels()[kernel], dim=(len(pix), count), device=dev,
              inputs=[SAMPLER_IDS[sampler], wp.uint32(seed & 0xFFFFFFFF), wp.array(pix, dtype=int, device=dev),
                      int(spp), wp.uint32(dim & 0xFFFFFFFF), out])
    return out.numpy()
