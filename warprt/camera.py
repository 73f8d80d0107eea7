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
from .sampling import QCOS4, QCOS6, QCOS8, QSIN3, QSIN5, QSIN7, square_to_disk
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


# ``camera_ray`` for a packet's 8 raster points (fx, fy) in one frame: its operations in its
# order, each rounded once, as clang vectors (lane by lane on CUDA). The divisions and square
# roots are most of a camera ray's cost, and 8 lanes take about what one does. First the witness
# points' offsets from the eye, through = us·u + vs·v − D·w (tx, ty, tz; ``_THROUGH`` as vectors,
# ``_THROUGH_LANE`` for lane l), then the unit direction of (ex, ey, ez) (``_UNIT``: Warp's
# ``normalize``).
_THROUGH = r"""
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
const float ex_ = dist * w[0], ey_ = dist * w[1], ez_ = dist * w[2];
const v8 tx = cx - ex_, ty = cy - ey_, tz = cz - ez_;
"""
_THROUGH_LANE = r"""
    const float ps = (2.0f * right) * fx[l];
    const float us = -right + ps / (float)width;
    const float qs = (2.0f * top) * fy[l];
    const float vs = top - qs / (float)height;
    const float ax = us * u[0], ay = us * u[1], az = us * u[2];
    const float bx = vs * v[0], by = vs * v[1], bz = vs * v[2];
    const float cx = ax + bx, cy = ay + by, cz = az + bz;
    const float ex_ = dist * w[0], ey_ = dist * w[1], ez_ = dist * w[2];
    const float tx = cx - ex_, ty = cy - ey_, tz = cz - ez_;
"""
_UNIT = r"""
const v8 len = __builtin_elementwise_sqrt(ex * ex + ey * ey + ez * ez);
const v8 zero = 0.0f;
const v8 rx = len > 0.0f ? ex / len : zero, ry = len > 0.0f ? ey / len : zero, rz = len > 0.0f ? ez / len : zero;
__builtin_memcpy(&out_dx, &rx, 32);
__builtin_memcpy(&out_dy, &ry, 32);
__builtin_memcpy(&out_dz, &rz, 32);
"""
_UNIT_LANE = r"""
    const float len = sqrtf(ex * ex + ey * ey + ez * ez);
    out_dx[l] = len > 0.0f ? ex / len : 0.0f;
    out_dy[l] = len > 0.0f ? ey / len : 0.0f;
    out_dz[l] = len > 0.0f ? ez / len : 0.0f;
"""

# ``sampling.quarter_sin`` and ``quarter_cos`` of x (x2 = x·x): s and c, the same operations
_QUARTER = f"""
auto sp_ = x2 * {QSIN7.hex()}f; sp_ = sp_ + {QSIN5.hex()}f; sp_ = sp_ * x2; sp_ = sp_ + {QSIN3.hex()}f;
sp_ = sp_ * x2; sp_ = sp_ * x;
const auto s = x + sp_;
auto cp_ = x2 * {QCOS8.hex()}f; cp_ = cp_ + {QCOS6.hex()}f; cp_ = cp_ * x2; cp_ = cp_ + {QCOS4.hex()}f;
cp_ = cp_ * x2; cp_ = cp_ - 0.5f; cp_ = cp_ * x2;
const auto c = 1.0f + cp_;
"""

# a thin-lens ray from the disk point (dkx, dky) (scaled by the lens radius) and through (tx, ty,
# tz), k = focus / D: the origin (ox, oy, oz) and the unnormalised direction (ex, ey, ez), the
# vectors' or one lane's (``auto``)
_LENS_RAY = r"""
const auto fpx = tx * k, fpy = ty * k, fpz = tz * k;
const auto gx = eye[0] + fpx, gy = eye[1] + fpy, gz = eye[2] + fpz;
const auto mx = dkx * u[0], my = dkx * u[1], mz = dkx * u[2];
const auto hx = eye[0] + mx, hy = eye[1] + my, hz = eye[2] + mz;
const auto nx = dky * v[0], ny = dky * v[1], nz = dky * v[2];
const auto ox = hx + nx, oy = hy + ny, oz = hz + nz;
const auto ex = gx - ox, ey = gy - oy, ez = gz - oz;
"""


def _camera_snippet(snippet: str) -> str:
    """A camera packet's snippet with its shared pieces (``@THROUGH@`` and the others above) in place."""
    for name, text in (("THROUGH", _THROUGH), ("THROUGH_LANE", _THROUGH_LANE), ("UNIT", _UNIT),
                       ("UNIT_LANE", _UNIT_LANE), ("QUARTER", _QUARTER), ("LENS_RAY", _LENS_RAY)):
        snippet = snippet.replace(f"@{name}@\n", text.lstrip("\n"))
    return snippet


# the pinhole: every lane's origin is the frame's eye, its direction through's
_CAMERA_PACKET = _camera_snippet(r"""
#if defined(__clang__) && !defined(__CUDA_ARCH__)
@THROUGH@
const v8 ex = tx, ey = ty, ez = tz;
@UNIT@
#else
for (int l = 0; l < 8; ++l) {
@THROUGH_LANE@
    const float ex = tx, ey = ty, ez = tz;
@UNIT_LANE@
}
#endif
""")


@wp.func_native(_CAMERA_PACKET)
def camera_packet(right: float, top: float, dist: float, width: int, height: int, u: wp.vec3, v: wp.vec3,
                  w: wp.vec3, fx: PacketF, fy: PacketF, out_dx: wp.ref[PacketF], out_dy: wp.ref[PacketF],
                  out_dz: wp.ref[PacketF]):
    """The unit directions of ``camera_ray``'s pinhole rays through the 8 lanes' raster points
    (fx, fy) in the frame (u, v, w) (see above)."""
    ...


# the thin lens: each lane's lens point (lx, ly) through ``square_to_disk``'s concentric map
# (its sine and cosine ``sampling.quarter_sin`` and ``quarter_cos``'s polynomials, ``_QUARTER``),
# scaled by the lens radius, gives the origin eye + x·u + y·v, and the direction runs from it to
# eye + through·(focus / D)
_LENS_PACKET = _camera_snippet(r"""
const float pi4 = 3.14159265358979323846f / 4.0f, k = focus / dist;
#if defined(__clang__) && !defined(__CUDA_ARCH__)
@THROUGH@
v8 LX, LY;
__builtin_memcpy(&LX, &lx, 32);
__builtin_memcpy(&LY, &ly, 32);
const v8 a2 = 2.0f * LX, b2 = 2.0f * LY;
const v8 a = a2 - 1.0f, b = b2 - 1.0f;
const v8 qa = b / a, qb = a / b;
const auto wide = __builtin_elementwise_abs(a) > __builtin_elementwise_abs(b);
const v8 q = wide ? qa : qb;
const v8 x = pi4 * q;
const v8 x2 = x * x;
@QUARTER@
const v8 r = wide ? a : b;
const v8 sx = r * (wide ? c : s), sy = r * (wide ? s : c);
const v8 none = 0.0f;
const auto centre = (a == 0.0f) & (b == 0.0f);
const v8 kx = centre ? none : sx, ky = centre ? none : sy;
const v8 dkx = kx * lens_radius, dky = ky * lens_radius;
@LENS_RAY@
__builtin_memcpy(&out_ox, &ox, 32);
__builtin_memcpy(&out_oy, &oy, 32);
__builtin_memcpy(&out_oz, &oz, 32);
@UNIT@
#else
for (int l = 0; l < 8; ++l) {
@THROUGH_LANE@
    const float a2 = 2.0f * lx[l], b2 = 2.0f * ly[l];
    const float a = a2 - 1.0f, b = b2 - 1.0f;
    float dkx = 0.0f, dky = 0.0f;
    if (!(a == 0.0f && b == 0.0f)) {
        const bool wide = fabsf(a) > fabsf(b);
        const float q = wide ? b / a : a / b;
        const float x = pi4 * q;
        const float x2 = x * x;
@QUARTER@
        const float r = wide ? a : b;
        const float sx = r * (wide ? c : s), sy = r * (wide ? s : c);
        dkx = sx * lens_radius; dky = sy * lens_radius;
    }
@LENS_RAY@
    out_ox[l] = ox; out_oy[l] = oy; out_oz[l] = oz;
@UNIT_LANE@
}
#endif
""")


@wp.func_native(_LENS_PACKET)
def lens_packet(right: float, top: float, dist: float, focus: float, lens_radius: float, width: int, height: int,
                eye: wp.vec3, u: wp.vec3, v: wp.vec3, w: wp.vec3, fx: PacketF, fy: PacketF, lx: PacketF,
                ly: PacketF, out_ox: wp.ref[PacketF], out_oy: wp.ref[PacketF], out_oz: wp.ref[PacketF],
                out_dx: wp.ref[PacketF], out_dy: wp.ref[PacketF], out_dz: wp.ref[PacketF]):
    """``camera_ray``'s thin-lens rays (origins and unit directions) through the 8 lanes' raster
    points (fx, fy) from their lens samples (lx, ly), in the frame (eye, u, v, w) (see above)."""
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
