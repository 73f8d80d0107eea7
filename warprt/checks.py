"""Device-array inputs checked on the device, before every render that reads them.

A pipeline keeps its poses on the device (``BatchRenderer``'s pose arrays, light positions and
fields of view, a Newton ``state.body_q``) and writes them from its own kernels: a NaN there (an
exploded simulation, an uninitialised buffer) would make a body vanish or a view go black with
finite pixels and no word. So each render that reads such arrays first runs one small kernel over
all of them (:func:`check_batch`, :func:`check_bodies`, :func:`check_points`) and reads back one
integer per array: the first bad element, if any. That element alone is then copied to the host
and described in a :class:`warprt.RenderError` naming the array, the index, the world, camera,
shape or body, and what is wrong. ``check_inputs=False`` (``BatchRenderer``, ``NewtonRenderer``)
skips the check once a pipeline trusts its inputs; ``python -m benchmarks.run`` reports its cost.

Refused: a coordinate that is NaN, infinite or beyond :data:`EXTENT_LIMIT` (1e19, where the
renderer's float32 squared distances overflow: ``scene.description.EXTENT_WARNING``); a rotation
quaternion that is not finite or whose squared length is off 1 by more than
:data:`QUAT_TOLERANCE` (rotating by q scales by |q|²: 1e-3 is a pixel in a thousand, while a
float32 quaternion normalised by Warp or a simulator is within a few 1e-7); a directional light
of zero direction; a field of view outside (0, 180) degrees.
"""

from __future__ import annotations

import numpy as np
import warp as wp

from ._warp import build_once
from .errors import RenderError
from .scene.description import EXTENT_WARNING

EXTENT_LIMIT = EXTENT_WARNING
VERTEX_LIMIT = 1e30  # mesh vertices (object space, as scene.description.validate_arrays refuses beyond)
QUAT_TOLERANCE = 1e-3
NONE = (1 << 31) - 1  # no bad element

# the slots of check_batch's answer, in order
BATCH_ARRAYS = ("shape_poses", "shape_poses_end", "camera_poses", "camera_poses_end", "light_positions", "fov")
# a batch's per-world looks, checked by its own kernel into the same answer (warprt.worlds)
LOOKS_ARRAYS = ("material_colors", "material_textures", "light_intensities")
BATCH_SLOTS = len(BATCH_ARRAYS) + len(LOOKS_ARRAYS)


@wp.func
def bad_point(p: wp.vec3, limit: float) -> int:
    if not wp.isfinite(p):
        return 1
    if wp.max(wp.abs(p)) > limit:
        return 1
    return 0


@wp.func
def bad_transform(t: wp.transform, limit: float, tol: float) -> int:
    if bad_point(wp.transform_get_translation(t), limit) != 0:
        return 1
    q = wp.transform_get_rotation(t)
    if not wp.isfinite(q):
        return 1
    if wp.abs(wp.dot(q, q) - 1.0) > tol:
        return 1
    return 0


@build_once
def _kernels():
    @wp.kernel(module="warprt_checks", enable_backward=False)
    def batch(shape_poses: wp.array(dtype=wp.transform), shape_poses_end: wp.array(dtype=wp.transform),
              n_shapes: int, camera_poses: wp.array(dtype=wp.transform),
              camera_poses_end: wp.array(dtype=wp.transform), lights: wp.array(dtype=wp.vec3),
              directional: wp.array(dtype=int), n_lights: int, fov: wp.array(dtype=float), limit: float, tol: float,
              first: wp.array(dtype=int)):
        i = wp.tid()
        if i < n_shapes:
            if bad_transform(shape_poses[i], limit, tol) != 0:
                wp.atomic_min(first, 0, i)
            if bad_transform(shape_poses_end[i], limit, tol) != 0:
                wp.atomic_min(first, 1, i)
        if i < camera_poses.shape[0]:
            if bad_transform(camera_poses[i], limit, tol) != 0:
                wp.atomic_min(first, 2, i)
            if bad_transform(camera_poses_end[i], limit, tol) != 0:
                wp.atomic_min(first, 3, i)
        if n_lights > 0 and i < lights.shape[0]:
            x = lights[i]
            bad = bad_point(x, limit)
            if bad == 0 and directional[i % n_lights] != 0 and not (wp.dot(x, x) > 0.0):
                bad = 1
            if bad != 0:
                wp.atomic_min(first, 4, i)
        if i < fov.shape[0]:
            f = fov[i]
            if not (f > 0.0 and f < 180.0):  # (NaN fails both)
                wp.atomic_min(first, 5, i)

    @wp.kernel(module="warprt_checks", enable_backward=False)
    def bodies(body_q: wp.array(dtype=wp.transform), used: wp.array(dtype=int), limit: float, tol: float,
               first: wp.array(dtype=int)):
        k = wp.tid()
        b = used[k]
        if b >= body_q.shape[0]:
            wp.atomic_min(first, 1, k)
        elif bad_transform(body_q[b], limit, tol) != 0:
            wp.atomic_min(first, 0, b)

    @wp.kernel(module="warprt_checks", enable_backward=False)
    def points(p: wp.array(dtype=wp.vec3), limit: float, first: wp.array(dtype=int)):
        i = wp.tid()
        if bad_point(p[i], limit) != 0:
            wp.atomic_min(first, 0, i)

    return batch, bodies, points


def _answer(slots: int, device) -> "wp.array":
    return wp.full(slots, NONE, dtype=int, device=device)


def describe_point(x, what: str = "position", limit: float = EXTENT_LIMIT) -> str:
    x = np.asarray(x, np.float64)
    text = f"{what} ({', '.join(f'{v:.6g}' for v in x)})"
    if not np.isfinite(x).all():
        return f"{text} is not finite"
    if np.abs(x).max() > limit:
        return (f"{text} is beyond {limit:g}, where the renderer's float32 squared distances overflow "
                "(scale the scene down)")
    if not np.any(x):
        return f"{text} is zero (a direction needs a length)"
    return f"{text} is invalid"


def describe_transform(t) -> str:
    """What is wrong with one (x, y, z, qx, qy, qz, qw) pose (host side, float64)."""
    t = np.asarray(t, np.float64)
    p, q = t[:3], t[3:]
    if not np.isfinite(p).all() or np.abs(p).max() > EXTENT_LIMIT:
        return describe_point(p)
    text = f"quaternion ({', '.join(f'{v:.6g}' for v in q)})"
    if not np.isfinite(q).all():
        return f"{text} is not finite"
    n2 = float(np.dot(q, q))
    return (f"{text} has squared length {n2:.6g}: expected a unit quaternion (|q|^2 within {QUAT_TOLERANCE:g} "
            "of 1; normalise it)")


def _element(a: "wp.array", i: int) -> np.ndarray:
    flat = a.flatten() if a.ndim > 1 else a
    return np.asarray(flat[i:i + 1].numpy()[0])


def check_batch(b, shape_poses_end, camera_poses_end) -> None:
    """Check a BatchRenderer's pose arrays, light positions and fields of view on its device
    and its per-world looks (two launches, one read of nine integers); raise :class:`RenderError` for the first bad element
    of each array found, naming it."""
    batch, _, _ = _kernels()
    dev = b.device
    W, C, S, L = b.worlds, b.cameras, b._n_shapes, b._n_lights
    if getattr(b, "_check_answer", None) is None:
        b._check_answer = _answer(BATCH_SLOTS, dev)
        b._directional = wp.array(np.array(b._directional_lights or [0], np.int32), dtype=int, device=dev)
    first = b._check_answer
    first.fill_(NONE)
    n = max(W * max(S, 1), W * C, W * max(L, 1), C)
    wp.launch(batch, dim=n, device=dev,
              inputs=[b.shape_poses.flatten(), shape_poses_end.flatten(), W * S, b.camera_poses.flatten(),
                      camera_poses_end.flatten(), b.light_positions.flatten(), b._directional, L, b.fov,
                      float(EXTENT_LIMIT), float(QUAT_TOLERANCE), first])
    b._check_looks(first[len(BATCH_ARRAYS):])
    found = first.numpy()
    if (found == NONE).all():
        return
    problems = b._looks_problems(found[len(BATCH_ARRAYS):])
    for slot, name in enumerate(BATCH_ARRAYS):
        i = int(found[slot])
        if i == NONE or (slot == 1 and shape_poses_end is b.shape_poses) or \
                (slot == 3 and camera_poses_end is b.camera_poses):  # (the same array: said once)
            continue
        if name.startswith("shape"):
            array = b.shape_poses if name == "shape_poses" else shape_poses_end
            w, s = divmod(i, S)
            problems.append(f"{name}[{w}, {s}] (world {w}, scene.shapes[{s}]): {describe_transform(_element(array, i))}")
        elif name.startswith("camera"):
            array = b.camera_poses if name == "camera_poses" else camera_poses_end
            w, c = divmod(i, C)
            problems.append(f"{name}[{w}, {c}] (world {w}, camera {c}): {describe_transform(_element(array, i))}")
        elif name == "light_positions":
            w, k = divmod(i, L)
            what = "direction" if b._directional_lights[k] else "position"
            problems.append(f"{name}[{w}, {k}] (world {w}, scene.lights[{b._light_index[k]}]): "
                            f"{describe_point(_element(b.light_positions, i), what)}")
        else:
            f = float(_element(b.fov, i))
            problems.append(f"fov[{i}] (camera {i}): {f:g} degrees is outside (0, 180)")
    raise RenderError("; ".join(problems) + " (check_inputs=False skips this check)")


def check_bodies(body_q: "wp.array", used: "wp.array", device, labels=None, worlds=None, answer=None) -> None:
    """Check the bodies ``used`` (indices into ``body_q``) of a Newton state on the device
    (``answer``: a 2-int device array to reuse, else one is made)."""
    _, bodies, _ = _kernels()
    first = _answer(2, device) if answer is None else answer
    if answer is not None:
        first.fill_(NONE)
    if len(used):
        wp.launch(bodies, dim=len(used), device=device,
                  inputs=[body_q, used, float(EXTENT_LIMIT), float(QUAT_TOLERANCE), first])
    found = first.numpy()
    if found[1] != NONE:
        raise RenderError(f"state.body_q holds {body_q.shape[0]} bodies, the model more; "
                          "is the state the model's (model.state())?")
    b = int(found[0])
    if b == NONE:
        return
    who = [f"body {labels[b]!r}"] if labels is not None and b < len(labels) and labels[b] else []
    if worlds is not None and b < len(worlds):
        who.append(f"world {int(worlds[b])}")
    where = f" ({', '.join(who)})" if who else ""
    raise RenderError(f"state.body_q[{b}]{where}: {describe_transform(_element(body_q, b))}: the simulation may "
                      "have diverged (check_inputs=False skips this check)")


def check_points(points: "wp.array", name: str = "points", limit: float = VERTEX_LIMIT) -> None:
    """Check a ``wp.array`` of vec3 (new mesh vertices) on its device."""
    _, _, kernel = _kernels()
    first = _answer(1, points.device)
    if points.shape[0]:
        wp.launch(kernel, dim=points.shape[0], device=points.device, inputs=[points, float(limit), first])
    i = int(first.numpy()[0])
    if i != NONE:
        raise RenderError(f"{name}[{i}]: {describe_point(_element(points, i), limit=limit)}")
