"""Arbitrary output variables (AOVs): per-pixel geometry next to the colour.

Every AOV comes from one ray per pixel, through the pixel centre, from the lens centre, at
shutter open. Nothing is averaged, so integer ids never blend at object edges and a depth is
always the depth of a real surface. Misses get ``inf`` depths, zero vectors and id -1.

========= ======= =====================================================================
name      shape   meaning
========= ======= =====================================================================
depth     (H, W)  distance from the eye along the ray (scene units)
z         (H, W)  camera-space depth: distance along the viewing axis -w
normal    (H,W,3) unit world shading normal, turned towards the camera
albedo    (H,W,3) the diffuse reflectance kd of the surface (Le for an area light)
position  (H,W,3) world position of the hit
object_id (H, W)  index into ``scene.shapes``; area lights are len(shapes) + light index
material  (H, W)  index into ``scene.materials`` (in insertion order); -1 for lights
motion    (H,W,2) screen-space motion in pixels (x right, y down) of the visible point from
                  shutter open to shutter close (objects and camera both move)
========= ======= =====================================================================
"""

from __future__ import annotations

import threading

import numpy as np
import warp as wp

from .build import (
    KIND_DISK, KIND_MESH, KIND_NONE, KIND_PLANE, KIND_RECT, KIND_SPHERE, LIGHT_DISK, LIGHT_RECT, LIGHT_SPHERE, CameraData,
    DeviceScene, Features, SceneData,
)
from .errors import RenderError
from .integrator import camera_ray, kernels_for
from .scene.description import DiskLight, RectLight, SphereLight

AOV_NAMES = ("depth", "z", "normal", "albedo", "position", "object_id", "material", "motion")

_lock = threading.Lock()
_kernel: list = []


@wp.func
def camera_frame_w(cam: CameraData, time: float) -> wp.vec3:
    eye = cam.eye0 + (cam.eye1 - cam.eye0) * time
    look = cam.look0 + (cam.look1 - cam.look0) * time
    return wp.normalize(eye - look)


@wp.func
def project(cam: CameraData, p: wp.vec3, time: float) -> wp.vec2:
    """Raster position (pixels, y down) of world point p seen by the camera at ``time``."""
    eye = cam.eye0 + (cam.eye1 - cam.eye0) * time
    w = camera_frame_w(cam, time)
    u = wp.normalize(wp.cross(cam.up, w))
    v = wp.cross(w, u)
    q = p - eye
    zc = -wp.dot(q, w)
    if zc <= 0.0:
        return wp.vec2(0.0, 0.0)
    us = wp.dot(q, u) * cam.dist / zc
    vs = wp.dot(q, v) * cam.dist / zc
    return wp.vec2((us + cam.right) / (2.0 * cam.right) * float(cam.width),
                   (cam.top - vs) / (2.0 * cam.top) * float(cam.height))


def _aov_kernel():
    with _lock:
        if _kernel:
            return _kernel[0]
        fns = kernels_for(Features.full())

        @wp.kernel(module="warprt_query", enable_backward=False)
        def aov_kernel(scene: SceneData, cam: CameraData, out_t: wp.array(dtype=float), out_z: wp.array(dtype=float),
                       out_n: wp.array(dtype=wp.vec3), out_albedo: wp.array(dtype=wp.vec3),
                       out_p: wp.array(dtype=wp.vec3), out_kind: wp.array(dtype=int), out_index: wp.array(dtype=int),
                       out_mat: wp.array(dtype=int), out_motion: wp.array(dtype=wp.vec2)):
            tid = wp.tid()
            px = tid % cam.width
            py = tid / cam.width
            t0 = cam.t_open
            ray = camera_ray(cam, float(px) + 0.5, float(py) + 0.5, wp.vec2(0.5, 0.5), t0)
            h = fns.closest_hit(scene, ray.o, ray.d, 0.0, 3.0e38, t0)
            out_kind[tid] = h.kind
            out_index[tid] = h.index
            if h.kind == KIND_NONE:
                out_t[tid] = wp.inf
                out_z[tid] = wp.inf
                out_mat[tid] = -1
                return
            out_t[tid] = h.t
            out_z[tid] = h.t * -wp.dot(ray.d, camera_frame_w(cam, t0))
            n = h.ns
            if wp.dot(n, ray.d) > 0.0:
                n = -n
            out_n[tid] = n
            out_p[tid] = h.p
            out_mat[tid] = h.mat
            m = scene.mats[h.mat]
            if wp.max(m.emit) > 0.0:
                out_albedo[tid] = m.emit
            else:
                out_albedo[tid] = m.kd
            # where the visible point is at shutter close
            t1 = cam.t_close
            p1 = h.p
            if h.kind == KIND_SPHERE:
                p1 = h.p + fns.sphere_center(scene, h.index, t1) - fns.sphere_center(scene, h.index, t0)
            elif h.kind == KIND_MESH:
                pos0 = fns.instance_pos(scene, h.index, t0)
                rot0 = fns.instance_rot(scene, h.index, t0)
                scl0 = fns.instance_scl(scene, h.index, t0)
                p_obj = wp.cw_div(wp.quat_rotate_inv(rot0, h.p - pos0), scl0)
                p1 = wp.quat_rotate(fns.instance_rot(scene, h.index, t1),
                                    wp.cw_mul(p_obj, fns.instance_scl(scene, h.index, t1))) + fns.instance_pos(scene, h.index, t1)
            out_motion[tid] = project(cam, p1, t1) - project(cam, h.p, t0)

        _kernel.append(aov_kernel)
        return aov_kernel


def _object_lookup(built: DeviceScene) -> dict[int, np.ndarray]:
    """Per shape kind, a table from the kind's row index to the object id."""
    scene = built.scene
    sizes = {KIND_SPHERE: built.data.n_spheres, KIND_RECT: built.data.n_rects, KIND_DISK: built.data.n_disks,
             KIND_MESH: built.data.n_inst, KIND_PLANE: built.data.n_planes}
    tables = {k: np.full(max(n, 1), -1, np.int64) for k, n in sizes.items()}
    for obj, (kind, row) in enumerate(built.shape_ids):
        tables[kind][row] = obj
    light_kind = {LIGHT_RECT: KIND_RECT, LIGHT_SPHERE: KIND_SPHERE, LIGHT_DISK: KIND_DISK}
    area = [i for i, l in enumerate(scene.lights) if isinstance(l, (RectLight, SphereLight, DiskLight))]
    for (kind, row, *_), light_index in zip(built.area_lights, area):
        tables[light_kind[kind]][row] = len(scene.shapes) + light_index
    return tables


def compute_aovs(built: DeviceScene, names) -> dict[str, np.ndarray]:
    """The requested AOVs of a built scene as numpy arrays (see the module docstring)."""
    names = list(dict.fromkeys(names))
    unknown = [n for n in names if n not in AOV_NAMES]
    if unknown:
        raise RenderError(f"unknown AOV(s) {', '.join(map(repr, unknown))}; available: {', '.join(AOV_NAMES)}")
    cam = built.scene.camera
    n, dev = cam.width * cam.height, built.device
    bufs = [wp.zeros(n, dtype=t, device=dev) for t in (float, float, wp.vec3, wp.vec3, wp.vec3, int, int, int, wp.vec2)]
    wp.launch(_aov_kernel(), dim=n, device=dev, inputs=[built.data, built.camera, *bufs])
    t, z, normal, albedo, pos, kind, index, mat, motion = (b.numpy() for b in bufs)
    hw = (cam.height, cam.width)
    out: dict[str, np.ndarray] = {}
    for name in names:
        if name == "depth":
            out[name] = t.reshape(hw).astype(np.float32)
        elif name == "z":
            out[name] = z.reshape(hw).astype(np.float32)
        elif name == "normal":
            out[name] = normal.reshape(*hw, 3).astype(np.float32)
        elif name == "albedo":
            out[name] = albedo.reshape(*hw, 3).astype(np.float32)
        elif name == "position":
            out[name] = pos.reshape(*hw, 3).astype(np.float32)
        elif name == "motion":
            out[name] = motion.reshape(*hw, 2).astype(np.float32)
        elif name == "object_id":
            tables = _object_lookup(built)
            ids = np.full(n, -1, np.int64)
            for k, table in tables.items():
                sel = kind == k
                ids[sel] = table[index[sel]]
            out[name] = ids.reshape(hw).astype(np.int32)
        elif name == "material":
            n_user = len(built.scene.materials)
            out[name] = np.where((mat >= 0) & (mat < n_user), mat, -1).reshape(hw).astype(np.int32)
    return out
