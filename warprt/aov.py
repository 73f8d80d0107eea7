"""Arbitrary output variables (AOVs): per-pixel geometry next to the colour, from the same samples.

Each AOV is averaged over the very camera samples that made the pixel's colour, in the same
kernel launch (as pbrt-v4's G-buffer film does): the render kernel (``integrator.render_pixels``)
adds each camera sample's first hit to the pixel's AOV sums (``make_aov_add``) where it adds the
sample's radiance to the film, so AOVs are antialiased, defocused and motion-blurred exactly like
the colour, with camera rays in packets or one by one alike. The sums are taken sample by sample
in sample order by the thread that owns the pixel, so AOVs are bit-identical for any worker
count, slices or pass split. With adaptive sampling a pixel's AOVs use its own count; an
interrupted render's AOVs use the samples it finished.

A render asks for AOVs with a run-time mask (``RenderParams.aovs``, one bit per AOV:
``AOV_BITS``) and an ``AovData`` (``AovTarget`` makes both); a render without AOVs runs the same
kernel with the mask 0. Between passes a pixel's sums wait in the AOV buffers themselves (depth,
z, normal, albedo, position and motion hold their sums), in ``AovData.hits`` and in the id slots;
the pass that completes a render's planned samples (``AovData.end``) writes the AOVs themselves
(``aov_write``), and a render that stops short of them (Ctrl-C, ``stop``, a time budget or a
target error), or an adaptive one, has them written by the small ``aov_finish`` kernel
(``AovTarget.finish``).

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
z         (H, W)  camera-space depth: distance along the viewing axis -w at the sample's time
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

from dataclasses import dataclass

import numpy as np
import warp as wp

from ._warp import build_once
from .build import DeviceScene
from .camera import camera_frame_w, project
from .errors import RenderError
from .film import NO_LIMIT, FilmData
from .records import KIND_BOX, KIND_MESH, KIND_SPHERE, CameraData, Features, SceneData
from .scene.description import is_area_light
from .trace import Hit, make_trace, to_object, to_world


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


# the run-time mask of the AOVs a render asks for (RenderParams.aovs): one bit per AOV, in AOVS' order
AOV_BITS = {name: 1 << i for i, name in enumerate(AOV_NAMES)}
AOV_DEPTH, AOV_Z, AOV_NORMAL, AOV_ALBEDO, AOV_POSITION = (AOV_BITS[n] for n in ("depth", "z", "normal", "albedo", "position"))
AOV_COVERAGE, AOV_OBJECT_ID, AOV_MATERIAL, AOV_MOTION = (AOV_BITS[n] for n in ("coverage", "object_id", "material",
                                                                                 "motion"))
AOV_IDS = AOV_OBJECT_ID | AOV_MATERIAL  # (both come from the same votes)


def aov_mask(names) -> int:
    """The run-time mask (``RenderParams.aovs``) of the named AOVs."""
    mask = 0
    for name in names:
        mask |= AOV_BITS[name]
    return mask


@wp.struct
class AovSums:
    """A pixel's AOV sums over its samples so far (held by the render kernel during a pass)."""

    hits: int  # samples that hit a surface
    depth: float
    z: float
    normal: wp.vec3  # Σ shading normals turned towards the camera
    albedo: wp.vec3
    position: wp.vec3
    motion: wp.vec2
    ids: wp.vec4i  # the first ID_SLOTS distinct object ids seen (-1: a free slot)
    mats: wp.vec4i  # their materials
    votes: wp.vec4i  # how many samples saw each


@wp.struct
class AovData:
    """What the render kernel writes the AOVs to. ``out`` holds the requested AOVs (one-element
    arrays for the others); between passes its depth, z, normal, albedo, position and motion
    hold their sums, ``hits`` and the id slots the rest of ``AovSums`` (one-element arrays where
    a render never stops between passes: a batch)."""

    out: AovBuffers
    hits: wp.array(dtype=int)
    ids: wp.array(dtype=wp.vec4i)
    mats: wp.array(dtype=wp.vec4i)
    votes: wp.array(dtype=wp.vec4i)
    idmap: IdMap
    end: int  # a pass whose samples end here or later is the render's last: it writes the AOVs themselves


@wp.func
def aov_start(aov: AovData, mask: int, pixel: int, s0: int) -> AovSums:
    """A pixel's sums before sample s0: none at sample 0, else those its last pass stored."""
    a = AovSums()
    a.ids = wp.vec4i(-1, -1, -1, -1)
    a.mats = wp.vec4i(-1, -1, -1, -1)
    if s0 > 0:
        a.hits = aov.hits[pixel]
        if (mask & AOV_DEPTH) != 0:
            a.depth = aov.out.depth[pixel]
        if (mask & AOV_Z) != 0:
            a.z = aov.out.z[pixel]
        if (mask & AOV_NORMAL) != 0:
            a.normal = aov.out.normal[pixel]
        if (mask & AOV_ALBEDO) != 0:
            a.albedo = aov.out.albedo[pixel]
        if (mask & AOV_POSITION) != 0:
            a.position = aov.out.position[pixel]
        if (mask & AOV_MOTION) != 0:
            a.motion = aov.out.motion[pixel]
        if (mask & AOV_IDS) != 0:
            a.ids = aov.ids[pixel]
            a.mats = aov.mats[pixel]
            a.votes = aov.votes[pixel]
    return a


@wp.func
def aov_write(out: AovBuffers, mask: int, slot: int, a: AovSums, n: int):
    """The AOVs of entry ``slot`` from its sums over n samples (the rules of the module docstring)."""
    if (mask & AOV_COVERAGE) != 0:
        out.coverage[slot] = float(a.hits) / float(wp.max(n, 1))
    if a.hits == 0:  # the miss values
        if (mask & AOV_DEPTH) != 0:
            out.depth[slot] = wp.inf
        if (mask & AOV_Z) != 0:
            out.z[slot] = wp.inf
        if (mask & AOV_NORMAL) != 0:
            out.normal[slot] = wp.vec3(0.0)
        if (mask & AOV_ALBEDO) != 0:
            out.albedo[slot] = wp.vec3(0.0)
        if (mask & AOV_POSITION) != 0:
            out.position[slot] = wp.vec3(0.0)
        if (mask & AOV_MOTION) != 0:
            out.motion[slot] = wp.vec2(0.0)
        if (mask & AOV_OBJECT_ID) != 0:
            out.object_id[slot] = -1
        if (mask & AOV_MATERIAL) != 0:
            out.material[slot] = -1
        return
    inv = 1.0 / float(a.hits)
    if (mask & AOV_DEPTH) != 0:
        out.depth[slot] = a.depth * inv
    if (mask & AOV_Z) != 0:
        out.z[slot] = a.z * inv
    if (mask & AOV_NORMAL) != 0:
        if wp.length(a.normal) > 0.0:
            out.normal[slot] = wp.normalize(a.normal)
        else:
            out.normal[slot] = wp.vec3(0.0)
    if (mask & AOV_ALBEDO) != 0:
        out.albedo[slot] = a.albedo * inv
    if (mask & AOV_POSITION) != 0:
        out.position[slot] = a.position * inv
    if (mask & AOV_MOTION) != 0:
        out.motion[slot] = a.motion * inv
    if (mask & AOV_IDS) != 0:
        best = int(0)
        for k in range(1, ID_SLOTS):
            if a.votes[k] > a.votes[best]:  # strictly more: ties go to the id seen first
                best = k
        if (mask & AOV_OBJECT_ID) != 0:
            out.object_id[slot] = a.ids[best]
        if (mask & AOV_MATERIAL) != 0:
            out.material[slot] = a.mats[best]


@wp.func
def aov_store(aov: AovData, mask: int, pixel: int, a: AovSums, n: int, final: bool):
    """A pixel's sums after a pass, n samples in all: its AOVs where the pass is the render's
    last (``final``), else the sums for the next pass (``aov_start``)."""
    if final:
        aov_write(aov.out, mask, pixel, a, n)
        return
    aov.hits[pixel] = a.hits
    if (mask & AOV_DEPTH) != 0:
        aov.out.depth[pixel] = a.depth
    if (mask & AOV_Z) != 0:
        aov.out.z[pixel] = a.z
    if (mask & AOV_NORMAL) != 0:
        aov.out.normal[pixel] = a.normal
    if (mask & AOV_ALBEDO) != 0:
        aov.out.albedo[pixel] = a.albedo
    if (mask & AOV_POSITION) != 0:
        aov.out.position[pixel] = a.position
    if (mask & AOV_MOTION) != 0:
        aov.out.motion[pixel] = a.motion
    if (mask & AOV_IDS) != 0:
        aov.ids[pixel] = a.ids
        aov.mats[pixel] = a.mats
        aov.votes[pixel] = a.votes


@build_once
def make_aov_add(F: Features):
    """``aov_add`` for the render kernel of feature set F: the sums with one more camera sample
    whose first hit is known (the motion of the visible point with F's own pose functions)."""
    trace = make_trace(F)
    sphere_center, instance_pose = trace.sphere_center, trace.instance_pose
    solid_pose, solid_rec = trace.solid_pose, trace.solid_rec

    @wp.func
    def aov_add(scene: SceneData, cam: CameraData, aov: AovData, mask: int, a: AovSums, h: Hit, d: wp.vec3,
                time: float) -> AovSums:
        """``a`` with the camera sample along unit direction d at ``time`` whose first hit is h
        (a surface, not a miss)."""
        r = a
        r.hits = a.hits + 1
        if (mask & AOV_DEPTH) != 0:
            r.depth = a.depth + h.t
        if (mask & AOV_Z) != 0:
            r.z = a.z + h.t * -wp.dot(d, camera_frame_w(cam, time))
        if (mask & AOV_NORMAL) != 0:
            nrm = h.ns
            if wp.dot(nrm, d) > 0.0:
                nrm = -nrm  # turned towards the camera
            r.normal = a.normal + nrm
        if (mask & AOV_ALBEDO) != 0:
            m = scene.mats[h.mat]
            if wp.max(m.emit) > 0.0:
                r.albedo = a.albedo + m.emit
            else:
                r.albedo = a.albedo + m.kd
        if (mask & AOV_POSITION) != 0:
            r.position = a.position + h.p
        if (mask & AOV_MOTION) != 0:
            # the visible point followed over the whole shutter: where it is at open and at close
            t0 = cam.t_open
            t1 = cam.t_close
            p0 = h.p
            p1 = h.p
            if wp.static(F.motion):  # (else nothing moves: p0 = p1)
                if h.kind == KIND_SPHERE:
                    c = sphere_center(scene, h.index, time)
                    p0 = h.p + sphere_center(scene, h.index, t0) - c
                    p1 = h.p + sphere_center(scene, h.index, t1) - c
                if wp.static(F.meshes):
                    if h.kind == KIND_MESH:
                        p_obj = to_object(instance_pose(scene, h.index, time), h.p)
                        p0 = to_world(instance_pose(scene, h.index, t0), p_obj)
                        p1 = to_world(instance_pose(scene, h.index, t1), p_obj)
                if wp.static(F.solids):
                    if h.kind >= KIND_BOX:
                        rec = solid_rec(scene, h.kind, h.index)
                        p_obj = to_object(solid_pose(rec, time), h.p)
                        p0 = to_world(solid_pose(rec, t0), p_obj)
                        p1 = to_world(solid_pose(rec, t1), p_obj)
            r.motion = a.motion + (project(cam, p1, t1) - project(cam, p0, t0))
        if (mask & AOV_IDS) != 0:
            oid = aov.idmap.ids[aov.idmap.base[h.kind] + h.index]
            mid = int(-1)
            if h.mat < aov.idmap.n_mats:
                mid = h.mat
            ids = a.ids
            mats = a.mats
            votes = a.votes
            for k in range(ID_SLOTS):
                if ids[k] == oid:
                    votes[k] = votes[k] + 1
                    break
                if ids[k] == -1:
                    ids[k] = oid
                    mats[k] = mid
                    votes[k] = 1
                    break
            r.ids = ids
            r.mats = mats
            r.votes = votes
        return r

    return aov_add


@build_once
def _aov_kernel():
    """The kernel that finishes the AOVs a render's last pass did not write (``AovTarget.finish``)."""

    @wp.kernel(module="warprt_aov", enable_backward=False)
    def aov_finish(aov: AovData, mask: int, film: FilmData, done: int):
        pixel = wp.tid()
        n = wp.min(done, film.limit[pixel])
        aov_write(aov.out, mask, pixel, aov_start(aov, mask, pixel, n), n)

    return aov_finish


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
    names = [names] if isinstance(names, str) else list(dict.fromkeys(names))
    unknown = [n for n in names if n not in AOVS]
    if unknown:
        raise RenderError(f"unknown AOV(s) {', '.join(map(repr, unknown))}; available: {', '.join(AOV_NAMES)}")
    return names


def _buffers(names, count: int, device) -> AovBuffers:
    """The named AOVs' buffers of ``count`` entries (unset), a one-element one for each other."""
    bufs = AovBuffers()
    for name, spec in AOVS.items():
        setattr(bufs, name, wp.empty(count if name in names else 1, dtype=spec.dtype, device=device))
    return bufs


_NO_AOVS: dict = {}  # no_aovs' record per device


def no_aovs(device) -> AovData:
    """The ``AovData`` of renders without AOVs (``RenderParams.aovs`` 0: the kernel never reads it),
    one per device."""
    data = _NO_AOVS.get(str(device))
    if data is not None:
        return data
    data = AovData()
    data.out = _buffers((), 1, device)
    data.hits = wp.empty(1, dtype=int, device=device)
    data.ids, data.mats, data.votes = (wp.empty(1, dtype=wp.vec4i, device=device) for _ in range(3))
    m = IdMap()
    m.base = wp.zeros(1, dtype=int, device=device)
    m.ids = wp.zeros(1, dtype=int, device=device)
    m.n_mats = 0
    data.idmap = m
    data.end = NO_LIMIT
    return _NO_AOVS.setdefault(str(device), data)


class AovTarget:
    """The AOV buffers of one render (or batch) of ``count`` pixels: ``data`` for the render
    kernel, ``mask`` for ``RenderParams.aovs``. ``end``: the render's planned samples per pixel
    (its pass that reaches them writes the AOVs; ``NO_LIMIT`` where no pass knows itself the
    last, as in adaptive sampling, and ``finish`` writes them); ``between_passes=False`` where
    every render is one pass (no sums are stored)."""

    def __init__(self, built: DeviceScene, names, count: int, end: int, between_passes: bool = True):
        self.names = check_aov_names(names)
        self.mask = aov_mask(self.names)
        self.count = count
        self.device = dev = built.device
        data = AovData()
        data.out = _buffers(self.names, count, dev)
        rows = count if between_passes else 1
        data.hits = wp.empty(rows, dtype=int, device=dev)
        ids = rows if self.mask & AOV_IDS else 1
        data.ids, data.mats, data.votes = (wp.empty(ids, dtype=wp.vec4i, device=dev) for _ in range(3))
        data.idmap = id_map(built)
        data.end = int(end)
        self.data = data
        _aov_kernel()  # (defined with the first AOVs, so that the module's content never changes)

    def finish(self, film: FilmData, done: int) -> None:
        """Write the AOVs of a render that ran ``done`` samples per pixel (each pixel at most its
        film limit) where its last pass did not (``done`` short of ``end``)."""
        if done < self.data.end:
            wp.launch(_aov_kernel(), dim=self.count, device=self.device, inputs=[self.data, self.mask, film, int(done)])

    def maps(self, shape: tuple, as_warp: bool) -> dict:
        """The requested AOVs shaped ``shape`` (+ channels) (see ``shaped``)."""
        return shaped(self.data.out, self.names, shape, as_warp)


def shaped(bufs: AovBuffers, names, shape: tuple, as_warp: bool) -> dict:
    """The named buffers reshaped to ``shape`` (+ channels): ``wp.array``s on their device with
    ``as_warp``, else numpy copies."""
    out = {}
    for name in names:
        buf = getattr(bufs, name).reshape(shape)
        out[name] = buf if as_warp else np.array(buf.numpy(), dtype=AOVS[name].out, copy=True)
    return out

