"""The camera on the device: rays through raster points, the viewing axis, projection.

Conventions: the camera looks along -w, w = normalize(eye - look_at), u = normalize(up × w),
v = w × u; the image plane lies at distance D along -w with half height D·tan(fov/2) and half
width that times width/height; raster y runs down from the top row. Eye and look-at are given at
times 0 and 1 (camera motion) and interpolated linearly.

Camera models (``Camera.model``, run-time data in ``CameraData``: no kernel variant each):

* pinhole (and thin lens): the image plane above, from the field of view or from intrinsics
  (fx, fy, cx, cy in pixels). OpenCV's pixel coordinates put pixel i's centre at i, warprt's
  raster positions at i + 0.5: raster x = OpenCV x + 0.5. So the ray through raster point (x, y)
  has the normalised coordinates ((x - 0.5 - cx) / fx, (y - 0.5 - cy) / fy), y down, and camera
  space (OpenCV's x right, y down, z forward) is (u, -v, -w).
* opencv: that pinhole with OpenCV's distortion (rational radial k1..k6, tangential p1, p2,
  thin prism s1..s4) between the normalised point and the pixel. A ray needs the inverse, solved
  by Newton's method in float32 (``opencv_undistort``; OpenCV's undistortPoints iterates too).
  It converges within the distortion's monotonic range: the undistorted radius r up to
  ``r_max``, where the radial part r·(1 + k1 r² + k2 r⁴ + k3 r⁶) / (1 + k4 r² + k5 r⁴ + k6 r⁶)
  first stops growing (or its denominator reaches 0); beyond it the model folds back and a pixel
  has two preimages or none. A raster point whose solution lies beyond r_max, or whose solution
  does not reproduce it to ``UNDISTORT_TOLERANCE`` pixels after ``UNDISTORT_ITERATIONS``, gets
  no ray: ``camera_ray`` returns the direction (0, 0, 0); the render kernel traces such a
  camera ray over an empty interval (not every intersector misses a zero direction by itself),
  so the pixel shows background (a miss: alpha 0, no depth), and ``camera_rays`` returns the
  direction as it is.
* fisheye: OpenCV's fisheye model (Kannala-Brandt with 4 terms): the angle θ from the optical
  axis maps to θd = θ (1 + k1 θ² + k2 θ⁴ + k3 θ⁶ + k4 θ⁸) in normalised coordinates, for any θ
  up to π (OpenCV's projectPoints stops at 90°: it goes through x / z). The inverse is Newton's
  method on [0, θ_max] kept inside its bracket, θ_max where θd(θ) stops growing (or π); raster
  points beyond θd(θ_max) get no ray.
* orthographic: parallel rays along -w from the plane through the eye: raster point (x, y)
  starts at eye + ((x - 0.5 - cx) / fx) u - ((y - 0.5 - cy) / fy) v (fx, fy in pixels per
  scene unit).

``project`` is the forward model of each (world point to raster position).
"""

from __future__ import annotations

import math

import numpy as np
import warp as wp

from .accel import PacketF
from .records import CameraData
from .sampling import QCOS4, QCOS6, QCOS8, QSIN3, QSIN5, QSIN7, square_to_disk
from .scene.description import CAMERA_MODELS, Camera, Scene


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


MODEL_PINHOLE, MODEL_OPENCV, MODEL_FISHEYE, MODEL_ORTHOGRAPHIC = 0, 1, 2, 3  # CAMERA_MODELS' order
# the inverse distortion: Newton steps at most, and how near (pixels) its answer must map back
# to the raster point to give a ray (float32 reaches ~1e-5 px at 1000 px focal lengths)
UNDISTORT_ITERATIONS = 20
UNDISTORT_TOLERANCE = 1.0e-3
NO_LIMIT = 1.0e30  # r_max of a distortion monotonic over every radius float32 holds


@wp.func
def opencv_distort(cam: CameraData, x: float, y: float) -> wp.vec2:
    """OpenCV's distortion of the normalised point (x, y) (y down): cv::projectPoints' formula."""
    k = cam.dk0
    m = cam.dk1
    s = cam.dk2
    r2 = x * x + y * y
    r4 = r2 * r2
    r6 = r4 * r2
    radial = (1.0 + k[0] * r2 + k[1] * r4 + k[2] * r6) / (1.0 + k[3] * r2 + m[0] * r4 + m[1] * r6)
    xd = x * radial + 2.0 * m[2] * x * y + m[3] * (r2 + 2.0 * x * x) + s[0] * r2 + s[1] * r4
    yd = y * radial + m[2] * (r2 + 2.0 * y * y) + 2.0 * m[3] * x * y + s[2] * r2 + s[3] * r4
    return wp.vec2(xd, yd)


@wp.func
def opencv_jacobian(cam: CameraData, x: float, y: float) -> wp.vec4:
    """The derivatives of ``opencv_distort`` at (x, y): (dxd/dx, dxd/dy, dyd/dx, dyd/dy)."""
    k = cam.dk0
    m = cam.dk1
    s = cam.dk2
    r2 = x * x + y * y
    r4 = r2 * r2
    num = 1.0 + k[0] * r2 + k[1] * r4 + k[2] * r2 * r4
    den = 1.0 + k[3] * r2 + m[0] * r4 + m[1] * r2 * r4
    dnum = k[0] + 2.0 * k[1] * r2 + 3.0 * k[2] * r4  # d/d(r²)
    dden = k[3] + 2.0 * m[0] * r2 + 3.0 * m[1] * r4
    radial = num / den
    drad = (dnum * den - num * dden) / (den * den)  # d radial / d(r²)
    j00 = radial + 2.0 * x * x * drad + 2.0 * m[2] * y + 6.0 * m[3] * x + 2.0 * s[0] * x + 4.0 * s[1] * r2 * x
    j01 = 2.0 * x * y * drad + 2.0 * m[2] * x + 2.0 * m[3] * y + 2.0 * s[0] * y + 4.0 * s[1] * r2 * y
    j10 = 2.0 * x * y * drad + 2.0 * m[2] * x + 2.0 * m[3] * y + 2.0 * s[2] * x + 4.0 * s[3] * r2 * x
    j11 = radial + 2.0 * y * y * drad + 6.0 * m[2] * y + 2.0 * m[3] * x + 2.0 * s[2] * y + 4.0 * s[3] * r2 * y
    return wp.vec4(j00, j01, j10, j11)


@wp.func
def clamp_radius(p: wp.vec2, r_max: float) -> wp.vec2:
    r = wp.length(p)
    if r > r_max:
        return p * (r_max / r)
    return p


@wp.func
def opencv_undistort(cam: CameraData, xd: float, yd: float) -> wp.vec3:
    """The normalised point (x, y) that ``opencv_distort`` takes to (xd, yd), and 1 where it was
    found (0: no ray; see the module docstring): Newton's method from (xd, yd) scaled by r_max /
    d_max (the monotonic range's radii, undistorted and distorted: the first guess lies inside
    it, where a pincushion that folds back maps points beyond r_max). The steps stop where the
    Jacobian's determinant is no longer positive (the fold), so they never reach the fold's other
    branch; what has not converged there is refused by its residual."""
    target = wp.vec2(xd, yd)
    p = clamp_radius(target * (cam.r_max / cam.d_max), cam.r_max)
    for _it in range(UNDISTORT_ITERATIONS):
        e = opencv_distort(cam, p[0], p[1]) - target
        j = opencv_jacobian(cam, p[0], p[1])
        det = j[0] * j[3] - j[1] * j[2]
        if not (det > 0.0):
            break  # (past the fold, or at it: the map no longer increases; the steps stay on its near side)
        step = wp.vec2(j[3] * e[0] - j[1] * e[1], j[0] * e[1] - j[2] * e[0]) / det
        p = p - step
        if wp.length_sq(step) <= 1.0e-14 * (1.0 + wp.length_sq(p)):
            break
    e = opencv_distort(cam, p[0], p[1]) - target
    ok = float(0.0)
    if wp.abs(e[0]) * cam.pfx <= UNDISTORT_TOLERANCE and wp.abs(e[1]) * cam.pfy <= UNDISTORT_TOLERANCE:
        ok = 1.0
    return wp.vec3(p[0], p[1], ok)


@wp.func
def fisheye_theta_d(cam: CameraData, theta: float) -> float:
    """OpenCV's fisheye distortion: θd = θ (1 + k1 θ² + k2 θ⁴ + k3 θ⁶ + k4 θ⁸)."""
    k = cam.dk0
    t2 = theta * theta
    return theta * (1.0 + t2 * (k[0] + t2 * (k[1] + t2 * (k[2] + t2 * k[3]))))


@wp.func
def fisheye_theta(cam: CameraData, theta_d: float) -> float:
    """The angle θ in [0, θ_max] whose ``fisheye_theta_d`` is theta_d (<= d_max): Newton's
    method kept inside the bracket it narrows (bisection where a step would leave it)."""
    k = cam.dk0
    lo = float(0.0)
    hi = cam.r_max
    t = wp.min(theta_d, hi)
    for _it in range(UNDISTORT_ITERATIONS):
        g = fisheye_theta_d(cam, t) - theta_d
        if g > 0.0:
            hi = t
        else:
            lo = t
        t2 = t * t
        dg = 1.0 + t2 * (3.0 * k[0] + t2 * (5.0 * k[1] + t2 * (7.0 * k[2] + t2 * 9.0 * k[3])))
        nt = t - g / dg
        if not (nt > lo and nt < hi):
            nt = 0.5 * (lo + hi)
        if wp.abs(nt - t) <= 1.0e-7 * t:
            t = nt
            break
        t = nt
    return t


@wp.func
def model_ray(cam: CameraData, f: CameraFrame, x: float, y: float, lens: wp.vec2) -> Ray:
    """``camera_ray`` of the opencv, fisheye and orthographic models (the module docstring)."""
    r = Ray()
    r.o = f.eye
    r.d = wp.vec3(0.0)
    xn = (x - cam.pcx) / cam.pfx  # normalised, y down
    yn = (y - cam.pcy) / cam.pfy
    if cam.model == MODEL_ORTHOGRAPHIC:
        r.o = f.eye + xn * f.u - yn * f.v
        r.d = -f.w
    elif cam.model == MODEL_OPENCV:
        q = opencv_undistort(cam, xn, yn)
        if q[2] > 0.0:
            through = q[0] * f.u - q[1] * f.v - f.w  # (unit depth along the axis)
            if cam.lens_radius > 0.0:
                disk = square_to_disk(lens) * cam.lens_radius
                r.o = f.eye + disk[0] * f.u + disk[1] * f.v
                r.d = wp.normalize(f.eye + through * cam.focus - r.o)
            else:
                r.d = wp.normalize(through)
    else:
        rd = wp.sqrt(xn * xn + yn * yn)
        if rd <= cam.d_max:
            if rd > 0.0:
                theta = fisheye_theta(cam, rd)
                sxy = wp.sin(theta) / rd
                r.d = (xn * sxy) * f.u - (yn * sxy) * f.v - wp.cos(theta) * f.w
            else:
                r.d = -f.w
    return r


@wp.func(inline=True)
def camera_ray(cam: CameraData, fx: float, fy: float, lens: wp.vec2, time: float) -> Ray:
    """Ray through raster point (fx, fy) (pixel units, y down from the top) at ``time``.

    Pinhole: from the eye through the witness point s = eye + u_s u + v_s v - D w. Thin lens:
    from a point of the lens disk (radius ``lens_radius`` in the u, v plane) towards where the
    pinhole ray meets the plane of focus (distance ``focus`` along -w). The other models:
    ``model_ray`` (direction (0, 0, 0) where the model has no ray).
    """
    f = camera_frame(cam, time)
    r = Ray()
    if cam.model != MODEL_PINHOLE:
        r = model_ray(cam, f, fx, fy, lens)
    else:
        eye = f.eye
        u = f.u
        v = f.v
        w = f.w
        us = -cam.x_off + 2.0 * cam.right * fx / float(cam.width)
        vs = cam.y_off - 2.0 * cam.top * fy / float(cam.height)
        through = us * u + vs * v - cam.dist * w  # witness point relative to the eye
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
const v8 us = -x_off + ps / (float)width;
const v8 qs = (2.0f * top) * FY;
const v8 vs = y_off - qs / (float)height;
const v8 ax = us * u[0], ay = us * u[1], az = us * u[2];
const v8 bx = vs * v[0], by = vs * v[1], bz = vs * v[2];
const v8 cx = ax + bx, cy = ay + by, cz = az + bz;
const float ex_ = dist * w[0], ey_ = dist * w[1], ez_ = dist * w[2];
const v8 tx = cx - ex_, ty = cy - ey_, tz = cz - ez_;
"""
_THROUGH_LANE = r"""
    const float ps = (2.0f * right) * fx[l];
    const float us = -x_off + ps / (float)width;
    const float qs = (2.0f * top) * fy[l];
    const float vs = y_off - qs / (float)height;
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
def camera_packet(right: float, top: float, x_off: float, y_off: float, dist: float, width: int, height: int,
                  u: wp.vec3, v: wp.vec3,
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
def lens_packet(right: float, top: float, x_off: float, y_off: float, dist: float, focus: float, lens_radius: float,
                width: int, height: int,
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
    """Raster position (pixels, y down) of world point p seen by the camera at ``time``: each
    model's forward map (the module docstring); (0, 0) for a point the camera does not see
    (behind the eye's plane, or beyond the distortion's valid range)."""
    f = camera_frame(cam, time)
    q = p - f.eye
    zc = -wp.dot(q, f.w)
    if cam.model == MODEL_ORTHOGRAPHIC:
        return wp.vec2(wp.dot(q, f.u) * cam.pfx + cam.pcx, -wp.dot(q, f.v) * cam.pfy + cam.pcy)
    if cam.model == MODEL_FISHEYE:
        xc = wp.dot(q, f.u)
        yc = -wp.dot(q, f.v)
        rho = wp.sqrt(xc * xc + yc * yc)
        theta = wp.atan2(rho, zc)
        if theta > cam.r_max:
            return wp.vec2(0.0, 0.0)
        if rho <= 0.0:
            return wp.vec2(cam.pcx, cam.pcy)
        s = fisheye_theta_d(cam, theta) / rho
        return wp.vec2(cam.pfx * xc * s + cam.pcx, cam.pfy * yc * s + cam.pcy)
    if zc <= 0.0:
        return wp.vec2(0.0, 0.0)
    if cam.model == MODEL_OPENCV:
        xn = wp.dot(q, f.u) / zc
        yn = -wp.dot(q, f.v) / zc
        if wp.sqrt(xn * xn + yn * yn) >= cam.r_max:
            return wp.vec2(0.0, 0.0)
        dd = opencv_distort(cam, xn, yn)
        return wp.vec2(cam.pfx * dd[0] + cam.pcx, cam.pfy * dd[1] + cam.pcy)
    us = wp.dot(q, f.u) * cam.dist / zc
    vs = wp.dot(q, f.v) * cam.dist / zc
    return wp.vec2((us + cam.x_off) / (2.0 * cam.right) * float(cam.width),
                   (cam.y_off - vs) / (2.0 * cam.top) * float(cam.height))


def distortion_limit(model: str, coeffs) -> tuple[float, float]:
    """The distortion's monotonic range (float64, on the host): (r_max, d_max), the first
    undistorted radius (opencv) or angle θ (fisheye, at most π) where the distorted radius stops
    growing with it, or where the rational model's denominator reaches 0, and the distorted
    radius there; (NO_LIMIT, NO_LIMIT) for an opencv model monotonic at every radius (checked
    up to 10⁴, 89.99° off axis). Only the radial terms count: the tangential and prism terms
    are checked pixel by pixel by the inverse's residual."""
    c = np.zeros(12)
    c[:len(coeffs)] = coeffs
    if model == "fisheye":
        k1, k2, k3, k4 = c[:4]
        g = lambda t: t * (1 + t**2 * (k1 + t**2 * (k2 + t**2 * (k3 + t**2 * k4))))  # noqa: E731
        dg = lambda t: 1 + t**2 * (3 * k1 + t**2 * (5 * k2 + t**2 * (7 * k3 + t**2 * 9 * k4)))  # noqa: E731
        grid = np.linspace(0.0, math.pi, 200001)
        bad = dg(grid) <= 0
        if not bad.any():
            return math.pi, float(g(math.pi))
    else:
        k1, k2, p1, p2, k3, k4, k5, k6 = c[:8]
        num = lambda r: 1 + r**2 * (k1 + r**2 * (k2 + r**2 * k3))  # noqa: E731
        den = lambda r: 1 + r**2 * (k4 + r**2 * (k5 + r**2 * k6))  # noqa: E731
        g = lambda r: r * num(r) / den(r)  # noqa: E731
        dnum = lambda r: 1 + r**2 * (3 * k1 + r**2 * (5 * k2 + r**2 * 7 * k3))  # noqa: E731
        dden = lambda r: 1 + r**2 * (3 * k4 + r**2 * (5 * k5 + r**2 * 7 * k6))  # noqa: E731
        # d/dr (r num / den) · den² = (r num)' den - r num den' (den' as r·den's derivative)
        dg = lambda r: np.where(den(r) > 0, dnum(r) * den(r) - num(r) * (dden(r) - den(r)), -1.0)  # noqa: E731
        grid = np.concatenate([np.linspace(0.0, 4.0, 100001), np.geomspace(4.0, 1e4, 100001)[1:]])
        bad = dg(grid) <= 0
        if not bad.any():
            return NO_LIMIT, NO_LIMIT
    i = int(np.argmax(bad))
    lo, hi = grid[i - 1], grid[i]  # (grid[0] = 0 is never bad: dg(0) = 1)
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        lo, hi = (lo, mid) if dg(mid) <= 0 else (mid, hi)
    return float(lo), float(g(lo))


def camera_data(scene: "Scene | Camera") -> CameraData:
    """The scene's camera (or a camera) as the device record."""
    cam = scene.camera if isinstance(scene, Scene) else scene
    c = CameraData()
    eye1, look1 = cam.pose(1.0)
    c.eye0, c.eye1 = wp.vec3(*cam.eye), wp.vec3(*eye1)
    c.look0, c.look1 = wp.vec3(*cam.look_at), wp.vec3(*look1)
    up = np.asarray(cam.up, dtype=np.float64)
    c.up = wp.vec3(*(up / np.linalg.norm(up)))  # unit length: a tiny up would underflow in float32
    fx, fy, cx, cy = cam.intrinsics()
    if cam.fx is None:
        c.top = cam.distance * math.tan(math.radians(cam.fov) / 2.0)
        c.right = c.top * cam.aspect
        c.x_off, c.y_off = c.right, c.top  # (the same float32 values: the centred plane's bits)
    else:
        c.top = cam.distance * cam.height / (2.0 * fy)
        c.right = cam.distance * cam.width / (2.0 * fx)
        c.x_off = cam.distance * (cx + 0.5) / fx
        c.y_off = cam.distance * (cy + 0.5) / fy
    c.dist = cam.distance
    c.lens_radius = cam.aperture
    c.focus = cam.focus
    c.t_open, c.t_close = cam.shutter
    c.width, c.height = cam.width, cam.height
    c.model = CAMERA_MODELS.index(cam.model)
    c.pfx, c.pfy, c.pcx, c.pcy = fx, fy, cx + 0.5, cy + 0.5
    k = cam.dist_coeffs()
    if cam.model == "opencv":  # OpenCV's order k1, k2, p1, p2, k3, k4, k5, k6, s1..s4
        c.dk0 = wp.vec4(k[0], k[1], k[4], k[5])
        c.dk1 = wp.vec4(k[6], k[7], k[2], k[3])
        c.dk2 = wp.vec4(*k[8:12])
    elif cam.model == "fisheye":
        c.dk0 = wp.vec4(*k[:4])
    c.r_max, c.d_max = distortion_limit(cam.model, k) if cam.model in ("opencv", "fisheye") else (NO_LIMIT, NO_LIMIT)
    c.line_delay = cam.rolling_shutter
    c.from_fov = int(cam.fx is None)
    return c
