"""Camera poses for batches and the Newton bridge: :func:`look_at` and the check that a pose is not
rolled against the scene's up axis.

A pose is camera to world, (x, y, z, qx, qy, qz, qw): the camera sits at (x, y, z) and looks along
its local -z with its local +y up and +x to the right (the OpenGL/USD convention of Newton's
cameras and of :class:`warprt.BatchRenderer`'s ``camera_poses``). :func:`look_at` makes one from
an eye, a target and the world's **up axis, which it always takes explicitly**: warprt scenes are
y-up by convention, Newton models are z-up unless built with ``up_axis="Y"``
(:attr:`warprt.newton_bridge.NewtonRenderer.up_axis` says which), and a pose made for one in the
other shows the world rolled by up to 90°.

:func:`camera_roll` measures that roll: the angle about the view between the camera's +y and the
world's up axis projected on the image plane (undefined, and taken as 0, for a camera that looks
within ``LEVEL_CONE_DEG`` of straight up or down). ``BatchRenderer.set_camera_poses`` (and the
bridge's) warns with a :class:`CameraRollWarning` naming the first camera rolled by more than
``ROLL_WARNING_DEG`` against the renderer's up axis; a camera rolled on purpose (on a robot's
wrist) silences it with ``warnings.filterwarnings("ignore", category=CameraRollWarning)``. Poses
written into the device arrays directly are not read back to check.
"""

from __future__ import annotations

import math
import warnings

import numpy as np

from .errors import RenderError

ROLL_WARNING_DEG = 45.0  # a levelled camera's roll is 0, one posed for the wrong up axis's up to 90
LEVEL_CONE_DEG = 10.0  # within this of straight up or down a camera's roll is not measured

_AXES = {"x": 0, "y": 1, "z": 2}


class CameraRollWarning(UserWarning):
    """A camera pose rolled against the renderer's up axis (see :mod:`warprt.poses`)."""


def up_vector(up, name: str = "up") -> np.ndarray:
    """The unit vector of an up axis: ``"x"``, ``"y"``, ``"z"`` (or with a sign, ``"-z"``), an
    axis index 0, 1, 2 (Newton's ``model.up_axis`` is one), or a non-zero 3-vector."""
    if isinstance(up, str):
        key = up.strip().lower()
        sign = -1.0 if key.startswith("-") else 1.0
        key = key.lstrip("+-")
        if key not in _AXES:
            raise RenderError(f"{name}: expected an axis 'x', 'y' or 'z' (optionally signed) or a vector, got {up!r}")
        v = np.zeros(3)
        v[_AXES[key]] = sign
        return v
    if not isinstance(up, bool) and isinstance(up, (int, np.integer)) or type(up).__name__ == "Axis":
        try:
            index = int(up)
        except (TypeError, ValueError):
            index = -1
        if index not in (0, 1, 2):
            raise RenderError(f"{name}: an axis index must be 0 (x), 1 (y) or 2 (z), got {up!r}")
        v = np.zeros(3)
        v[index] = 1.0
        return v
    try:
        v = np.asarray(up, np.float64)
    except (TypeError, ValueError):
        v = None
    if v is None or v.shape != (3,) or not np.isfinite(v).all() or not np.linalg.norm(v) > 0.0:
        raise RenderError(f"{name}: expected an axis 'x', 'y' or 'z', an index 0-2 or a non-zero 3-vector, "
                          f"got {up!r:.60}")
    return v / np.linalg.norm(v)


def _quaternion(m: np.ndarray) -> np.ndarray:
    """Unit quaternions (x, y, z, w) of rotation matrices (..., 3, 3): Warp's
    ``quat_from_matrix`` (float32, as the device stores a pose; the quaternion a batch's own
    default camera pose takes), normalised in float64."""
    import warp as wp

    m = np.asarray(m, np.float64)
    flat = m.reshape(-1, 3, 3)
    q = np.array([wp.quat_from_matrix(wp.mat33(*x.reshape(-1))) for x in flat], np.float64).reshape(m.shape[:-2] + (4,))
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


def look_at(eye, target, up) -> np.ndarray:
    """Camera-to-world pose(s) (x, y, z, qx, qy, qz, qw) of a camera at ``eye`` looking at
    ``target`` with the world's ``up`` axis up in its image (see :func:`up_vector` for the forms
    ``up`` takes: ``"y"`` for warprt scenes, ``"z"`` for Newton's default, a vector). ``eye`` and
    ``target`` broadcast: (W, C, 3) arrays give (W, C, 7) poses for
    :meth:`warprt.BatchRenderer.set_camera_poses`. The frame is :class:`warprt.Camera`'s:
    w = normalize(eye - target), u = normalize(up × w), v = w × u."""
    U = up_vector(up)
    eye = np.asarray(eye, np.float64)
    target = np.asarray(target, np.float64)
    try:
        eye_b, target_b = np.broadcast_arrays(eye, target)
    except ValueError:
        raise RenderError(f"look_at: eye {eye.shape} and target {target.shape} do not broadcast") from None
    if eye_b.shape[-1:] != (3,) or not (np.isfinite(eye_b).all() and np.isfinite(target_b).all()):
        raise RenderError(f"look_at: eye and target must be finite 3-vectors (..., 3), got {eye.shape} and "
                          f"{target.shape}")
    w = eye_b - target_b
    length = np.linalg.norm(w, axis=-1, keepdims=True)
    if (length == 0).any():
        where = tuple(int(i) for i in np.argwhere(length[..., 0] == 0)[0])
        raise RenderError(f"look_at: eye and target are the same point{f' at {list(where)}' if where else ''}")
    w = w / length
    u = np.cross(U, w)
    ulen = np.linalg.norm(u, axis=-1, keepdims=True)
    if (ulen < 1e-9).any():
        where = tuple(int(i) for i in np.argwhere(ulen[..., 0] < 1e-9)[0])
        raise RenderError(f"look_at: the view{f' at {list(where)}' if where else ''} is parallel to up "
                          f"{U.tolist()}: the camera's roll is undefined (give another up or move the eye)")
    u = u / ulen
    v = np.cross(w, u)
    q = _quaternion(np.stack([u, v, w], axis=-1))
    return np.concatenate([eye_b, q], axis=-1)


def _rotate(q: np.ndarray, v) -> np.ndarray:
    """Vectors v rotated by unit quaternions q (..., 4) (x, y, z, w)."""
    qv, qw = q[..., :3], q[..., 3:]
    v = np.broadcast_to(np.asarray(v, np.float64), qv.shape)
    t = 2.0 * np.cross(qv, v)
    return v + qw * t + np.cross(qv, t)


def camera_roll(poses, up) -> np.ndarray:
    """The roll in degrees, [0, 180], of camera-to-world poses (..., 7) against the world's
    ``up`` axis (0 for a camera within LEVEL_CONE_DEG of looking straight up or down)."""
    p = np.asarray(poses, np.float64)
    q = p[..., 3:] / np.linalg.norm(p[..., 3:], axis=-1, keepdims=True)
    U = up_vector(up)
    w = _rotate(q, (0.0, 0.0, 1.0))
    v = _rotate(q, (0.0, 1.0, 0.0))
    level = U - (w @ U)[..., None] * w
    n = np.linalg.norm(level, axis=-1)
    steep = n < math.sin(math.radians(LEVEL_CONE_DEG))
    cos = np.clip(np.sum(v * level, axis=-1) / np.where(steep, 1.0, n), -1.0, 1.0)
    return np.where(steep, 0.0, np.degrees(np.arccos(cos)))


def warn_rolled(poses, up, name: str, stacklevel: int = 3) -> None:
    """A CameraRollWarning naming the first pose of ``poses`` (..., 7) rolled by more than
    ROLL_WARNING_DEG against ``up``."""
    roll = camera_roll(poses, up)
    bad = np.argwhere(roll > ROLL_WARNING_DEG)
    if len(bad):
        index = tuple(int(i) for i in bad[0])
        U = up_vector(up)
        axis = next((f"{'+-'[int(U[k] < 0)]}{'xyz'[k]}" for k in range(3) if abs(U[k]) == 1.0), str(U.tolist()))
        warnings.warn(f"{name}[{', '.join(map(str, index))}]: the camera is rolled {roll[index]:.0f}° against the "
                      f"renderer's up axis {axis} ({len(bad)} of {roll.size} cameras); a pose made with another "
                      f"up axis shows the world turned: use warprt.look_at(eye, target, up={axis!r}) (filter "
                      "warprt.poses.CameraRollWarning if the roll is meant)", CameraRollWarning, stacklevel=stacklevel)


__all__ = ["CameraRollWarning", "camera_roll", "look_at", "up_vector"]
