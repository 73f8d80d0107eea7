"""Depth sensor models: what a depth camera reports (``sensor_z``, ``sensor_depth``) from the
exact depth a render gives (``z``, ``depth``).

A scene with a :class:`warprt.DepthSensor` (``Scene(depth_sensor=...)``, ``[depth_sensor]`` in a
scene file) renders two more outputs on request, next to the exact ones, which stay available:

============ ====== ==================================================================
name         shape  meaning
============ ====== ==================================================================
sensor_z     (H, W) the camera-space depth Z' the sensor reports (``z`` with its errors)
sensor_depth (H, W) the distance along the ray it reports: ``depth`` · Z' / Z (the same
                    error, along the ray)
============ ====== ==================================================================

``warprt.render(scene, aovs=["z", "sensor_z"])``, ``Renderer.render``, ``BatchRenderer.render``
and the Newton bridge all take these names. They are made after the render by one small kernel
(:func:`apply_depth_sensor`) over the render's own AOVs: ``z``, ``depth`` for ``sensor_depth``,
and, with dropouts, ``normal`` and ``position`` (asked of the render kernel with its run-time
mask; no other kernel is compiled). Per pixel, with Z the pixel's exact camera-space depth:

1. **miss**: a pixel that sees nothing (Z = inf) is invalid.
2. **grazing-angle dropout** (``dropout_start`` < 90): θ = the angle between the pixel's normal
   (turned towards the camera) and the direction from its visible point back to the camera's
   centre at shutter open (an orthographic camera's rays are parallel: the direction is its
   axis, towards the camera); the pixel is dropped with probability
   p(θ) = clamp((θ - start) / (end - start), 0, 1) (a step at ``dropout_end`` when the two are
   equal), drawn with one uniform number.
3. **stereo** (``disparity_sigma`` or ``disparity_step`` > 0): the disparity d = f·b / Z gets a
   Gaussian error d' = d + σ_d·g (g standard normal, Box-Muller from two uniform numbers), is
   rounded to a multiple of ``disparity_step`` if set, and Z' = f·b / d'; d' <= 0 (no match) is
   invalid. To first order σ_Z = Z²·σ_d / (f·b); the exact Z' has a small positive bias,
   Z·(σ_d/d)² to second order.
4. **range**: a reported Z' below ``min_range`` or above ``max_range`` is invalid (limits
   inclusive).
5. an invalid pixel reads NaN (``invalid = "nan"``) or 0 (``"zero"``) in both outputs.

Randomness: every number is a hash of (the render's seed, the pixel's index in the render or
batch, the draw), as the image's samples are (``warprt.sampling``) but in draws of their own, so
the same seed gives the same noise bit for bit, on any thread count or tiling; another seed
(e.g. the simulation step) gives independent noise. The exact ``z`` and ``depth`` are averages
over the pixel's samples: the noise is applied once per pixel, as a sensor reports one value.
"""

from __future__ import annotations

import math

import numpy as np
import warp as wp

from ._warp import build_once
from .errors import RenderError
from .poses import look_at
from .sampling import hash2, hash_u32, u32_to_unit
from .scene.description import DepthSensor

SENSOR_AOVS = ("sensor_z", "sensor_depth")
SENSOR_SALT = wp.constant(wp.uint32(0x5E4D0C71))  # keeps the sensor's draws apart from the image's samples
DRAW_DROPOUT, DRAW_NOISE_1, DRAW_NOISE_2 = (wp.constant(k) for k in (1, 2, 3))


@wp.struct
class SensorParams:
    fb: float  # focal_length · baseline (pixels · scene units)
    sigma_d: float  # disparity noise, pixels
    step: float  # disparity quantisation step, pixels (0: none)
    stereo: int  # 1: through the disparity
    z_min: float
    z_max: float
    dropouts: int  # 1: grazing-angle dropouts
    start: float  # dropout_start, radians
    end: float  # dropout_end, radians
    invalid: float  # NaN or 0
    seed: wp.uint32


@wp.func
def sensor_uniform(key: wp.uint32, draw: int) -> float:
    return u32_to_unit(hash2(key, wp.uint32(draw)))


@wp.func
def dropout_probability(p: SensorParams, theta: float) -> float:
    """p(θ): 0 below ``start``, 1 from ``end`` on, linear in between."""
    if theta >= p.end:
        return 1.0
    if theta <= p.start:
        return 0.0
    return (theta - p.start) / (p.end - p.start)


@wp.func
def measured_z(p: SensorParams, key: wp.uint32, z: float) -> float:
    """The depth the stereo pair reports for true depth z (<= 0: no match)."""
    d = p.fb / z
    if p.sigma_d > 0.0:
        # Box-Muller: u1 in (0, 1] (log finite), u2 in [0, 1)
        u1 = 1.0 - sensor_uniform(key, DRAW_NOISE_1)
        u2 = sensor_uniform(key, DRAW_NOISE_2)
        g = wp.sqrt(-2.0 * wp.log(u1)) * wp.cos(2.0 * wp.pi * u2)
        d = d + p.sigma_d * g
    if p.step > 0.0:
        d = p.step * wp.floor(d / p.step + 0.5)
    if d <= 0.0:
        return -1.0
    return p.fb / d


@build_once
def _sensor_kernel():
    @wp.kernel(module="warprt_sensor", enable_backward=False)
    def depth_sensor(p: SensorParams, z: wp.array(dtype=float), depth: wp.array(dtype=float),
                     normal: wp.array(dtype=wp.vec3), position: wp.array(dtype=wp.vec3),
                     eyes: wp.array(dtype=wp.transform), per_eye: int, ortho: wp.array(dtype=int),
                     with_depth: int, out_z: wp.array(dtype=float), out_depth: wp.array(dtype=float)):
        i = wp.tid()
        zc = z[i]
        key = hash2(hash_u32(p.seed ^ SENSOR_SALT), wp.uint32(i))
        valid = zc > 0.0 and zc < wp.inf
        if valid and p.dropouts != 0:
            e = i // per_eye
            view = wp.transform_get_translation(eyes[e]) - position[i]
            if ortho[e % ortho.shape[0]] != 0:  # parallel rays: towards the camera along its axis
                view = wp.quat_rotate(wp.transform_get_rotation(eyes[e]), wp.vec3(0.0, 0.0, 1.0))
            n = normal[i]
            c = float(1.0)
            if wp.length(view) > 0.0 and wp.length(n) > 0.0:
                c = wp.dot(wp.normalize(view), wp.normalize(n))
            theta = wp.acos(wp.clamp(c, -1.0, 1.0))
            if sensor_uniform(key, DRAW_DROPOUT) < dropout_probability(p, theta):
                valid = False
        zm = zc
        if valid and p.stereo != 0:
            zm = measured_z(p, key, zc)
            if zm <= 0.0:
                valid = False
        if valid and (zm < p.z_min or zm > p.z_max):
            valid = False
        if valid:
            out_z[i] = zm
        else:
            out_z[i] = p.invalid
        if with_depth != 0:
            if valid:
                out_depth[i] = depth[i] * (zm / zc)
            else:
                out_depth[i] = p.invalid

    return depth_sensor


def sensor_params(model: DepthSensor, seed: int) -> SensorParams:
    p = SensorParams()
    p.stereo = int(model.stereo)
    p.fb = float(model.focal_length * model.baseline) if model.stereo else 1.0
    p.sigma_d = float(model.disparity_sigma)
    p.step = float(model.disparity_step)
    p.z_min = float(model.min_range)
    p.z_max = float(model.max_range)
    p.dropouts = int(model.dropouts)
    p.start = math.radians(model.dropout_start)
    p.end = math.radians(model.dropout_end)
    p.invalid = float("nan") if model.invalid == "nan" else 0.0
    p.seed = wp.uint32(int(seed) & 0xFFFFFFFF)
    return p


def needed_aovs(model: DepthSensor, names) -> list[str]:
    """The render AOVs the sensor outputs ``names`` are made from."""
    need = ["z"]
    if "sensor_depth" in names:
        need.append("depth")
    if model.dropouts:
        need += ["normal", "position"]
    return need


def split_aovs(names, scene) -> tuple[list, list, list]:
    """(the names asked for, the render's AOVs (those asked plus what the sensor needs), the sensor
    outputs asked for). A sensor output without a depth sensor is a RenderError."""
    from .aov import check_aov_names

    if not names:
        return [], [], []
    if isinstance(names, str):
        names = [names]
    if not isinstance(names, (list, tuple, set, frozenset)) or not all(isinstance(n, str) for n in names):
        return check_aov_names(names), check_aov_names(names), []  # (its error)
    names = list(dict.fromkeys(names))
    sensor = [n for n in names if n in SENSOR_AOVS]
    render = check_aov_names([n for n in names if n not in SENSOR_AOVS]) if len(sensor) < len(names) else []
    if sensor:
        model = getattr(scene, "depth_sensor", None)
        if model is None:
            raise RenderError(f"aovs: {', '.join(map(repr, sensor))} need a depth sensor model: "
                              "Scene(depth_sensor=warprt.DepthSensor(...)) or [depth_sensor] in the scene file")
        render = list(dict.fromkeys(render + needed_aovs(model, sensor)))
    return names, render, sensor


def apply_depth_sensor(model: DepthSensor, aovs: dict, eyes, per_eye: int, seed: int, names=SENSOR_AOVS,
                       out: dict | None = None, ortho=(False,)) -> dict:
    """The sensor outputs ``names`` (``sensor_z``, ``sensor_depth``) of the flat AOV buffers
    ``aovs`` (``z``; ``depth`` for sensor_depth; ``normal`` and ``position`` with dropouts: 1-D
    ``wp.array``s of one length, on one device): a dict of 1-D float ``wp.array``s. ``eyes``: a
    ``wp.array`` of ``wp.transform`` whose translations are the camera centres, one for each
    ``per_eye`` consecutive pixels; ``seed``: the render's. ``out``: arrays of a previous call
    to write into (reused when they fit). ``ortho``: for each camera (eye e is camera
    e % len(ortho)), whether it is orthographic: its view direction is then its axis (the
    pose's local +z), not the line to its centre."""
    z = aovs["z"]
    dev, count = z.device, z.shape[0]
    with_depth = "sensor_depth" in names
    dummy_f = wp.empty(1, dtype=float, device=dev)
    dummy_v = wp.empty(1, dtype=wp.vec3, device=dev)
    normal = aovs["normal"] if model.dropouts else dummy_v
    position = aovs["position"] if model.dropouts else dummy_v
    depth = aovs["depth"] if with_depth else dummy_f
    out = dict(out or {})
    for name in SENSOR_AOVS:
        a = out.get(name)
        if a is None or a.shape[0] != count or a.device != dev:
            out[name] = wp.empty(count, dtype=float, device=dev) if name == "sensor_z" or with_depth else dummy_f
    wp.launch(_sensor_kernel(), dim=count, device=dev,
              inputs=[sensor_params(model, seed), z, depth, normal, position, eyes, int(per_eye),
                      wp.array(np.asarray(ortho, np.int32), dtype=int, device=dev), int(with_depth),
                      out["sensor_z"], out["sensor_depth"]])
    return {name: out[name] for name in names}


def eye_poses(camera, device) -> "wp.array":
    """A one-element array of the camera's pose at shutter open (camera to world, the form a
    batch's camera poses take)."""
    eye, target = camera.pose(camera.shutter[0])
    return wp.array(look_at(eye, target, camera.up)[None].astype(np.float32), dtype=wp.transform, device=device)


__all__ = ["SENSOR_AOVS", "apply_depth_sensor", "split_aovs"]
