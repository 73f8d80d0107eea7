"""Batched rendering: W worlds × C cameras of one scene structure in one launch per slice, with
poses read from device arrays.

A simulation pipeline (robotics, synthetic data) steps many copies of one scene ("worlds") that
differ only in where things are, and looks at each through a few cameras. :class:`BatchRenderer`
builds the scene once and keeps, on the device:

* ``shape_poses`` (W, S) ``wp.transform``: a rigid pose applied on top of each of the scene's S
  shapes as described (identity by default). Spheres: the centre is moved and turned (the radius
  stays); planes, rectangles and disks: moved and turned; meshes, boxes, capsules and cylinders:
  the pose is composed with the shape's own transform (pose ∘ transform, so a shape keeps its
  scale). ``shape_poses_end`` holds the poses at shutter close (motion blur,
  ``motion_blur=True``); planes, rectangles and disks take the shutter-open pose.
* ``light_positions`` (W, L) ``vec3``: the position of each point light and the direction of
  travel of each directional light (L = those lights, in ``scene.lights`` order). Area lights
  are the same in every world.
* ``material_colors`` (W, M) ``vec3``, ``material_textures`` (W, M) int32 and
  ``light_intensities`` (W, L) ``vec3``: each world's looks (domain randomisation): the diffuse
  colour kd of each of the scene's M materials (ka keeps its ratio to kd), its texture (an index
  into ``textures``, -1 none; the kernel has texture code where the scene has a texture or
  ``textures=[...]`` is given) and each point or directional light's intensity.
* ``camera_poses`` (W, C) ``wp.transform``: camera to world; the camera looks along its local
  -z with +y up (the OpenGL convention). ``camera_poses_end``: at shutter close (the up vector
  is the shutter-open one). ``fov`` (C,) float32: each camera's vertical field of view in
  degrees. Image size, aperture, focus and shutter are the scene camera's, unless the batch is
  given a list of cameras (``BatchRenderer(scene, cameras=[...])`` or ``set_cameras``): each
  then has its own model (intrinsics, distortion, fisheye, orthographic), aperture, shutter and
  rolling shutter, with the scene camera's image size; a camera given by intrinsics ignores its
  ``fov`` entry.

Write into these arrays in place, from Warp kernels or with ``wp.copy`` (``set_*`` methods
accept numpy, ``wp.array``s of transforms or of 4×4 matrices): a render reads them with three
small kernels (world tables, cameras, the BVH's bounds plus a refit), so an update costs no host
copy, no rebuild and no recompile; ``counters`` counts all three, and the tests check them
against Warp's own entry points.

The frame rendered is one tall image, W·C·H rows of the camera's width, whose blocks of rows the
worker threads claim in turn like a single image's (``render.py``); each pixel's noise is keyed
by its index in that image, so the batch is bit-identical for any thread count, and a world
renders the same whatever the other worlds hold. The render kernel is the single-image one's
per-pixel function with the world's rows of each table (array views of (W, n) tables) and the
world's group root in one grouped BVH over every world's bounded analytic shapes.
"""

from __future__ import annotations

import math
import time as _time
from dataclasses import dataclass, field

import numpy as np
import warp as wp

from . import _warp, kernels
from ._warp import build_once
from .accel import build_tree, forest_nodes, refit_kernel
from .build import ANALYTIC_BVH_MIN, DeviceScene, render_params
from .camera import camera_data
from .checks import EXTENT_LIMIT, NONE, check_batch, describe_transform
from .errors import RenderError
from .film import Film, FilmData, claim_block
from .aov import AOVS, AovData, AovTarget, no_aovs
from .integrator import kernels_for, packets_for
from .memory import check_memory
from .results import Displayed, FrameResult, camera_record_matrices, png_bytes, scene_metadata
from .records import (
    FALLOFF_DIRECTIONAL, KIND_BOX, KIND_CAPSULE, KIND_CYLINDER, KIND_DISK, KIND_MESH, KIND_PLANE, KIND_RECT, KIND_SPHERE,
    GENERAL_FEATURES, CameraData, DiskRec, Features, InstRec, MatRec, PlaneRec, PointLightRec, RectRec, RenderParams,
    SceneData, SolidRec, SphereRec,
)
from .render import (
    SLICE_BLOCK, SLICES_PER_WORKER, WorkerPool, _slices, check_seed, default_workers, pixels_per_thread, run_pass,
)
from .errors import SceneError
from .scene.description import SPP_LIMIT, Camera, DirectionalLight, PointLight, Scene
from .scene.texture import Texture, as_texture
from .geometry import disk_extent
from .poses import up_vector, warn_rolled
from .sensor import apply_depth_sensor, split_aovs
from .trace import instance_box, posed_solid, solid_box

BLOCK_ARG, AOV_ARG = 15, 16  # positions of these among the batch kernel's arguments
BOUNDS_PAD = 1e-6  # relative padding of BVH boxes (float32 rounding must not cut off a hit), as build.py


@wp.struct
class WorldTables:
    """Every per-world table, (W, n) each: row w is world w's table."""

    spheres: wp.array2d(dtype=SphereRec)
    planes: wp.array2d(dtype=PlaneRec)
    rects: wp.array2d(dtype=RectRec)
    disks: wp.array2d(dtype=DiskRec)
    insts: wp.array2d(dtype=InstRec)
    boxes: wp.array2d(dtype=SolidRec)
    capsules: wp.array2d(dtype=SolidRec)
    cylinders: wp.array2d(dtype=SolidRec)
    plights: wp.array2d(dtype=PointLightRec)
    mats: wp.array2d(dtype=MatRec)
    bvh_nodes_per_world: int  # world w's BVH is the nodes from w · this on (accel: a forest of equal trees)


@wp.func
def world_scene(scene: SceneData, tables: WorldTables, w: int) -> SceneData:
    """``scene`` seen from world w: its rows of every per-world table and its BVH group root."""
    sc = scene
    sc.spheres = tables.spheres[w]
    sc.planes = tables.planes[w]
    sc.rects = tables.rects[w]
    sc.disks = tables.disks[w]
    sc.insts = tables.insts[w]
    sc.boxes = tables.boxes[w]
    sc.capsules = tables.capsules[w]
    sc.cylinders = tables.cylinders[w]
    sc.plights = tables.plights[w]
    sc.mats = tables.mats[w]
    if scene.bvh_root >= 0:
        sc.bvh_root = w * tables.bvh_nodes_per_world
    return sc


@wp.func
def end_rotation(q1: wp.quat, rot1: wp.quat, rot0: wp.quat) -> wp.quat:
    """A shape's own rotation at shutter close turned by the pose q1, in rot0's hemisphere (slerp
    from rot0 takes the shorter arc)."""
    r = wp.normalize(q1 * rot1)
    if wp.dot(r, rot0) < 0.0:
        r = -r
    return r


@build_once
def _pose_kernels():
    """The kernels that turn the pose arrays into world tables, cameras and BVH bounds (one
    module, whatever the scene)."""

    @wp.kernel(module="warprt_worlds", enable_backward=False)
    def pose_shapes(base: SceneData, shape_map: wp.array(dtype=wp.vec2i), poses: wp.array2d(dtype=wp.transform),
                    poses_end: wp.array2d(dtype=wp.transform), tables: WorldTables):
        w, s = wp.tid()
        kind = shape_map[s][0]
        row = shape_map[s][1]
        T0 = poses[w, s]
        T1 = poses_end[w, s]
        q0 = wp.transform_get_rotation(T0)
        if kind == KIND_SPHERE:
            sph = base.spheres[row]
            sph.c0 = wp.transform_point(T0, sph.c0)
            sph.c1 = wp.transform_point(T1, sph.c1)
            tables.spheres[w, row] = sph
        elif kind == KIND_PLANE:
            pl = base.planes[row]
            pl.p = wp.transform_point(T0, pl.p)
            pl.n = wp.normalize(wp.quat_rotate(q0, pl.n))
            tables.planes[w, row] = pl
        elif kind == KIND_RECT:
            rc = base.rects[row]
            rc.c = wp.transform_point(T0, rc.c)
            rc.e1 = wp.quat_rotate(q0, rc.e1)
            rc.e2 = wp.quat_rotate(q0, rc.e2)
            rc.n = wp.normalize(wp.quat_rotate(q0, rc.n))
            tables.rects[w, row] = rc
        elif kind == KIND_DISK:
            dk = base.disks[row]
            dk.c = wp.transform_point(T0, dk.c)
            dk.n = wp.normalize(wp.quat_rotate(q0, dk.n))
            tables.disks[w, row] = dk
        elif kind == KIND_MESH:
            ins = base.insts[row]
            q1 = wp.transform_get_rotation(T1)
            ins.pos0 = wp.transform_point(T0, ins.pos0)
            ins.rot0 = wp.normalize(q0 * ins.rot0)
            ins.pos1 = wp.transform_point(T1, ins.pos1)
            ins.rot1 = end_rotation(q1, ins.rot1, ins.rot0)
            tables.insts[w, row] = instance_box(ins)
        elif kind >= KIND_BOX:
            rec = posed_solid(base, kind, row)
            q1 = wp.transform_get_rotation(T1)
            rec.pos0 = wp.transform_point(T0, rec.pos0)
            rec.rot0 = wp.normalize(q0 * rec.rot0)
            rec.pos1 = wp.transform_point(T1, rec.pos1)
            rec.rot1 = end_rotation(q1, rec.rot1, rec.rot0)
            rec = solid_box(rec, kind)
            if kind == KIND_BOX:
                tables.boxes[w, row] = rec
            elif kind == KIND_CAPSULE:
                tables.capsules[w, row] = rec
            else:
                tables.cylinders[w, row] = rec

    @wp.kernel(module="warprt_worlds", enable_backward=False)
    def pose_lights(base: SceneData, positions: wp.array2d(dtype=wp.vec3), intensities: wp.array2d(dtype=wp.vec3),
                    tables: WorldTables):
        w, i = wp.tid()
        rec = base.plights[i]
        rec.intensity = intensities[w, i]
        x = positions[w, i]
        if rec.inv_sq == FALLOFF_DIRECTIONAL:
            rec.pos = -wp.normalize(x)  # the unit vector towards the light
        else:
            rec.pos = x
        tables.plights[w, i] = rec

    @wp.kernel(module="warprt_worlds", enable_backward=False)
    def pose_cameras(lenses: wp.array(dtype=CameraData), poses: wp.array2d(dtype=wp.transform),
                     poses_end: wp.array2d(dtype=wp.transform), fov: wp.array(dtype=float),
                     cams: wp.array(dtype=CameraData)):
        w, c = wp.tid()
        n_cams = poses.shape[1]
        cam = lenses[c]
        T0 = poses[w, c]
        T1 = poses_end[w, c]
        q0 = wp.transform_get_rotation(T0)
        forward = wp.vec3(0.0, 0.0, -1.0)
        cam.eye0 = wp.transform_get_translation(T0)
        cam.look0 = cam.eye0 + wp.quat_rotate(q0, forward)
        cam.eye1 = wp.transform_get_translation(T1)
        cam.look1 = cam.eye1 + wp.quat_rotate(wp.transform_get_rotation(T1), forward)
        cam.up = wp.normalize(wp.quat_rotate(q0, wp.vec3(0.0, 1.0, 0.0)))
        if cam.from_fov != 0:  # (a camera given by intrinsics keeps its own plane)
            cam.top = cam.dist * wp.tan(0.5 * wp.radians(fov[c]))
            cam.right = cam.top * float(cam.width) / float(cam.height)
            cam.x_off = cam.right
            cam.y_off = cam.top
            cam.pfy = 0.5 * float(cam.height) / wp.tan(0.5 * wp.radians(fov[c]))
            cam.pfx = cam.pfy
        cams[w * n_cams + c] = cam

    @wp.kernel(module="warprt_worlds", enable_backward=False)
    def world_bounds(tables: WorldTables, prims: wp.array(dtype=wp.vec2i), per_world: int, moving: int,
                     lowers: wp.array(dtype=wp.vec3), uppers: wp.array(dtype=wp.vec3)):
        j = wp.tid()
        w = j / per_world
        kind = prims[j][0]
        row = prims[j][1]
        lo = wp.vec3(0.0)
        hi = wp.vec3(0.0)
        if kind == KIND_SPHERE:
            sph = tables.spheres[w, row]
            r = wp.vec3(sph.r, sph.r, sph.r)
            lo = sph.c0 - r
            hi = sph.c0 + r
            if moving != 0:  # swept over the shutter
                lo = wp.min(lo, sph.c1 - r)
                hi = wp.max(hi, sph.c1 + r)
        elif kind == KIND_RECT:
            q = tables.rects[w, row]
            lo = wp.min(wp.min(q.c, q.c + q.e1), wp.min(q.c + q.e2, q.c + q.e1 + q.e2))
            hi = wp.max(wp.max(q.c, q.c + q.e1), wp.max(q.c + q.e2, q.c + q.e1 + q.e2))
        elif kind == KIND_DISK:
            dk = tables.disks[w, row]
            ext = disk_extent(dk.n, dk.r)
            lo = dk.c - ext
            hi = dk.c + ext
        else:  # a solid: its box, computed when it was posed
            rec = tables.boxes[w, row]
            if kind == KIND_CAPSULE:
                rec = tables.capsules[w, row]
            elif kind == KIND_CYLINDER:
                rec = tables.cylinders[w, row]
            lo = rec.lo
            hi = rec.hi
        size = wp.max(hi - lo)
        big = wp.max(wp.max(wp.abs(lo[0]), wp.abs(lo[1])), wp.max(wp.abs(lo[2]), wp.max(wp.abs(hi[0]),
                      wp.max(wp.abs(hi[1]), wp.abs(hi[2])))))
        pad = wp.vec3(1.0) * ((size + big) * BOUNDS_PAD)
        lowers[j] = lo - pad
        uppers[j] = hi + pad

    @wp.kernel(module="warprt_worlds", enable_backward=False)
    def pose_materials(base: SceneData, colors: wp.array2d(dtype=wp.vec3), textures: wp.array2d(dtype=int),
                       n_textures: int, tables: WorldTables):
        # the scene's materials take each world's colour (kd; ka keeps its ratio to kd) and
        # texture; the rows past them (area lights' emitters) stay the scene's
        w, m = wp.tid()
        rec = base.mats[m]
        if m < colors.shape[1]:
            c = colors[w, m]
            for k in range(3):
                if rec.kd[k] > 0.0:
                    rec.ka[k] = rec.ka[k] * (c[k] / rec.kd[k])
                rec.kd[k] = c[k]
            t = textures[w, m]
            if t < -1 or t >= n_textures:
                t = -1  # (refused before the render where check_inputs is on)
            rec.tex = t
        tables.mats[w, m] = rec

    @wp.kernel(module="warprt_worlds", enable_backward=False)
    def check_looks(colors: wp.array2d(dtype=wp.vec3), textures: wp.array2d(dtype=int), n_textures: int,
                    intensities: wp.array2d(dtype=wp.vec3), first: wp.array(dtype=int)):
        # the first bad element of each: a colour or intensity that is not finite and >= 0, a
        # texture index outside [-1, n_textures)
        w, j = wp.tid()
        if j < colors.shape[1]:
            c = colors[w, j]
            if not (wp.isfinite(c) and wp.min(c) >= 0.0):
                wp.atomic_min(first, 0, w * colors.shape[1] + j)
            t = textures[w, j]
            if t < -1 or t >= n_textures:
                wp.atomic_min(first, 1, w * colors.shape[1] + j)
        if j < intensities.shape[1]:
            c = intensities[w, j]
            if not (wp.isfinite(c) and wp.min(c) >= 0.0):
                wp.atomic_min(first, 2, w * intensities.shape[1] + j)

    return pose_shapes, pose_lights, pose_cameras, world_bounds, pose_materials, check_looks


@build_once
def batch_kernel_for(F: Features, packets: bool):
    """The batched render kernel for a feature set: the single-image kernel's function for a run
    of pixels of one row, on each world's tables (one Warp module per feature set and packet
    choice, compiled on first use; ``packets``: :func:`warprt.integrator.packets_for` the device)."""
    render_pixels = kernels_for(F, packets).pixels

    @wp.kernel(module="unique", enable_backward=False, module_options=_warp.MODULE_OPTIONS)
    def batch_render(scene: SceneData, cams: wp.array(dtype=CameraData), params: RenderParams,
                     row0: int, stride: int, s0: int, s1: int, film: FilmData, tables: WorldTables,
                     n_cams: int, height: int, width: int, run: int, inv_spp: float, color: wp.array(dtype=wp.vec3),
                     block: int, aov: AovData):
        # this launch's pixels: blocks of ``block`` consecutive rows from rows row0, row0 + stride,
        # ... of the tall image (W·C·H rows; render._slices), ``run`` consecutive pixels of one row
        # per thread (``run`` divides the width); or, with stride 0 (a CPU batch's default, run =
        # the width), each thread claims the next block of ``block`` rows from the film's counter
        # (film.claim_block) until none is left. A batch renders all its samples in one pass, so
        # each pixel's colour is written here too, and its AOVs where the render asks for them.
        # The thread's pixels of a row go to render_pixels together (as in a single image): with
        # few samples a camera packet takes several pixels, and what render_pixels sets up is set
        # up once a row
        k0 = wp.tid() * run
        gy0 = int(0)
        px0 = int(0)
        rows = int(1)
        if stride == 0:  # (a last block's rows past the image's end return below)
            gy0 = claim_block(film.claims) * block
            rows = block
        else:
            k = k0 / width
            gy0 = row0 + (k / block) * stride + k % block
            px0 = k0 % width
        for r in range(rows):
            gy = gy0 + r
            image = gy / height
            if image >= cams.shape[0]:
                return
            sc = world_scene(scene, tables, image / n_cams)
            cam = cams[image]
            py = gy - image * height
            g0 = gy * width + px0
            render_pixels(sc, cam, params, px0, py, g0, run, s0, s1, film, 0, aov)
            for j in range(run):
                color[g0 + j] = film.accum[g0 + j] * inv_spp

    kernels.label(batch_render, f"the batch render kernel for {F.key}" + ("" if packets else " (rays one by one)"))
    return batch_render


def _out_dtype(name: str):
    """The numpy type of an output: an AOV's, float32 for the depth sensor's."""
    return AOVS[name].out if name in AOVS else np.float32


@dataclass
class BatchResult(Displayed):
    """A batch render: every world's and camera's image on the device (``color``, also
    ``image``), the AOVs, the samples per pixel and the metadata the images share;
    :meth:`frame` gives one image as a :class:`warprt.results.FrameResult` (numpy copies with
    that camera's matrices), which ``save_image`` writes whole. The arrays (and the cameras the
    metadata reads) are the batch's own, reused by its next render. A notebook shows the images
    as a grid (worlds down, cameras across)."""

    color: "wp.array"  # (W, C, H, Wpx) vec3 on the device: linear radiance
    spp: int
    wall_time: float  # seconds from the pose update to the image (compiles excluded)
    film: Film  # the batch's accumulation buffers (read only on demand: rays, overflows)
    aovs: dict  # requested AOVs as (W, C, H, Wpx) wp.arrays on the device (see warprt.aov)
    seed: int = 0
    scene: Scene | None = field(default=None, repr=False, compare=False)
    cameras: "wp.array | None" = field(default=None, repr=False, compare=False)  # (W·C,) CameraData of the render

    @property
    def image(self) -> "wp.array":
        """The colour: ``color`` under the name every result uses ((W, C, H, Wpx) vec3, on the device)."""
        return self.color

    @property
    def metadata(self) -> dict:
        """What the images share (:mod:`warprt.results`): spp, seed, the background and the id
        AOVs' name tables; each :meth:`frame` adds its camera's matrices."""
        meta = {"warprt_spp": self.spp, "warprt_seed": self.seed}
        if self.scene is not None:
            meta.update(scene_metadata(self.scene, self.aovs))
        return meta

    def frame(self, world: int = 0, camera: int = 0) -> FrameResult:
        """Image ``world``, ``camera`` with its AOVs (numpy copies) and metadata (the camera's
        ``worldToCamera`` / ``worldToNDC`` at shutter open, ``warprt_world``, ``warprt_camera``)."""
        W, C = self.color.shape[:2]
        for name, value, n in (("world", world, W), ("camera", camera, C)):
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or not -n <= value < n:
                raise RenderError(f"{name} must be an integer index below {n}, got {value!r:.60}")
        world, camera = int(world) % W, int(camera) % C
        image = np.array(self.color[world, camera].numpy(), copy=True)
        aovs = {name: np.array(a[world, camera].numpy(), dtype=_out_dtype(name), copy=True)
                for name, a in self.aovs.items()}
        meta = {**self.metadata, "warprt_world": world, "warprt_camera": camera}
        if self.cameras is not None:
            rec = self.cameras[world * C + camera: world * C + camera + 1].numpy()[0]
            meta["worldToCamera"], meta["worldToNDC"] = camera_record_matrices(rec)
        return FrameResult(image=image, aovs=aovs, spp=self.spp, metadata=meta)

    def _repr_png_(self) -> bytes:
        """The images in a grid (at most 8 worlds down and 8 cameras across, 2-pixel gaps)."""
        W, C, H, X = self.color.shape
        w, c = min(W, 8), min(C, 8)
        colour = self.color.numpy()
        grid = np.zeros((w * H + 2 * (w - 1), c * X + 2 * (c - 1), 3), np.float32)
        for i in range(w):
            for j in range(c):
                grid[i * (H + 2):i * (H + 2) + H, j * (X + 2):j * (X + 2) + X] = colour[i, j]
        return png_bytes(grid)

    @property
    def rays(self) -> int:
        """Camera, secondary and shadow rays traced (summed on the host when asked)."""
        return self.film.rays()

    @property
    def stack_overflows(self) -> int:
        return self.film.overflows()

    def numpy(self) -> np.ndarray:
        """The colour as numpy (W, C, H, Wpx, 3) float32: a copy (on the CPU device too, where
        ``color.numpy()`` would be a view of the buffer the next render overwrites)."""
        return np.array(self.color.numpy(), copy=True)

    def aovs_numpy(self) -> dict:
        """The AOVs as numpy copies: (W, C, H, Wpx[, channels])."""
        return {name: np.array(a.numpy(), dtype=_out_dtype(name), copy=True) for name, a in self.aovs.items()}

    @property
    def mpix_per_s(self) -> float:
        w, c, h, x = self.color.shape
        return w * c * h * x / self.wall_time / 1e6 if self.wall_time > 0 else float("nan")


def camera_quaternion(eye, look_at, up) -> np.ndarray:
    """The rotation (x, y, z, w) of the camera frame u, v, w (columns) of ``camera.py``."""
    eye, look_at, up = (np.asarray(x, np.float64) for x in (eye, look_at, up))
    w = eye - look_at
    w /= np.linalg.norm(w)
    u = np.cross(up, w)
    u /= np.linalg.norm(u)
    v = np.cross(w, u)
    m = np.stack([u, v, w], axis=1)
    return np.array(wp.quat_from_matrix(wp.mat33(*m.reshape(-1))), dtype=np.float64)


def _camera_models(cameras, scene_camera) -> list:
    """A batch's cameras (warprt.Camera, the scene camera's image size), else a RenderError."""
    if not cameras:
        raise RenderError("cameras: an empty list (give a count or at least one warprt.Camera)")
    out = []
    for i, c in enumerate(cameras):
        if not isinstance(c, Camera):
            raise RenderError(f"cameras[{i}]: expected a warprt.Camera, got {type(c).__name__}")
        if (c.width, c.height) != (scene_camera.width, scene_camera.height):
            raise RenderError(f"cameras[{i}]: {c.width}×{c.height} pixels, but a batch's images are the scene "
                              f"camera's {scene_camera.width}×{scene_camera.height}")
        out.append(c)
    return out


def _camera_pose_pair(cam) -> tuple:
    """A camera's poses (translation + quaternion) at times 0 and 1, as ``camera_poses`` holds them."""
    eye1, look1 = cam.pose(1.0)
    return (np.concatenate([cam.eye, camera_quaternion(cam.eye, cam.look_at, cam.up)]),
            np.concatenate([eye1, camera_quaternion(eye1, look1, cam.up)]))


def _camera_arrays(models, worlds: int, device) -> tuple:
    """The device arrays of a batch's cameras: the poses at times 0 and 1 in every world (W, C),
    each camera's ``fov`` entry and its record."""
    t0, t1 = zip(*(_camera_pose_pair(m) for m in models))
    poses = tuple(wp.array(np.tile(np.array(t, np.float32)[None], (worlds, 1, 1)), dtype=wp.transform, device=device)
                  for t in (t0, t1))
    fov = wp.array(np.array([_fov_entry(m) for m in models], np.float32), dtype=float, device=device)
    return (*poses, fov, wp.array([camera_data(m) for m in models], dtype=CameraData, device=device))


def _fov_entry(cam) -> float:
    """A camera's ``fov`` entry: its field of view; for one given by intrinsics (which ignores
    the entry), the vertical field of view of a pinhole with its fy, 2 atan(height / 2 fy)."""
    if cam.fov is not None:
        return cam.fov
    return math.degrees(2.0 * math.atan(cam.height / (2.0 * cam.intrinsics()[1])))


def _positive_int(value, name: str) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
        raise RenderError(f"{name} must be a positive integer, got {value!r}")
    return int(value)


class BatchRenderer:
    """W worlds × C cameras of one scene, rendered together from poses held on the device (see
    the module docstring for the pose arrays and their conventions).

    ``motion_blur=True`` samples time over the shutter between ``shape_poses`` /
    ``camera_poses`` and their ``_end`` arrays; ``features`` may widen the kernel (e.g. to keep
    one kernel across scenes). Every other distribution effect (soft shadows, depth of field,
    glossy and refractive materials) comes from the scene as in a single render.
    """

    def __init__(self, scene: Scene, worlds: int = 1, cameras: int = 1, device: str | None = None,
                 motion_blur: bool = False, features: Features | None = None, check_inputs: bool = True,
                 background_compile: bool | None = None, up_axis=None, textures=()):
        if not isinstance(scene, Scene):
            raise RenderError(f"BatchRenderer needs a warprt.Scene, got {type(scene).__name__}")
        if features is not None and not isinstance(features, Features):
            raise RenderError(f"features must be a warprt.Features, got {type(features).__name__}")
        for name, value in (("motion_blur", motion_blur), ("check_inputs", check_inputs)):
            if not isinstance(value, (bool, np.bool_)):
                raise RenderError(f"{name} must be True or False, got {value!r:.60}")
        #: check the pose arrays, light positions and fields of view on the device before each
        #: render (warprt.checks); False once a pipeline trusts what it writes there
        self.check_inputs = bool(check_inputs)
        #: the world's up axis (a unit vector; default the scene camera's ``up``): camera poses
        #: rolled against it are warned about (warprt.poses)
        self.up_axis = up_vector(scene.camera.up if up_axis is None else up_axis, "up_axis")
        self.worlds = _positive_int(worlds, "worlds")
        models = None
        if isinstance(cameras, (list, tuple)):
            models = _camera_models(cameras, scene.camera)
            cameras = len(models)
        self.cameras = _positive_int(cameras, "cameras")
        _warp.init()
        self.device = dev = _warp.resolve_device(device)
        self.scene = scene
        self.motion_blur = bool(motion_blur)
        cam = scene.camera
        self.height, self.width = cam.height, cam.width
        W, C = self.worlds, self.cameras
        pixels = W * C * cam.height * cam.width
        if pixels >= 1 << 31:
            raise RenderError(f"{W} worlds × {C} cameras × {cam.width}×{cam.height} pixels exceed 2^31 pixels per batch")
        # the film and the colour buffer of the whole batch, refused before anything is built
        check_memory(cam.width, W * C * cam.height, formats=(), film_on_host=dev.is_cpu)
        self.counters = {"rebuilds": 0, "compiles": 0, "host_transfers": 0}
        self.built = DeviceScene(scene, dev, light_buffers=False)  # (the worlds pose their lights and shapes)
        self.counters["rebuilds"] += 1
        F = self.built.features
        if self.motion_blur:
            F = F.union(Features(motion=True))
        if features is not None:
            F = F.union(features)
        if isinstance(textures, (str, Texture)) or not isinstance(textures, (list, tuple)):
            raise RenderError(f"textures must be a list of warprt.Texture (or image paths), got {textures!r:.60}")
        if textures:
            F = F.union(Features(textures=True))
        if models is not None and any(m.aperture > 0.0 for m in models):
            F = F.union(Features(lens=True))
        self.features = F
        d = self.built.data

        # per-world tables: world w starts as the scene itself
        self.tables = WorldTables()
        for name in ("spheres", "planes", "rects", "disks", "insts", "boxes", "capsules", "cylinders", "plights", "mats"):
            base = getattr(d, name)
            host = base.numpy()
            if name == "insts":
                host["n_balls"] = 0  # a world's poses and cameras are its own: no interior balls (build.py)
                host["cones"] = 0  # nor normal cones
                host["wide_cones"] = 0
            setattr(self.tables, name, wp.array(np.repeat(host[None], W, axis=0), dtype=base.dtype, device=dev))
            self.counters["host_transfers"] += 2
        self._shape_map = wp.array(np.array(self.built.shape_ids or [(0, 0)], dtype=np.int32), dtype=wp.vec2i,
                                   device=dev)
        S = len(scene.shapes)
        ident = np.zeros((W, max(S, 1), 7), np.float32)
        ident[..., 6] = 1.0
        self.shape_poses = wp.array(ident, dtype=wp.transform, device=dev)
        self.shape_poses_end = wp.array(ident, dtype=wp.transform, device=dev)
        lights = [light for light in scene.lights if isinstance(light, (PointLight, DirectionalLight))]
        pos = np.array([light.direction if isinstance(light, DirectionalLight) else light.position
                        for light in lights] or [(0.0, 0.0, 0.0)], np.float32)
        self.light_positions = wp.array(np.repeat(pos[None], W, axis=0), dtype=wp.vec3, device=dev)
        inten = np.array([light.intensity for light in lights] or [(0.0, 0.0, 0.0)], np.float32)
        #: (W, L) vec3: each world's intensity of each point and directional light
        self.light_intensities = wp.array(np.repeat(inten[None], W, axis=0), dtype=wp.vec3, device=dev)
        # the looks: each world's colour and texture of each of the scene's materials
        self.material_names = list(scene.materials)
        M = len(self.material_names)
        rows = self.built.material_rows[:M]
        #: (W, M) vec3: each world's diffuse colour kd of each material (``material_names`` order)
        self.material_colors = wp.array(np.repeat(np.array([r["kd"] for r in rows], np.float32)[None], W, axis=0),
                                        dtype=wp.vec3, device=dev)
        #: (W, M) int32: each world's texture of each material (an index into ``textures``; -1: none)
        self.material_textures = wp.array(np.repeat(np.array([r["tex"] for r in rows], np.int32)[None], W, axis=0),
                                          dtype=int, device=dev)
        self.counters["host_transfers"] += 3
        for i, t in enumerate(textures):
            try:
                self.built.textures.add(as_texture(t, f"textures[{i}]"))
            except SceneError as e:
                raise RenderError(str(e)) from None
        if textures:
            d.texs, d.texels = self.built.textures.upload(dev)
            self.counters["host_transfers"] += 2
        self._n_shapes, self._n_lights = S, len(lights)
        self._directional_lights = [int(isinstance(light, DirectionalLight)) for light in lights]
        self._light_index = [i for i, light in enumerate(scene.lights) if isinstance(light, (PointLight, DirectionalLight))]
        self.camera_models = tuple(models or [cam] * C)
        self.camera_poses, self.camera_poses_end, self.fov, self._lenses = _camera_arrays(self.camera_models, W, dev)
        self._cams = wp.zeros(W * C, dtype=CameraData, device=dev)
        self.counters["host_transfers"] += 7

        # one grouped BVH over every world's bounded analytic shapes (group = world), refitted
        # from the posed tables before each render
        self.scene_data = SceneData()
        for name in SceneData.vars:
            setattr(self.scene_data, name, getattr(d, name))
        prims = [(KIND_SPHERE, i) for i in range(d.n_spheres)] + [(KIND_RECT, i) for i in range(d.n_rects)] \
            + [(KIND_DISK, i) for i in range(d.n_disks)] + [(KIND_BOX, i) for i in range(d.n_boxes)] \
            + [(KIND_CAPSULE, i) for i in range(d.n_capsules)] + [(KIND_CYLINDER, i) for i in range(d.n_cylinders)]
        self._per_world = len(prims)
        self.bvh = None  # the worlds' BVHs (accel: one tree per world, refitted from the posed tables)
        self.scene_data.bvh_root = -1
        self._use_bvh = len(prims) >= ANALYTIC_BVH_MIN
        if self._use_bvh:
            P = len(prims)
            self._prims = wp.array(np.tile(np.array(prims, np.int32), (W, 1)), dtype=wp.vec2i, device=dev)
            self._lowers = wp.zeros(W * P, dtype=wp.vec3, device=dev)
            self._uppers = wp.zeros(W * P, dtype=wp.vec3, device=dev)
            self.counters["host_transfers"] += 2
            self._update_tables()
            lo, hi = self._lowers.numpy().reshape(W, P, 3), self._uppers.numpy().reshape(W, P, 3)
            trees = [build_tree(lo[w], hi[w]) for w in range(W)]
            # each world's primitives in its leaf order: the bounds kernel then writes them where
            # the leaves look
            leaf_order = np.concatenate([w * P + t[0] for w, t in enumerate(trees)])
            self._prims = wp.array(self._prims.numpy()[leaf_order], dtype=wp.vec2i, device=dev)
            self.bvh = forest_nodes(trees, dev)
            self.counters["rebuilds"] += 1
            self.counters["host_transfers"] += 2
            self.tables.bvh_nodes_per_world = P - 1
            self.scene_data.bvh_root = 0
            self.scene_data.bvh_nodes = self.bvh
            self.scene_data.bvh_prims = self._prims
        self.film = Film(cam.width, W * C * cam.height, dev)
        self._color = wp.zeros(pixels, dtype=wp.vec3, device=dev)
        self._own = batch_kernel_for(self.features, packets_for(dev))  # the scene's own kernel
        self._kernel = None  # the kernel renders launch: the own one, or the general one while it compiles
        self._background = None  # the own kernel compiling in the background (kernels.Background)
        self._background_compile = (kernels.background_default() if background_compile is None
                                    else bool(background_compile))
        self._aovs: AovTarget | None = None  # the last render's AOV buffers (kept while it asks for the same)
        self._pool = WorkerPool("warprt-batch")

    def _pick_kernel(self) -> None:
        """Load the kernel this render launches, from this thread (the workers must not race to
        build it): the scene's own once it is loaded or in Warp's cache; while it is not, with
        background compiles on and the general batch kernel (``Features.full()``: the same images
        bit for bit) cached, that one, while the own one compiles in the background (as
        ``Renderer`` does; the render after it is ready takes it up)."""
        own = self._own
        if self._kernel is own:
            return
        bg = self._background
        if bg is not None and bg.ready():
            self._kernel, self._background = own, None
            self.counters["compiles"] += 1
            return
        if self._kernel is not None:
            return  # (the general kernel, while the own one compiles)
        general = batch_kernel_for(GENERAL_FEATURES, packets_for(self.device))
        if (self._background_compile and own is not general and not kernels.module_cached(own, self.device)
                and kernels.module_cached(general, self.device)):
            self._background = kernels.Background(own, self.device)
            kernels.load(general, self.device)
            self._kernel = general
        else:
            kernels.load(own, self.device)
            self._kernel = own
        self.counters["compiles"] += 1

    # --- poses ------------------------------------------------------------------------------

    def _check_poses(self, values, shape: tuple, name: str) -> "wp.array":
        """``values`` as a (shape) wp.array of transforms on this device: a wp.array of
        wp.transform, or of 4×4 matrices (rigid: rotation and translation), or numpy (..., 7)
        (x, y, z, qx, qy, qz, qw) or (..., 4, 4)."""
        if isinstance(values, wp.array):
            if values.device != self.device:
                raise RenderError(f"{name}: the array is on {values.device}, the renderer on {self.device}")
            if values.dtype == wp.transform and tuple(values.shape) == shape:
                return values
            if values.dtype == wp.mat44 and tuple(values.shape) == shape:
                out = wp.empty(shape, dtype=wp.transform, device=self.device)
                wp.launch(_matrix_kernel(), dim=shape, inputs=[values, out], device=self.device)
                return out
            raise RenderError(f"{name}: expected a wp.array of wp.transform or wp.mat44 shaped {shape}, "
                              f"got {values.dtype.__name__} {tuple(values.shape)}")
        if isinstance(values, (str, bytes)) or values is None:
            raise RenderError(f"{name}: expected poses shaped {shape + (7,)} (position, quaternion x y z w) or "
                              f"{shape + (4, 4)} (matrices), a numpy array or a wp.array, got {values!r:.60}")
        try:
            a = np.asarray(values, dtype=np.float64)
        except (TypeError, ValueError):
            raise RenderError(f"{name}: expected numbers shaped {shape + (7,)} (position, quaternion x y z w) or "
                              f"{shape + (4, 4)} (matrices), got {type(values).__name__}") from None
        if a.shape == shape + (4, 4):
            a = _rigid_from_matrices(a, name)
        if a.shape != shape + (7,):
            raise RenderError(f"{name}: expected values shaped {shape + (7,)} (position, quaternion x y z w) "
                              f"or {shape + (4, 4)} (matrices), got {a.shape}")
        bad = ~np.isfinite(a).all(axis=-1) | (np.abs(np.nan_to_num(a[..., :3])) > EXTENT_LIMIT).any(axis=-1)
        if bad.any():
            index = tuple(int(x) for x in np.argwhere(bad)[0])
            raise RenderError(f"{name}[{', '.join(map(str, index))}]: {describe_transform(a[index])}")
        q = a[..., 3:]
        norms = np.linalg.norm(q, axis=-1, keepdims=True)
        if (norms == 0).any():
            index = tuple(int(x) for x in np.argwhere(norms[..., 0] == 0)[0])
            raise RenderError(f"{name}[{', '.join(map(str, index))}]: a quaternion is zero")
        a = np.concatenate([a[..., :3], q / norms], axis=-1)
        self.counters["host_transfers"] += 1
        return wp.array(a.astype(np.float32), dtype=wp.transform, device=self.device)

    def set_shape_poses(self, poses, end=None) -> None:
        """Poses of every shape in every world, (W, S) (see the module docstring); ``end``: at
        shutter close (default: the same)."""
        shape = (self.worlds, self._n_shapes)
        wp.copy(self.shape_poses, self._check_poses(poses, shape, "shape_poses"))
        wp.copy(self.shape_poses_end, self._check_poses(poses if end is None else end, shape, "shape_poses_end"))

    def set_cameras(self, cameras) -> None:
        """Each of the C cameras' model from a list of ``warprt.Camera`` (intrinsics, distortion,
        orthographic, aperture, shutter, rolling shutter; image size as the scene's), and its
        pose and field of view from the camera's own; no rebuild, no recompile."""
        models = _camera_models(cameras, self.scene.camera)
        if len(models) != self.cameras:
            raise RenderError(f"cameras: {len(models)} cameras given for a batch of {self.cameras}")
        if not self.features.lens and any(m.aperture > 0.0 for m in models):
            raise RenderError("cameras: a thin lens (aperture > 0) in a batch built without one (give the cameras "
                              "when the BatchRenderer is made, or features=warprt.Features(lens=True))")
        for array, made in zip((self.camera_poses, self.camera_poses_end, self.fov, self._lenses),
                               _camera_arrays(models, self.worlds, self.device)):
            wp.copy(array, made)
        self.camera_models = tuple(models)

    def set_camera_poses(self, poses, end=None) -> None:
        """Camera-to-world poses, (W, C) (the camera looks along its local -z, +y up; make them
        with :func:`warprt.look_at`); ``end``: at shutter close (default: the same). Poses given
        on the host and rolled against ``up_axis`` by more than 45° are warned about
        (:class:`warprt.poses.CameraRollWarning`)."""
        shape = (self.worlds, self.cameras)
        start = self._check_poses(poses, shape, "camera_poses")
        close = self._check_poses(poses if end is None else end, shape, "camera_poses_end")
        for name, given, checked in (("camera_poses", poses, start), ("camera_poses_end", end, close)):
            if given is not None and not isinstance(given, wp.array):  # (device arrays are not read back)
                warn_rolled(checked.numpy(), self.up_axis, name)
        wp.copy(self.camera_poses, start)
        wp.copy(self.camera_poses_end, close)

    # --- looks: colours, textures, light intensities -------------------------------------------

    @property
    def textures(self) -> list:
        """The textures ``material_textures`` indexes: the scene's own, then those given to the
        constructor or to :meth:`add_texture`, in that order."""
        return list(self.built.textures.textures)

    def material_index(self, material) -> int:
        """The column of ``material`` (a name in ``scene.materials``, or an index) in
        ``material_colors`` and ``material_textures``."""
        if isinstance(material, str):
            if material not in self.material_names:
                raise RenderError(f"unknown material {material!r} (known: {', '.join(self.material_names)})")
            return self.material_names.index(material)
        if isinstance(material, bool) or not isinstance(material, (int, np.integer)) \
                or not 0 <= material < len(self.material_names):
            raise RenderError(f"material must be a name or an index below {len(self.material_names)}, "
                              f"got {material!r:.60}")
        return int(material)

    def add_texture(self, texture) -> int:
        """Add a texture (a :class:`warprt.Texture`, an image path or a table of its fields) to
        those ``material_textures`` may name and return its index. Its texels are copied to the
        device (the pool grows: no rebuild, no recompile); the kernel must have the textures
        feature: a scene with a texture, ``textures=[...]`` given to the constructor, or
        ``features=Features(textures=True)``."""
        if not self.features.textures:
            raise RenderError("this batch's kernel has no texture code: give the constructor textures=[...] "
                              "(or features=warprt.Features(textures=True)) to switch textures between frames")
        try:
            tex = as_texture(texture, "texture")
        except SceneError as e:
            raise RenderError(str(e)) from None
        if tex is None:
            raise RenderError("add_texture needs a texture, got None")
        index = self.built.textures.add(tex)
        d = self.built.data
        d.texs, d.texels = self.built.textures.upload(self.device)
        self.scene_data.texs, self.scene_data.texels = d.texs, d.texels
        self.counters["host_transfers"] += 2
        return index

    def _looks_array(self, values, shape: tuple, name: str, dtype) -> "wp.array":
        """``values`` (numpy, or a wp.array of ``dtype`` shaped ``shape`` on this device) as a wp.array."""
        if isinstance(values, wp.array):
            if values.device != self.device or values.dtype != dtype or tuple(values.shape) != shape:
                raise RenderError(f"{name}: expected a wp.array of {dtype.__name__} shaped {shape} on {self.device}, "
                                  f"got {getattr(values.dtype, '__name__', values.dtype)} {tuple(values.shape)} on "
                                  f"{values.device}")
            return values
        try:
            a = np.asarray(values, dtype=np.float64)
        except (TypeError, ValueError):
            raise RenderError(f"{name}: expected numbers, got {type(values).__name__}") from None
        full = shape + ((3,) if dtype == wp.vec3 else ())
        if a.shape != full:
            try:
                a = np.broadcast_to(a, full)
            except ValueError:
                raise RenderError(f"{name}: expected values shaped {full} (or broadcastable to it), got {a.shape}") from None
        if dtype == wp.vec3:
            bad = ~np.isfinite(a).all(axis=-1) | (np.nan_to_num(a, nan=-1.0) < 0).any(axis=-1)
        else:
            bad = (a != np.round(a)) | (a < -1) | (a >= len(self.built.textures))
        if bad.any():
            index = ", ".join(map(str, np.argwhere(bad)[0]))
            what = ("a colour must be finite and >= 0" if dtype == wp.vec3 else
                    f"a texture index must be -1 (none) or below {len(self.built.textures)} (the textures)")
            raise RenderError(f"{name}[{index}]: {what}, got {a[tuple(np.argwhere(bad)[0])].tolist()}")
        self.counters["host_transfers"] += 1
        return wp.array(np.ascontiguousarray(a, dtype=np.float32 if dtype == wp.vec3 else np.int32), dtype=dtype,
                        device=self.device)

    def set_material_colors(self, colors) -> None:
        """Each world's diffuse colour kd of each material, (W, M, 3) linear RGB (or anything that
        broadcasts to it: (M, 3) for every world alike); ``ka`` keeps its ratio to kd per channel."""
        shape = (self.worlds, len(self.material_names))
        wp.copy(self.material_colors, self._looks_array(colors, shape, "material_colors", wp.vec3))

    def set_material_textures(self, indices) -> None:
        """Each world's texture of each material, (W, M) indices into :attr:`textures` (-1: none;
        broadcast like the colours). It multiplies kd and ka as the material's ``texture`` does."""
        if not self.features.textures:
            raise RenderError("this batch's kernel has no texture code: give the constructor textures=[...] "
                              "(or features=warprt.Features(textures=True))")
        shape = (self.worlds, len(self.material_names))
        wp.copy(self.material_textures, self._looks_array(indices, shape, "material_textures", int))

    def set_light_intensities(self, intensities) -> None:
        """Each world's intensity of each point and directional light, (W, L, 3) (broadcast like
        the colours; L as ``light_positions``)."""
        wp.copy(self.light_intensities,
                self._looks_array(intensities, (self.worlds, max(self._n_lights, 1)), "light_intensities", wp.vec3))

    def _check_looks(self, first: "wp.array") -> None:
        """Launch the check of the looks' arrays on the device: the first bad element of each
        into ``first`` (three ints, NONE where none; read with the poses' check, warprt.checks)."""
        W, M, L = self.worlds, len(self.material_names), max(self._n_lights, 1)
        wp.launch(_pose_kernels()[5], dim=(W, max(M, L)), device=self.device,
                  inputs=[self.material_colors, self.material_textures, len(self.built.textures),
                          self.light_intensities, first])

    def _looks_problems(self, found) -> list:
        """What ``_check_looks`` found, as messages naming each array's first bad element."""
        problems = []
        for slot, (name, n) in enumerate((("material_colors", len(self.material_names)),
                                          ("material_textures", len(self.material_names)),
                                          ("light_intensities", max(self._n_lights, 1)))):
            if found[slot] != NONE:
                w, j = divmod(int(found[slot]), n)
                value = getattr(self, name)[w:w + 1].numpy()[0][j]
                what = (f"a texture index must be -1 (none) or below {len(self.built.textures)}"
                        if slot == 1 else "must be finite and >= 0")
                problems.append(f"{name}[{w}, {j}]: {what}, got {np.asarray(value).tolist()}")
        return problems

    def _check_arrays(self) -> None:
        """The pose arrays are attributes a pipeline may replace: each must still be a wp.array
        of its dtype and shape on this device (else a RenderError naming it, not Warp's)."""
        W, C = self.worlds, self.cameras
        for name, dtype, shape in (("shape_poses", wp.transform, (W, max(self._n_shapes, 1))),
                                   ("shape_poses_end", wp.transform, (W, max(self._n_shapes, 1))),
                                   ("camera_poses", wp.transform, (W, C)), ("camera_poses_end", wp.transform, (W, C)),
                                   ("light_positions", wp.vec3, (W, max(self._n_lights, 1))), ("fov", float, (C,)),
                                   ("light_intensities", wp.vec3, (W, max(self._n_lights, 1))),
                                   ("material_colors", wp.vec3, (W, len(self.material_names))),
                                   ("material_textures", wp.int32, (W, len(self.material_names)))):
            a = getattr(self, name)
            if not isinstance(a, wp.array) or a.dtype != (wp.float32 if dtype is float else dtype) \
                    or tuple(a.shape) != shape or a.device != self.device or not a.is_contiguous:
                got = (f"{getattr(a.dtype, '__name__', a.dtype)} {tuple(a.shape)} on {a.device}"
                       if isinstance(a, wp.array) else type(a).__name__)
                raise RenderError(f"{name}: expected a contiguous wp.array of {getattr(dtype, '__name__', dtype)} "
                                  f"shaped {shape} on {self.device}, got {got} (write into it in place, "
                                  "e.g. with wp.copy)")

    def _update_tables(self) -> None:
        pose_shapes, pose_lights, pose_cameras, world_bounds, pose_materials, _ = _pose_kernels()
        dev, d = self.device, self.built.data
        end = self.shape_poses_end if self.motion_blur else self.shape_poses
        if self._n_shapes:
            wp.launch(pose_shapes, dim=(self.worlds, self._n_shapes), device=dev,
                      inputs=[d, self._shape_map, self.shape_poses, end, self.tables])
        if self._n_lights:
            wp.launch(pose_lights, dim=(self.worlds, self._n_lights), device=dev,
                      inputs=[d, self.light_positions, self.light_intensities, self.tables])
        wp.launch(pose_materials, dim=(self.worlds, d.mats.shape[0]), device=dev,
                  inputs=[d, self.material_colors, self.material_textures, len(self.built.textures), self.tables])
        cam_end = self.camera_poses_end if self.motion_blur or self.scene.camera.moves else self.camera_poses
        wp.launch(pose_cameras, dim=(self.worlds, self.cameras), device=dev,
                  inputs=[self._lenses, self.camera_poses, cam_end, self.fov, self._cams])
        if self._use_bvh:
            wp.launch(world_bounds, dim=self.worlds * self._per_world, device=dev,
                      inputs=[self.tables, self._prims, self._per_world, int(self.features.motion), self._lowers,
                              self._uppers])

    # --- rendering --------------------------------------------------------------------------

    def close(self) -> None:
        """Stop the worker threads (they also stop when the renderer is garbage-collected)."""
        self._pool.close()

    def render(self, spp: int = 1, seed: int = 0, *, aovs=(), workers: int | None = None,
               slices: int | None = None) -> BatchResult:
        """Render every world and camera with ``spp`` samples per pixel from the current pose
        arrays. The colour stays on the device: ``BatchResult.color`` is a (W, C, H, Wpx) vec3
        ``wp.array`` (``.numpy()`` gives (W, C, H, Wpx, 3) float32; DLPack shares it with torch
        or JAX); ``aovs`` (names of ``warprt.aov.AOVS``, and ``sensor_z`` / ``sensor_depth`` with
        the scene's ``depth_sensor``: ``warprt.sensor``) come in ``BatchResult.aovs`` the same
        way, averaged over the colour's samples. The arrays are reused by the next render: copy
        them to keep them."""
        asked, aovs, sensor_names = split_aovs(aovs, self.scene)  # (the depth sensor's: warprt.sensor)
        spp = _positive_int(spp, "spp")
        if spp > SPP_LIMIT:
            raise RenderError(f"spp must be <= {SPP_LIMIT}, got {spp}")
        check_seed(seed)
        workers = default_workers() if workers is None else _positive_int(workers, "workers")
        dev = self.device
        self._check_arrays()
        if self.check_inputs:  # NaN poses, non-unit quaternions, a zero fov: named, before rendering
            check_batch(self, self.shape_poses_end if self.motion_blur else self.shape_poses,
                        self.camera_poses_end if self.motion_blur or self.scene.camera.moves else self.camera_poses)
        rows = self.worlds * self.cameras * self.height
        # (None: on the CPU one launch per worker, claiming blocks of rows from the film's counter;
        # slices=N: N fixed interleaved sets of blocks)
        n_slices = (None if slices is None else _positive_int(slices, "slices")) if dev.is_cpu else 1
        params = render_params(self.scene, spp, int(seed), self.features)
        run = pixels_per_thread(dev, self.width)
        inputs = [self.scene_data, self._cams, params, 0, 1, 0, 0, self.film.data, self.tables, self.cameras,
                  self.height, self.width, run, 1.0 / float(spp), self._color, 1, no_aovs(dev)]
        self._pick_kernel()
        # the AOVs come from the render's own samples (warprt.aov): its one pass, which takes every
        # sample, writes them
        target = None
        if aovs:
            target = self._aovs
            if target is None or target.names != aovs:
                self._aovs = None  # (its buffers freed before the new ones are made)
                target = self._aovs = AovTarget(self.built, aovs, self._color.shape[0], spp)
            target.data.end = spp
            params.aovs = target.mask
            inputs[AOV_ARG] = target.data
        start = _time.perf_counter()
        self._update_tables()
        if self.bvh is not None:
            wp.launch(refit_kernel, dim=self.worlds, device=dev,
                      inputs=[self.bvh, self._lowers, self._uppers, self._per_world - 1])
        # (every pixel starts its film sums at sample 0: no zeroing; stride 0: the launches claim
        # blocks of rows, a thread per block in case one launch takes them all)
        if n_slices is None and run >= self.width:
            args = list(inputs)
            args[4], args[BLOCK_ARG] = 0, SLICE_BLOCK
            launches = [wp.launch(self._kernel, dim=-(-rows // SLICE_BLOCK), device=dev, inputs=args, record_cmd=True)
                        for _ in range(workers)]
            self.film.reset_claims()
        else:
            launches = []
            for first, stride, block, count in _slices(self.width, rows,
                                                       SLICES_PER_WORKER * workers if n_slices is None else n_slices):
                args = list(inputs)
                args[3], args[4], args[BLOCK_ARG] = first, stride, block
                launches.append(wp.launch(self._kernel, dim=count // run, device=dev, inputs=args, record_cmd=True))
        run_pass(self._pool.get(workers), launches, workers, 0, spp)
        shape = (self.worlds, self.cameras, self.height, self.width)
        aov_maps = {} if target is None else target.maps(shape, as_warp=True)
        if sensor_names:
            self._sensor_out = made = apply_depth_sensor(
                self.scene.depth_sensor, {n: getattr(target.data.out, n) for n in target.names},
                self.camera_poses.reshape(-1), self.height * self.width, int(seed), sensor_names,
                getattr(self, "_sensor_out", None), ortho=[m.model == "orthographic" for m in self.camera_models])
            aov_maps.update({name: a.reshape(shape) for name, a in made.items()})
            aov_maps = {name: aov_maps[name] for name in asked}
        wp.synchronize_device(dev)
        wall = _time.perf_counter() - start
        return BatchResult(color=self._color.reshape(shape), spp=spp, wall_time=wall, film=self.film, aovs=aov_maps,
                           seed=int(seed), scene=self.scene, cameras=self._cams)


@build_once
def _matrix_kernel():
    @wp.kernel(module="warprt_worlds", enable_backward=False)
    def matrices_to_transforms(m: wp.array2d(dtype=wp.mat44), out: wp.array2d(dtype=wp.transform)):
        i, j = wp.tid()
        a = m[i, j]
        r = wp.mat33(a[0, 0], a[0, 1], a[0, 2], a[1, 0], a[1, 1], a[1, 2], a[2, 0], a[2, 1], a[2, 2])
        out[i, j] = wp.transform(wp.vec3(a[0, 3], a[1, 3], a[2, 3]), wp.normalize(wp.quat_from_matrix(r)))

    return matrices_to_transforms


def _rigid_from_matrices(m: np.ndarray, name: str) -> np.ndarray:
    """(..., 4, 4) rigid matrices as (..., 7) position + quaternion (x, y, z, w), checked."""
    r = m[..., :3, :3]
    eye = np.eye(3)
    if not np.isfinite(m).all():
        raise RenderError(f"{name}: a matrix is not finite")
    if not np.allclose(m[..., 3, :], [0, 0, 0, 1], atol=1e-6):
        raise RenderError(f"{name}: the last row of a pose matrix must be [0, 0, 0, 1]")
    if not np.allclose(np.swapaxes(r, -1, -2) @ r, eye, atol=1e-4) or (np.linalg.det(r) < 0).any():
        raise RenderError(f"{name}: a pose matrix must be a rotation and a translation (no scale, shear or mirror)")
    flat = r.reshape(-1, 3, 3)
    q = np.array([wp.quat_from_matrix(wp.mat33(*x.reshape(-1))) for x in flat], np.float64).reshape(r.shape[:-2] + (4,))
    return np.concatenate([m[..., :3, 3], q], axis=-1)
