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

from .records import CameraData
from .sampling import square_to_disk
from .scene.description import Scene


@wp.struct
class Ray:
    o: wp.vec3
    d: wp.vec3


@wp.func(inline=True)
def camera_ray(cam: CameraData, fx: float, fy: float, lens: wp.vec2, time: float) -> Ray:
    """Ray through raster point (fx, fy) (pixel units, y down from the top) at ``time``.

    Pinhole: from the eye through the witness point s = eye + u_s u + v_s v - D w. Thin lens:
    from a point of the lens disk (radius ``lens_radius`` in the u, v plane) towards where the
    pinhole ray meets the plane of focus (distance ``focus`` along -w).
    """
    eye = cam.eye0 + (cam.eye1 - cam.eye0) * time  # poses given at times 0 and 1
    look = cam.look0 + (cam.look1 - cam.look0) * time
    w = wp.normalize(eye - look)
    u = wp.normalize(wp.cross(cam.up, w))
    v = wp.cross(w, u)
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


@wp.func
def camera_frame_w(cam: CameraData, time: float) -> wp.vec3:
    """The camera's w axis (from the look-at point towards the eye) at ``time``."""
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
