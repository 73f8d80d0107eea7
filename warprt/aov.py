"""Arbitrary output variables (AOVs): per-pixel geometry next to the colour, from the same samples.

Each AOV is averaged over the very camera samples that made the pixel's colour (as pbrt-v4's
G-buffer film does): the AOV kernel regenerates each sample's camera ray from the same sampler,
seed and dimensions (film position, lens point, time), so AOVs are antialiased, defocused and
motion-blurred exactly like the colour. With adaptive sampling a pixel's AOVs use its own count;
an interrupted render's AOVs use the samples it finished.

Rules, in one place:

* **coverage** is the fraction of the samples that hit a surface (the alpha of the pixel).
* **geometric AOVs** (depth, z, normal, albedo, position, motion) are the mean over the samples
  that hit; the normal is that mean renormalised. A pixel no sample hits gets the **miss value**:
  depth and z ``inf`` (the same as ``trace_rays``' ``t``), vectors 0, ids -1.
* **ids** (object_id, material) stay exact integers: the id seen by the most samples among the
  first four distinct ids of the pixel, ties going to the one seen first (a pixel straddling
  five objects is rare; the fifth and later are not counted). Misses do not vote: a pixel whose
  samples hit anything at all has that thing's id, coverage says how much of it.

========= ======= =====================================================================
name      shape   meaning
========= ======= =====================================================================
depth     (H, W)  distance from the eye along the ray (scene units)
z         (H, W)  camera-space depth: distance along the viewing axis -w
normal    (H,W,3) unit world shading normal, turned towards the camera
albedo    (H,W,3) the diffuse reflectance kd of the surface (Le for an area light)
position  (H,W,3) world position of the hit
coverage  (H, W)  fraction of the pixel's samples that hit a surface
object_id (H, W)  index into ``scene.shapes``; area lights are len(shapes) + light index
material  (H, W)  index into ``scene.materials`` (in insertion order); -1 for lights
motion    (H,W,2) screen-space motion in pixels (x right, y down) of the visible point from
                  shutter open to shutter close (objects and camera both move)
========= ======= =====================================================================

EXR channels (``image.save_image``): ``EXR_CHANNELS`` below: depth is ``Z`` and coverage ``A``
(OpenEXR's standard names), the normal ``N.X N.Y N.Z``, the position ``P.X P.Y P.Z``, the
albedo ``albedo.R albedo.G albedo.B``, ids as UINT channels holding id + 1 (0: none).
"""

from __future__ import annotations

import threading
from dataclasses import dataclass

import numpy as np
import warp as wp

from ._warp import build_once
from .build import DeviceScene
from .camera import camera_frame_w, camera_ray, project
from .errors import RenderError
from .film import FilmData
from .integrator import DIM_FILM, DIM_LENS, DIM_TIME
from .records import KIND_BOX, KIND_MESH, KIND_NONE, KIND_SPHERE, CameraData, Features, RenderParams, SceneData
from .sampling import pixel_key, sample_1d_keyed, sample_2d_keyed
from .scene.description import is_area_light
from .trace import make_trace, to_object, to_world


@dataclass(frozen=True)
class AovSpec:
    dtype: object  # the device buffer's element type
    channels: int  # 1, 2 or 3
    out: type  # numpy dtype of the result
    exr: tuple  # EXR channel names
    uint: bool = False  # written as a UINT channel holding id + 1 (0: none)


# one entry per AOV: the kernel writes the buffers of the same names
AOVS = {
    "depth": AovSpec(float, 1, np.float32, ("Z",)),
    "z": AovSpec(float, 1, np.float32, ("z.V",)),
    "normal": AovSpec(wp.vec3, 3, np.float32, ("N.X", "N.Y", "N.Z")),
    "albedo": AovSpec(wp.vec3, 3, np.float32, ("albedo.R", "albedo.G", "albedo.B")),
    "position": AovSpec(wp.vec3, 3, np.float32, ("P.X", "P.Y", "P.Z")),
    "coverage": AovSpec(float, 1, np.float32, ("A",)),
    "object_id": AovSpec(int, 1, np.int32, ("object_id",), uint=True),
    "material": AovSpec(int, 1, np.int32, ("material",), uint=True),
    "motion": AovSpec(wp.vec2, 2, np.float32, ("motion.X", "motion.Y")),
}
AOV_NAMES = tuple(AOVS)
EXR_CHANNELS = {name: spec.exr for name, spec in AOVS.items()}
MISS_DEPTH = float("inf")  # depth and z of a pixel (or ray) that hits nothing
ID_SLOTS = 4  # distinct ids a pixel counts votes for


@wp.struct
class AovBuffers:
    depth: wp.array(dtype=float)
    z: wp.array(dtype=float)
    normal: wp.array(dtype=wp.vec3)
    albedo: wp.array(dtype=wp.vec3)
    position: wp.array(dtype=wp.vec3)
    coverage: wp.array(dtype=float)
    object_id: wp.array(dtype=int)
    material: wp.array(dtype=int)
    motion: wp.array(dtype=wp.vec2)


@wp.struct
class IdMap:
    """Object id of each (kind, row): ``ids[base[kind] + row]``; materials below ``n_mats`` are the
    scene's (the rest are area lights' emitting materials)."""

    base: wp.array(dtype=int)
    ids: wp.array(dtype=int)
    n_mats: int


@build_once
def aov_functions():
    """The per-pixel AOV function (shared by the single-image and the batch AOV kernels) with the
    tracing of ``Features.full()`` (runtime checks stand in for the render kernel's switches)."""
    trace = make_trace(Features.full())
    closest_hit, sphere_center, instance_pose = trace.closest_hit, trace.sphere_center, trace.instance_pose
    solid_pose, solid_rec = trace.solid_pose, trace.solid_rec

    @wp.func
    def aov_pixel(scene: SceneData, cam: CameraData, params: RenderParams, px: int, py: int, pixel: int,
                  n: int, idmap: IdMap, out: AovBuffers, slot: int):
        """AOVs of raster pixel (px, py) from its samples [0, n) (keys of film entry ``pixel``),
        written to entry ``slot`` of ``out``."""
        pkey = pixel_key(params.seed, pixel)
        hits = int(0)
        depth = float(0.0)
        zc = float(0.0)
        nsum = wp.vec3(0.0)
        alb = wp.vec3(0.0)
        pos = wp.vec3(0.0)
        mot = wp.vec2(0.0)
        ids = wp.vec4i(-1, -1, -1, -1)
        mats = wp.vec4i(-1, -1, -1, -1)
        votes = wp.vec4i(0, 0, 0, 0)
        for s in range(n):
            # the render kernel's camera sample (integrator.render_pixel), dimension for dimension
            uf = sample_2d_keyed(params.sampler, pkey, s, params.spp, wp.uint32(DIM_FILM))
            time = cam.t_open
            if params.moving != 0 and cam.t_close > cam.t_open:
                ut = sample_1d_keyed(params.sampler, pkey, s, params.spp, wp.uint32(DIM_TIME))
                time = cam.t_open + (cam.t_close - cam.t_open) * ut
            ul = wp.vec2(0.5, 0.5)
            if cam.lens_radius > 0.0:
                ul = sample_2d_keyed(params.sampler, pkey, s, params.spp, wp.uint32(DIM_LENS))
            ray = camera_ray(cam, float(px) + uf[0], float(py) + uf[1], ul, time)
            h = closest_hit(scene, ray.o, ray.d, params.t_min, params.t_max, time)
            if h.kind == KIND_NONE:
                continue
            hits += 1
            depth += h.t
            zc += h.t * -wp.dot(ray.d, camera_frame_w(cam, time))
            nrm = h.ns
            if wp.dot(nrm, ray.d) > 0.0:
                nrm = -nrm
            nsum += nrm
            pos += h.p
            m = scene.mats[h.mat]
            if wp.max(m.emit) > 0.0:
                alb += m.emit
            else:
                alb += m.kd
            # the visible point followed over the whole shutter: where it is at open and at close
            t0 = cam.t_open
            t1 = cam.t_close
            p0 = h.p
            p1 = h.p
            if h.kind == KIND_SPHERE:
                c = sphere_center(scene, h.index, time)
                p0 = h.p + sphere_center(scene, h.index, t0) - c
                p1 = h.p + sphere_center(scene, h.index, t1) - c
            elif h.kind == KIND_MESH:
                p_obj = to_object(instance_pose(scene, h.index, time), h.p)
                p0 = to_world(instance_pose(scene, h.index, t0), p_obj)
                p1 = to_world(instance_pose(scene, h.index, t1), p_obj)
            elif h.kind >= KIND_BOX:
                rec = solid_rec(scene, h.kind, h.index)
                p_obj = to_object(solid_pose(rec, time), h.p)
                p0 = to_world(solid_pose(rec, t0), p_obj)
                p1 = to_world(solid_pose(rec, t1), p_obj)
            mot += project(cam, p1, t1) - project(cam, p0, t0)
            # id votes
            oid = idmap.ids[idmap.base[h.kind] + h.index]
            mid = int(-1)
            if h.mat < idmap.n_mats:
                mid = h.mat
            for k in range(4):
                if ids[k] == oid:
                    votes[k] = votes[k] + 1
                    break
                if ids[k] == -1:
                    ids[k] = oid
                    mats[k] = mid
                    votes[k] = 1
                    break
        out.coverage[slot] = float(hits) / float(wp.max(n, 1))
        if hits == 0:
            out.depth[slot] = wp.inf
            out.z[slot] = wp.inf
            out.normal[slot] = wp.vec3(0.0)
            out.albedo[slot] = wp.vec3(0.0)
            out.position[slot] = wp.vec3(0.0)
            out.motion[slot] = wp.vec2(0.0)
            out.object_id[slot] = -1
            out.material[slot] = -1
            return
        inv = 1.0 / float(hits)
        out.depth[slot] = depth * inv
        out.z[slot] = zc * inv
        if wp.length(nsum) > 0.0:
            out.normal[slot] = wp.normalize(nsum)
        else:
            out.normal[slot] = wp.vec3(0.0)
        out.albedo[slot] = alb * inv
        out.position[slot] = pos * inv
        out.motion[slot] = mot * inv
        best = int(0)
        for k in range(1, 4):
            if votes[k] > votes[best]:  # strictly more: ties go to the id seen first
                best = k
        out.object_id[slot] = ids[best]
        out.material[slot] = mats[best]

    return aov_pixel


@build_once
def _aov_kernel():
    aov_pixel = aov_functions()

    @wp.kernel(module="warprt_aov", enable_backward=False)
    def aov_kernel(scene: SceneData, cam: CameraData, params: RenderParams, film: FilmData, n: int, idmap: IdMap,
                   out: AovBuffers, first: int):
        pixel = first + wp.tid()
        aov_pixel(scene, cam, params, pixel % cam.width, pixel / cam.width, pixel, wp.min(n, film.limit[pixel]),
                  idmap, out, pixel)

    return aov_kernel


def id_map(built: DeviceScene) -> IdMap:
    """The object id of every row of every shape table: the shape's index in ``scene.shapes``, or
    len(shapes) + light index for an area light's own surface."""
    d = built.data
    # KIND_SPHERE ... KIND_MESH, KIND_BOX, KIND_CAPSULE, KIND_CYLINDER
    counts = [d.n_spheres, d.n_planes, d.n_rects, d.n_disks, d.n_inst, d.n_boxes, d.n_capsules, d.n_cylinders]
    base = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.int32)
    ids = np.full(max(int(sum(counts)), 1), -1, dtype=np.int32)
    for obj, (kind, row) in enumerate(built.shape_ids):
        ids[base[kind] + row] = obj
    lights = [i for i, light in enumerate(built.scene.lights) if is_area_light(light)]
    for rec, light_index in zip(built.area_lights, lights):
        ids[base[rec["kind"]] + rec["shape"]] = len(built.scene.shapes) + light_index
    m = IdMap()
    m.base = wp.array(base, dtype=int, device=built.device)
    m.ids = wp.array(ids, dtype=int, device=built.device)
    m.n_mats = len(built.scene.materials)
    return m


def check_aov_names(names) -> list[str]:
    if isinstance(names, str):
        names = [names]
    elif not isinstance(names, (list, tuple, set, frozenset)) or not all(isinstance(n, str) for n in names):
        raise RenderError(f"aovs: expected a list of AOV names ({', '.join(AOV_NAMES)}), got {names!r:.60}")
    names = list(dict.fromkeys(names))
    unknown = [n for n in names if n not in AOVS]
    if unknown:
        raise RenderError(f"unknown AOV(s) {', '.join(map(repr, unknown))}; available: {', '.join(AOV_NAMES)}")
    return names


def aov_buffers(n: int, device) -> AovBuffers:
    bufs = AovBuffers()
    for name, spec in AOVS.items():
        setattr(bufs, name, wp.zeros(n, dtype=spec.dtype, device=device))
    return bufs


def shaped(bufs: AovBuffers, names, shape: tuple, as_warp: bool) -> dict:
    """The named buffers reshaped to ``shape`` (+ channels): ``wp.array``s on their device with
    ``as_warp``, else numpy copies."""
    out = {}
    for name in names:
        buf = getattr(bufs, name).reshape(shape)
        out[name] = buf if as_warp else np.array(buf.numpy(), dtype=AOVS[name].out, copy=True)
    return out


AOV_PIECES_PER_WORKER = 8  # bands of rows the CPU's AOV pixels are cut into, per worker (compute_aovs)


def compute_aovs(built: DeviceScene, names, params: RenderParams, film: FilmData, n: int,
                 as_warp: bool = False, pool=None, workers: int = 1) -> dict:
    """The requested AOVs of a render, from samples [0, n) of each pixel (at most its film
    limit) with the render's ``params``: numpy arrays, or ``wp.array``s with ``as_warp``. On the
    CPU with a thread ``pool`` and several ``workers`` (a CPU launch runs on one thread), the
    workers take bands of rows in turn, AOV_PIECES_PER_WORKER of them per worker; a pixel's AOVs
    are its own, whatever the split."""
    names = check_aov_names(names)
    cam = built.scene.camera
    count, dev = cam.width * cam.height, built.device
    bufs = aov_buffers(count, dev)
    inputs = [built.data, built.camera, params, film, int(n), id_map(built), bufs]
    if pool is None or workers <= 1 or not dev.is_cpu:
        wp.launch(_aov_kernel(), dim=count, device=dev, inputs=[*inputs, 0])
    else:
        # recorded here (the module is loaded from this thread), launched by the workers
        step = -(-cam.height // (AOV_PIECES_PER_WORKER * workers)) * cam.width
        pieces = iter([wp.launch(_aov_kernel(), dim=min(step, count - first), device=dev, inputs=[*inputs, first],
                                 record_cmd=True) for first in range(0, count, step)])
        lock = threading.Lock()

        def work():
            while True:
                with lock:
                    cmd = next(pieces, None)
                if cmd is None:
                    return
                cmd.launch()

        # (a Ctrl-C waits for the bands under way, as a render's pass does: render.run_pass)
        held = False
        for f in [pool.submit(work) for _ in range(workers)]:
            while True:
                try:
                    f.result()
                    break
                except KeyboardInterrupt:
                    held = True
        if held:
            raise KeyboardInterrupt
    return shaped(bufs, names, (cam.height, cam.width), as_warp)
