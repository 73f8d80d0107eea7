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

from dataclasses import dataclass

import numpy as np
import warp as wp

from ._warp import build_once
from .build import DeviceScene
from .camera import camera_frame_w, camera_ray, project
from .errors import RenderError
from .records import KIND_MESH, KIND_NONE, KIND_SPHERE, CameraData, Features, SceneData
from .scene.description import is_area_light
from .trace import make_trace, to_object, to_world


@dataclass(frozen=True)
class AovSpec:
    dtype: object  # the device buffer's element type
    channels: int  # 1, 2 or 3
    out: type  # numpy dtype of the result


# one entry per AOV: the kernel writes the buffers in this order, compute_aovs reads them by name
AOVS = {
    "depth": AovSpec(float, 1, np.float32),
    "z": AovSpec(float, 1, np.float32),
    "normal": AovSpec(wp.vec3, 3, np.float32),
    "albedo": AovSpec(wp.vec3, 3, np.float32),
    "position": AovSpec(wp.vec3, 3, np.float32),
    "object_id": AovSpec(int, 1, np.int32),
    "material": AovSpec(int, 1, np.int32),
    "motion": AovSpec(wp.vec2, 2, np.float32),
}
AOV_NAMES = tuple(AOVS)


@wp.struct
class AovBuffers:
    depth: wp.array(dtype=float)
    z: wp.array(dtype=float)
    normal: wp.array(dtype=wp.vec3)
    albedo: wp.array(dtype=wp.vec3)
    position: wp.array(dtype=wp.vec3)
    kind: wp.array(dtype=int)  # object_id is decoded on the host from (kind, row)
    row: wp.array(dtype=int)
    material: wp.array(dtype=int)
    motion: wp.array(dtype=wp.vec2)


@build_once
def _aov_kernel():
    trace = make_trace(Features.full())
    closest_hit, sphere_center, instance_pose = trace.closest_hit, trace.sphere_center, trace.instance_pose

    @wp.kernel(module="warprt_aov", enable_backward=False)
    def aov_kernel(scene: SceneData, cam: CameraData, out: AovBuffers):
        tid = wp.tid()
        px = tid % cam.width
        py = tid / cam.width
        t0 = cam.t_open
        ray = camera_ray(cam, float(px) + 0.5, float(py) + 0.5, wp.vec2(0.5, 0.5), t0)
        h = closest_hit(scene, ray.o, ray.d, 0.0, 3.0e38, t0)
        out.kind[tid] = h.kind
        out.row[tid] = h.index
        if h.kind == KIND_NONE:
            out.depth[tid] = wp.inf
            out.z[tid] = wp.inf
            out.material[tid] = -1
            return
        out.depth[tid] = h.t
        out.z[tid] = h.t * -wp.dot(ray.d, camera_frame_w(cam, t0))
        n = h.ns
        if wp.dot(n, ray.d) > 0.0:
            n = -n
        out.normal[tid] = n
        out.position[tid] = h.p
        out.material[tid] = h.mat
        m = scene.mats[h.mat]
        if wp.max(m.emit) > 0.0:
            out.albedo[tid] = m.emit
        else:
            out.albedo[tid] = m.kd
        # where the visible point is at shutter close
        t1 = cam.t_close
        p1 = h.p
        if h.kind == KIND_SPHERE:
            p1 = h.p + sphere_center(scene, h.index, t1) - sphere_center(scene, h.index, t0)
        elif h.kind == KIND_MESH:
            p1 = to_world(instance_pose(scene, h.index, t1), to_object(instance_pose(scene, h.index, t0), h.p))
        out.motion[tid] = project(cam, p1, t1) - project(cam, h.p, t0)

    return aov_kernel


def _object_ids(built: DeviceScene, kind: np.ndarray, row: np.ndarray) -> np.ndarray:
    """Object id per pixel from (kind, row): the shape's index in ``scene.shapes``, or
    len(shapes) + light index for an area light's own surface, -1 for a miss."""
    owner = {key: obj for obj, key in enumerate(built.shape_ids)}
    lights = [i for i, light in enumerate(built.scene.lights) if is_area_light(light)]
    for rec, light_index in zip(built.area_lights, lights):
        owner[(rec["kind"], rec["shape"])] = len(built.scene.shapes) + light_index
    keys = kind.astype(np.int64) * (1 << 32) + row.astype(np.int64)
    uniq, inverse = np.unique(keys, return_inverse=True)
    ids = np.array([owner.get((int(k >> 32), int(k & 0xFFFFFFFF)), -1) for k in uniq], dtype=np.int64)
    return ids[inverse]


def compute_aovs(built: DeviceScene, names) -> dict[str, np.ndarray]:
    """The requested AOVs of a built scene as numpy arrays (see the module docstring)."""
    names = list(dict.fromkeys(names))
    unknown = [n for n in names if n not in AOVS]
    if unknown:
        raise RenderError(f"unknown AOV(s) {', '.join(map(repr, unknown))}; available: {', '.join(AOV_NAMES)}")
    cam = built.scene.camera
    n, dev = cam.width * cam.height, built.device
    bufs = AovBuffers()
    for name in ("depth", "z", "normal", "albedo", "position", "material", "motion"):
        setattr(bufs, name, wp.zeros(n, dtype=AOVS[name].dtype, device=dev))
    bufs.kind = wp.zeros(n, dtype=int, device=dev)
    bufs.row = wp.zeros(n, dtype=int, device=dev)
    wp.launch(_aov_kernel(), dim=n, device=dev, inputs=[built.data, built.camera, bufs])
    out: dict[str, np.ndarray] = {}
    for name in names:
        spec = AOVS[name]
        shape = (cam.height, cam.width) + ((spec.channels,) if spec.channels > 1 else ())
        if name == "object_id":
            values = _object_ids(built, bufs.kind.numpy(), bufs.row.numpy())
        elif name == "material":
            mat = bufs.material.numpy()
            values = np.where((mat >= 0) & (mat < len(built.scene.materials)), mat, -1)  # -1: lights, misses
        else:
            values = getattr(bufs, name).numpy()
        out[name] = values.reshape(shape).astype(spec.out)
    return out
