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

EXR channels (``image.save_image``): ``EXR_CHANNELS`` below: the camera-space depth z is ``Z``
and coverage ``A`` (OpenEXR's standard names), the distance along the ray ``distance.V``, the
normal ``N.X N.Y N.Z``, the position ``P.X P.Y P.Z``, the albedo ``albedo.R albedo.G albedo.B``,
the motion Nuke's ``forward.u forward.v`` (v up: the array's y negated), ids as UINT channels
holding id + 1 (0: none) with a table of their names in the header.
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
from .records import KIND_BOX, KIND_MESH, KIND_NONE, KIND_SPHERE, CameraData, Features, SceneData
from .scene.description import is_area_light
from .trace import Hit, make_trace, to_object, to_world


@dataclass(frozen=True)
class AovSpec:
    dtype: object  # the device buffer's element type
    channels: int  # 1, 2 or 3
    out: type  # numpy dtype of the result
    exr: tuple  # EXR channel names
    uint: bool = False  # written as a UINT channel holding id + 1 (0: none)
    signs: tuple = ()  # per channel, the sign the EXR stores it with (empty: all +1)
    half: bool = True  # stored as HALF in a 16-bit EXR (False: kept FLOAT, distances and positions)


# one entry per AOV: the kernel writes the buffers of the same names. EXR channels as compositors
# read them: Z is camera-space depth (Nuke's depth.Z, what ZDefocus and deep tools take), A the
# coverage (the alpha of the premultiplied RGBA), N and P world normals and positions, the motion
# Nuke's forward layer (u right, v up: the y of the array turned over)
AOVS = {
    "depth": AovSpec(float, 1, np.float32, ("distance.V",), half=False),
    "z": AovSpec(float, 1, np.float32, ("Z",), half=False),
    "normal": AovSpec(wp.vec3, 3, np.float32, ("N.X", "N.Y", "N.Z")),
    "albedo": AovSpec(wp.vec3, 3, np.float32, ("albedo.R", "albedo.G", "albedo.B")),
    "position": AovSpec(wp.vec3, 3, np.float32, ("P.X", "P.Y", "P.Z"), half=False),
    "coverage": AovSpec(float, 1, np.float32, ("A",)),
    "object_id": AovSpec(int, 1, np.int32, ("object_id",), uint=True),
    "material": AovSpec(int, 1, np.int32, ("material",), uint=True),
    "motion": AovSpec(wp.vec2, 2, np.float32, ("forward.u", "forward.v"), signs=(1.0, -1.0)),
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
class AovData:
    """What the render kernel writes the AOVs to. ``out`` holds the requested AOVs (one-element
    arrays for the others); until a pixel's last sample its depth, z, normal, albedo, position
    and motion hold their sums over the samples so far, ``hits`` how many of them hit, and the
    id slots (``ids``, ``mats``, ``votes``: the first ID_SLOTS distinct object ids seen, their
    materials and how many samples saw each; one-element arrays unless object_id or material,
    for ``mats`` material, is asked for)."""

    out: AovBuffers
    hits: wp.array(dtype=int)
    ids: wp.array(dtype=wp.vec4i)
    mats: wp.array(dtype=wp.vec4i)
    votes: wp.array(dtype=wp.vec4i)
    idmap: IdMap
    end: int  # a pass whose samples end here or later is the render's last: it writes the AOVs themselves


@wp.func
def aov_mean(total: float, inv: float, hits: int) -> float:
    """Depth or z: the mean over the samples that hit, the miss value where none did."""
    if hits == 0:
        return wp.inf
    return total * inv


@wp.func
def aov_inverse(hits: int) -> float:
    """1 / hits (0 for none; 1 for one, exactly, without a division: one-sample renders)."""
    if hits > 1:
        return 1.0 / float(hits)
    return float(hits)


@wp.func
def aov_fraction(hits: int, n: int) -> float:
    """Coverage: hits / n, correctly rounded (0 for no samples; no division for one)."""
    if n > 1:
        return float(hits) / float(n)
    return float(hits)


@wp.func
def aov_normal(total: wp.vec3, hits: int) -> wp.vec3:
    """The normal: the mean renormalised (0 where no sample hit). One sample's shading normal is
    a unit vector already: it is kept as it is (a square root and a division less a pixel in a
    one-sample render, a third of what the normal, depth and object_id cost there)."""
    if hits == 1:
        return total
    if hits == 0 or not (wp.length(total) > 0.0):
        return wp.vec3(0.0)
    return wp.normalize(total)


@wp.func
def aov_vote(votes: wp.vec4i) -> int:
    """The slot seen by the most samples, ties going to the one seen first (slot 0 when none
    voted: its id is -1 then, the miss value)."""
    best = int(0)
    if votes[1] > votes[best]:  # strictly more: ties go to the id seen first
        best = 1
    if votes[2] > votes[best]:
        best = 2
    if votes[3] > votes[best]:
        best = 3
    return best


@wp.func
def aov_ids(aov: AovData, mask: int, pixel: int, ids: wp.vec4i, mats: wp.vec4i, votes: wp.vec4i):
    """The object_id and material of a pixel from its id slots (``aov_vote``)."""
    best = aov_vote(votes)
    if (mask & AOV_OBJECT_ID) != 0:
        aov.out.object_id[pixel] = ids[best]
    if (mask & AOV_MATERIAL) != 0:
        aov.out.material[pixel] = mats[best]


@build_once
def make_aov_sample(F: Features):
    """``aov_sample`` for the render kernel of feature set F (the motion of the visible point
    with F's own pose functions)."""
    trace = make_trace(F)
    sphere_center, instance_pose = trace.sphere_center, trace.instance_pose
    solid_pose, solid_rec = trace.solid_pose, trace.solid_rec
    from .textures import make_textures  # (textures imports trace, as this module does)

    textured = make_textures(F)

    @wp.func
    def point_motion(scene: SceneData, cam: CameraData, h: Hit, time: float) -> wp.vec2:
        """Screen motion of the visible point h.p (seen at ``time``) from shutter open to close.
        Without the motion feature nothing moves, the camera neither: the two projections are the
        same and the motion 0, exactly (and the kernel compiles without them)."""
        if wp.static(not F.motion):
            return wp.vec2(0.0)
        t0 = cam.t_open
        t1 = cam.t_close
        p0 = h.p
        p1 = h.p
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
        return project(cam, p1, t1) - project(cam, p0, t0)

    @wp.func
    def aov_sample(scene: SceneData, cam: CameraData, aov: AovData, mask: int, pixel: int, s: int, s1: int,
                   final: bool, h: Hit, d: wp.vec3, time: float):
        """Camera sample s of film entry ``pixel`` (along unit direction d at ``time``; first hit
        h, or a miss): added to the pixel's sums, which sample 0 starts; where the pass is the
        render's last (``final``) and the sample its last one (s1 - 1), the AOVs themselves
        are written instead (the rules of the module docstring). The render kernel calls it for
        each camera sample in sample order, so the sums are the same whatever the passes."""
        hit = h.kind != KIND_NONE
        last = final and s + 1 >= s1
        hits = int(0)
        if s > 0:
            hits = aov.hits[pixel]
        if hit:
            hits = hits + 1
        inv = float(0.0)
        if last:
            inv = aov_inverse(hits)
            if (mask & AOV_COVERAGE) != 0:
                aov.out.coverage[pixel] = aov_fraction(hits, s + 1)
        else:
            aov.hits[pixel] = hits
        if (mask & AOV_DEPTH) != 0:
            depth = float(0.0)
            if s > 0:
                depth = aov.out.depth[pixel]
            if hit:
                depth = depth + h.t
            if last:
                depth = aov_mean(depth, inv, hits)
            aov.out.depth[pixel] = depth
        if (mask & AOV_Z) != 0:
            zc = float(0.0)
            if s > 0:
                zc = aov.out.z[pixel]
            if hit:
                zc = zc + h.t * -wp.dot(d, camera_frame_w(cam, time))
            if last:
                zc = aov_mean(zc, inv, hits)
            aov.out.z[pixel] = zc
        if (mask & AOV_NORMAL) != 0:
            nsum = wp.vec3(0.0)
            if s > 0:
                nsum = aov.out.normal[pixel]
            if hit:
                nrm = h.ns
                if wp.dot(nrm, d) > 0.0:
                    nrm = -nrm  # turned towards the camera
                nsum = nsum + nrm
            if last:
                nsum = aov_normal(nsum, hits)
            aov.out.normal[pixel] = nsum
        if (mask & AOV_ALBEDO) != 0:
            alb = wp.vec3(0.0)
            if s > 0:
                alb = aov.out.albedo[pixel]
            if hit:
                m = scene.mats[h.mat]
                if wp.static(F.textures):
                    m = textured(scene, h, time)
                if wp.max(m.emit) > 0.0:
                    alb = alb + m.emit
                else:
                    alb = alb + m.kd
            if last:
                alb = alb * inv
            aov.out.albedo[pixel] = alb
        if (mask & AOV_POSITION) != 0:
            pos = wp.vec3(0.0)
            if s > 0:
                pos = aov.out.position[pixel]
            if hit:
                pos = pos + h.p
            if last:
                pos = pos * inv
            aov.out.position[pixel] = pos
        if (mask & AOV_MOTION) != 0:
            mot = wp.vec2(0.0)
            if s > 0:
                mot = aov.out.motion[pixel]
            if hit:
                mot = mot + point_motion(scene, cam, h, time)
            if last:
                mot = mot * inv
            aov.out.motion[pixel] = mot
        if (mask & AOV_IDS) != 0:
            ids = wp.vec4i(-1, -1, -1, -1)
            mats = wp.vec4i(-1, -1, -1, -1)
            votes = wp.vec4i(0, 0, 0, 0)
            if s > 0:
                ids = aov.ids[pixel]
                votes = aov.votes[pixel]
                if (mask & AOV_MATERIAL) != 0:
                    mats = aov.mats[pixel]
            if hit:
                oid = aov.idmap.ids[aov.idmap.base[h.kind] + h.index]
                mid = int(-1)
                if h.mat < aov.idmap.n_mats:
                    mid = h.mat
                # the id's slot, or the first free one (a fifth distinct id is not counted);
                # slot by slot with constant indices, so the slots stay in registers
                if ids[0] == oid:
                    votes[0] = votes[0] + 1
                elif ids[0] == -1:
                    ids[0] = oid
                    mats[0] = mid
                    votes[0] = 1
                elif ids[1] == oid:
                    votes[1] = votes[1] + 1
                elif ids[1] == -1:
                    ids[1] = oid
                    mats[1] = mid
                    votes[1] = 1
                elif ids[2] == oid:
                    votes[2] = votes[2] + 1
                elif ids[2] == -1:
                    ids[2] = oid
                    mats[2] = mid
                    votes[2] = 1
                elif ids[3] == oid:
                    votes[3] = votes[3] + 1
                elif ids[3] == -1:
                    ids[3] = oid
                    mats[3] = mid
                    votes[3] = 1
            if last:
                aov_ids(aov, mask, pixel, ids, mats, votes)
            else:
                aov.ids[pixel] = ids
                aov.votes[pixel] = votes
                if (mask & AOV_MATERIAL) != 0:
                    aov.mats[pixel] = mats

    return aov_sample


@build_once
def _aov_kernel():
    """The kernel that finishes the AOVs a render's last pass did not write (``AovTarget.finish``):
    the same rules as ``aov_sample``'s last sample, from the sums of the pixel's n samples."""

    @wp.kernel(module="warprt_aov", enable_backward=False)
    def aov_finish(aov: AovData, mask: int, film: FilmData, done: int):
        pixel = wp.tid()
        n = wp.min(done, film.limit[pixel])
        hits = int(0)
        if n > 0:
            hits = aov.hits[pixel]
        inv = aov_inverse(hits)
        if (mask & AOV_COVERAGE) != 0:
            aov.out.coverage[pixel] = aov_fraction(hits, n)
        # (a pixel without samples: sums of zero, and so the miss values)
        if (mask & AOV_DEPTH) != 0:
            aov.out.depth[pixel] = aov_mean(wp.where(n > 0, aov.out.depth[pixel], 0.0), inv, hits)
        if (mask & AOV_Z) != 0:
            aov.out.z[pixel] = aov_mean(wp.where(n > 0, aov.out.z[pixel], 0.0), inv, hits)
        if (mask & AOV_NORMAL) != 0:
            aov.out.normal[pixel] = aov_normal(wp.where(n > 0, aov.out.normal[pixel], wp.vec3(0.0)), hits)
        if (mask & AOV_ALBEDO) != 0:
            aov.out.albedo[pixel] = wp.where(n > 0, aov.out.albedo[pixel], wp.vec3(0.0)) * inv
        if (mask & AOV_POSITION) != 0:
            aov.out.position[pixel] = wp.where(n > 0, aov.out.position[pixel], wp.vec3(0.0)) * inv
        if (mask & AOV_MOTION) != 0:
            aov.out.motion[pixel] = wp.where(n > 0, aov.out.motion[pixel], wp.vec2(0.0)) * inv
        if (mask & AOV_IDS) != 0:
            ids = wp.vec4i(-1, -1, -1, -1)
            mats = wp.vec4i(-1, -1, -1, -1)
            votes = wp.vec4i(0, 0, 0, 0)
            if n > 0:
                ids = aov.ids[pixel]
                votes = aov.votes[pixel]
                if (mask & AOV_MATERIAL) != 0:
                    mats = aov.mats[pixel]
            aov_ids(aov, mask, pixel, ids, mats, votes)

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
    if isinstance(names, str):
        names = [names]
    elif not isinstance(names, (list, tuple, set, frozenset)) or not all(isinstance(n, str) for n in names):
        raise RenderError(f"aovs: expected a list of AOV names ({', '.join(AOV_NAMES)}), got {names!r:.60}")
    names = list(dict.fromkeys(names))
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
    (the pass that reaches them writes the AOVs); ``NO_LIMIT`` where no pass can tell that it
    is the last (adaptive sampling's counts come after its pilot), and ``finish`` writes them."""

    def __init__(self, built: DeviceScene, names, count: int, end: int):
        self.names = check_aov_names(names)
        self.mask = aov_mask(self.names)
        self.count = count
        self.built = built
        self.device = dev = built.device
        data = AovData()
        data.out = _buffers(self.names, count, dev)
        # (sums that wait for the next sample or pass; unset memory costs nothing until a render
        # needs it: a one-sample render writes the AOVs at once)
        data.hits = wp.empty(count, dtype=int, device=dev)
        ids = count if self.mask & AOV_IDS else 1
        data.ids, data.votes = (wp.empty(ids, dtype=wp.vec4i, device=dev) for _ in range(2))
        data.mats = wp.empty(count if self.mask & AOV_MATERIAL else 1, dtype=wp.vec4i, device=dev)
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
        buf = getattr(bufs, name)
        if as_warp:
            out[name] = buf.reshape(shape)
        else:  # (reshaped in numpy: a Warp reshape costs more than the copy of a small image)
            out[name] = np.array(buf.numpy(), dtype=AOVS[name].out, copy=True).reshape(
                shape + ((AOVS[name].channels,) if AOVS[name].channels > 1 else ()))
    return out

