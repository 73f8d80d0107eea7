"""The camera on the device: rays through raster points, the viewing axis, projection.

Conventions: the camera looks along -w, w = normalize(eye - look_at), u = normalize(up × w),
v = w × u; the image plane lies at distance D along -w with half height D·tan(fov/2) and half
width that times width/height; raster y runs down from the top row. Eye and look-at are given at
times 0 and 1 (camera motion) and interpolated linearly.
"""

from __future__ import annotations

import math

import numpy as np
import warp as wp

from .accel import PacketF
from .records import CameraData
from .sampling import square_to_disk
from .scene.description import Scene


@wp.struct
class Ray:
    o: wp.vec3
    d: wp.vec3


@wp.struct
class CameraFrame:
    """The camera's eye and axes at one time (``camera_frame``)."""
    eye: wp.vec3
    u: wp.vec3
    v: wp.vec3
    w: wp.vec3


@wp.func(inline=True)
def camera_frame(cam: CameraData, time: float) -> CameraFrame:
    """Eye, u, v and w at ``time`` (poses given at times 0 and 1, interpolated linearly)."""
    f = CameraFrame()
    f.eye = cam.eye0 + (cam.eye1 - cam.eye0) * time
    look = cam.look0 + (cam.look1 - cam.look0) * time
    f.w = wp.normalize(f.eye - look)
    f.u = wp.normalize(wp.cross(cam.up, f.w))
    f.v = wp.cross(f.w, f.u)
    return f


@wp.func(inline=True)
def camera_ray(cam: CameraData, fx: float, fy: float, lens: wp.vec2, time: float) -> Ray:
    """Ray through raster point (fx, fy) (pixel units, y down from the top) at ``time``.

    Pinhole: from the eye through the witness point s = eye + u_s u + v_s v - D w. Thin lens:
    from a point of the lens disk (radius ``lens_radius`` in the u, v plane) towards where the
    pinhole ray meets the plane of focus (distance ``focus`` along -w).
    """
    f = camera_frame(cam, time)
    eye = f.eye
    u = f.u
    v = f.v
    w = f.w
    us = -cam.right + 2.0 * cam.right * fx / float(cam.width)
    vs = cam.top - 2.0 * cam.top * fy / float(cam.height)
    through = us * u + vs * v - cam.dist * w  # witness point relative to the eye
    r = Ray()
    if cam.lens_radius > 0.0:
        disk = square_to_disk(lens) * cam.lens_radius
        focus_point = eye + through * (cam.focus / cam.dist)
        r.o = eye + disk[0] * u + disk[1] * v
        r.d = wp.normalize(focus_point - r.o)
    else:
        r.o = eye
        r.d = wp.normalize(through)
    return r


# ``camera_ray``'s pinhole directions for a packet's 8 raster points (fx, fy) in one frame: its
# operations in its order, each rounded once, as clang vectors (lane by lane on CUDA); every
# lane's origin is the frame's eye. The divisions and the square root are most of a camera ray's
# cost, and 8 lanes take about what one does.
_CAMERA_PACKET = r"""
#if defined(__clang__) && !defined(__CUDA_ARCH__)
typedef float v8 __attribute__((ext_vector_type(8)));
v8 FX, FY;
__builtin_memcpy(&FX, &fx, 32);
__builtin_memcpy(&FY, &fy, 32);
const v8 ps = (2.0f * right) * FX;
const v8 us = -right + ps / (float)width;
const v8 qs = (2.0f * top) * FY;
const v8 vs = top - qs / (float)height;
const v8 ax = us * u[0], ay = us * u[1], az = us * u[2];
const v8 bx = vs * v[0], by = vs * v[1], bz = vs * v[2];
const v8 cx = ax + bx, cy = ay + by, cz = az + bz;
const float ex = dist * w[0], ey = dist * w[1], ez = dist * w[2];
const v8 tx = cx - ex, ty = cy - ey, tz = cz - ez;
const v8 len = __builtin_elementwise_sqrt(tx * tx + ty * ty + tz * tz);
const v8 zero = 0.0f;
const v8 rx = len > 0.0f ? tx / len : zero, ry = len > 0.0f ? ty / len : zero, rz = len > 0.0f ? tz / len : zero;
__builtin_memcpy(&out_dx, &rx, 32);
__builtin_memcpy(&out_dy, &ry, 32);
__builtin_memcpy(&out_dz, &rz, 32);
#else
for (int l = 0; l < 8; ++l) {
    const float ps = (2.0f * right) * fx[l];
    const float us = -right + ps / (float)width;
    const float qs = (2.0f * top) * fy[l];
    const float vs = top - qs / (float)height;
    const float ax = us * u[0], ay = us * u[1], az = us * u[2];
    const float bx = vs * v[0], by = vs * v[1], bz = vs * v[2];
    const float cx = ax + bx, cy = ay + by, cz = az + bz;
    const float ex = dist * w[0], ey = dist * w[1], ez = dist * w[2];
    const float tx = cx - ex, ty = cy - ey, tz = cz - ez;
    const float len = sqrtf(tx * tx + ty * ty + tz * tz);
    out_dx[l] = len > 0.0f ? tx / len : 0.0f;
    out_dy[l] = len > 0.0f ? ty / len : 0.0f;
    out_dz[l] = len > 0.0f ? tz / len : 0.0f;
}
#endif
"""


@wp.func_native(_CAMERA_PACKET)
def camera_packet(right: float, top: float, dist: float, width: int, height: int, u: wp.vec3, v: wp.vec3,
                  w: wp.vec3, fx: PacketF, fy: PacketF, out_dx: wp.ref[PacketF], out_dy: wp.ref[PacketF],
                  out_dz: wp.ref[PacketF]):
    """The unit directions of ``camera_ray``'s pinhole rays through the 8 lanes' raster points
    (fx, fy) in the frame (u, v, w) (see above)."""
    ...


@wp.func
def camera_frame_w(cam: CameraData, time: float) -> wp.vec3:
    """The camera's w axis (from the look-at point towards the eye) at ``time``."""
    eye = cam.eye0 + (cam.eye1 - cam.eye0) * time
    look = cam.look0 + (cam.look1 - cam.look0) * time
    return wp.normalize(eye - look)


@wp.func
def project(cam: CameraData, p: wp.vec3, time: float) -> wp.vec2:
    """Raster position (pixels, y down) of world point p seen by the camera at ``time``."""
    f = camera_frame(cam, time)
    q = p - f.eye
    zc = -wp.dot(q, f.w)
    if zc <= 0.0:
        return wp.vec2(0.0, 0.0)
    us = wp.dot(q, f.u) * cam.dist / zc
    vs = wp.dot(q, f.v) * cam.dist / zc
    return wp.vec2((us + cam.right) / (2.0 * cam.right) * float(cam.width),
                   (cam.top - vs) / (2.0 * cam.top) * float(cam.height))


def camera_data(scene: Scene) -> CameraData:
    """The scene's camera as the device record."""
    cam = scene.camera
    c = CameraData()
    eye1, look1 = cam.pose(1.0)
    c.eye0, c.eye1 = wp.vec3(*cam.eye), wp.vec3(*eye1)
    c.look0, c.look1 = wp.vec3(*cam.look_at), wp.vec3(*look1)
    up = np.asarray(cam.up, dtype=np.float64)
    c.up = wp.vec3(*(up / np.linalg.norm(up)))  # unit length: a tiny up would underflow in float32
    c.top = cam.distance * math.tan(math.radians(cam.fov) / 2.0)
    c.right = c.top * cam.aspect
    c.dist = cam.distance
    c.lens_radius = cam.aperture
    c.focus = cam.focus
    c.t_open, c.t_close = cam.shutter
    c.width, c.height = cam.width, cam.height
    return c
