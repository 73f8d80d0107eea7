"""Object-to-world transforms: scale, then rotate, then translate; and their quaternions (Warp's
x, y, z, w layout) for the device.

The rotation is given one of three ways: Euler angles (``rotate``, degrees about x, then y, then
z), a quaternion (``quaternion``, (x, y, z, w) as Warp orders it: the name scene files use; the
field that holds it, and an older keyword, is ``rotation_quaternion``), or taken apart from a
matrix by :meth:`Transform.from_matrix`. The device's instance pose is scale → rotate →
translate, so a matrix is accepted only when it is exactly that: columns orthogonal (no shear),
a positive determinant (no mirror, unless the caller asks for it to become a negative scale) and
no zero column (not singular). Keyframed rotations interpolate by :func:`slerp` (see
:func:`rotation_keys` for Euler keys more than 180 degrees apart).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Mapping, Sequence

import numpy as np

from ..errors import SceneError
from .values import Vec3, as_quaternion, as_vec3, checked_keywords, finite, set_field

# |cos| between two columns of a matrix's 3x3 part above which it is sheared, and the relative
# length of a column below which it is singular. The float32 round-off of a rotation matrix (about
# 1e-7) passes; a rotation typed with 4 decimals (errors up to 5e-5) generally does not, and is
# better given as a quaternion or with more digits.
SHEAR_TOLERANCE = 1e-5
SINGULAR_TOLERANCE = 1e-9
# largest rotation, in degrees of Euler angle (summed over x, y, z), between two keyframes that
# slerp interpolates as it stands (see rotation_keys)
EULER_STEP = 180.0


def quaternion_matrix(q: Sequence[float]) -> np.ndarray:
    """The 3x3 rotation matrix of a unit quaternion (x, y, z, w)."""
    x, y, z, w = (float(c) for c in q)
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def matrix_quaternion(m: np.ndarray) -> np.ndarray:
    """The unit quaternion (x, y, z, w) of a 3x3 rotation matrix (Shepperd's method: the branch
    with the largest diagonal term, so no division by a small number)."""
    tr = np.trace(m)
    if tr > 0:
        s = math.sqrt(tr + 1.0) * 2
        q = [(m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s, 0.25 * s]
    elif m[0, 0] > m[1, 1] and m[0, 0] > m[2, 2]:
        s = math.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2]) * 2
        q = [0.25 * s, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s, (m[2, 1] - m[1, 2]) / s]
    elif m[1, 1] > m[2, 2]:
        s = math.sqrt(1.0 + m[1, 1] - m[0, 0] - m[2, 2]) * 2
        q = [(m[0, 1] + m[1, 0]) / s, 0.25 * s, (m[1, 2] + m[2, 1]) / s, (m[0, 2] - m[2, 0]) / s]
    else:
        s = math.sqrt(1.0 + m[2, 2] - m[0, 0] - m[1, 1]) * 2
        q = [(m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, 0.25 * s, (m[1, 0] - m[0, 1]) / s]
    q = np.asarray(q)
    return q / np.linalg.norm(q)


def quaternion_product(a, b) -> np.ndarray:
    """The rotation b, then a, as one quaternion (x, y, z, w)."""
    ax, ay, az, aw = a
    bx, by, bz, bw = b
    return np.array([aw * bx + ax * bw + ay * bz - az * by, aw * by - ax * bz + ay * bw + az * bx,
                     aw * bz + ax * by - ay * bx + az * bw, aw * bw - ax * bx - ay * by - az * bz])


def quaternion_y_to(v) -> np.ndarray:
    """The shortest rotation taking the y axis to the direction of ``v`` (identity for v = 0)."""
    v = np.asarray(v, np.float64)
    n = np.linalg.norm(v)
    if n == 0.0:
        return np.array([0.0, 0.0, 0.0, 1.0])
    u = v / n
    if u[1] < -1.0 + 1e-12:  # straight down: half a turn about x
        return np.array([1.0, 0.0, 0.0, 0.0])
    q = np.array([u[2], 0.0, -u[0], 1.0 + u[1]])  # (y × u, 1 + y·u), normalised
    return q / np.linalg.norm(q)


def slerp(q0: Sequence[float], q1: Sequence[float], f: float) -> np.ndarray:
    """Spherical linear interpolation of unit quaternions along the shorter arc: at fraction f the
    rotation is q0 followed by f times the angle of q0⁻¹q1 about its fixed axis."""
    a, b = np.asarray(q0, dtype=np.float64), np.asarray(q1, dtype=np.float64)
    b = same_hemisphere(b, a)
    d = min(1.0, float(np.dot(a, b)))
    theta = math.acos(d)
    if theta < 1e-9:  # (nearly) the same rotation: lerp is exact to float64 round-off
        q = a + (b - a) * f
    else:
        q = (math.sin((1.0 - f) * theta) * a + math.sin(f * theta) * b) / math.sin(theta)
    return q / np.linalg.norm(q)


@checked_keywords
@dataclass(frozen=True)
class Transform:
    """Scale, then rotate, then translate. The rotation is ``rotate`` (Euler angles in degrees
    about x, then y, then z) or ``quaternion`` ((x, y, z, w), normalised; held in the field
    ``rotation_quaternion``, which is also accepted as the keyword), not both."""

    KEYWORD_ALIASES = {"quaternion": "rotation_quaternion"}  # (the scene files' name; checked_keywords)

    translate: Vec3 = (0.0, 0.0, 0.0)
    rotate: Vec3 = (0.0, 0.0, 0.0)  # degrees about x, then y, then z (extrinsic)
    scale: Vec3 | float = (1.0, 1.0, 1.0)
    rotation_quaternion: tuple | None = None  # (x, y, z, w); stored unit length with w >= 0

    def __post_init__(self):
        set_field(self, "translate", as_vec3(self.translate, "translate"))
        set_field(self, "rotate", as_vec3(self.rotate, "rotate"))
        s = self.scale
        if isinstance(s, (int, float, np.integer, np.floating)) and not isinstance(s, bool):
            s = (s, s, s)
        s = as_vec3(s, "scale")
        if any(c == 0.0 for c in s):
            raise SceneError(f"must be non-zero on every axis, got {list(s)}", "scale")
        set_field(self, "scale", s)
        if self.rotation_quaternion is not None:
            if any(a != 0.0 for a in self.rotate):
                raise SceneError("give the rotation once: rotate (Euler angles) or a quaternion, not both",
                                 "rotation_quaternion")
            set_field(self, "rotation_quaternion", as_quaternion(self.rotation_quaternion, "rotation_quaternion"))

    @classmethod
    def from_quaternion(cls, q: Sequence[float], translate: Sequence[float] = (0.0, 0.0, 0.0),
                        scale: Sequence[float] | float = (1.0, 1.0, 1.0)) -> "Transform":
        """A transform whose rotation is the quaternion ``q`` = (x, y, z, w) (Warp's order)."""
        return cls(translate=translate, scale=scale, rotation_quaternion=q)  # type: ignore[arg-type]

    @classmethod
    def from_matrix(cls, m: Any, name: str = "matrix", allow_mirror: bool = False) -> "Transform":
        """Take a 4x4 (last row 0, 0, 0, 1) or 3x4 affine matrix apart into translate, rotation
        (a quaternion) and scale, so that ``from_matrix(m).matrix() == m`` to float64 round-off.

        The 3x3 part must be a rotation times a diagonal scale: its columns are the scaled axes,
        so they must be orthogonal (no shear) and non-zero (not singular), and its determinant
        positive (no mirror). ``allow_mirror=True`` turns a mirror into a negative x scale
        instead (glTF nodes may mirror). Errors name ``name``.
        """
        try:
            a = np.array(m, dtype=np.float64)
        except (TypeError, ValueError):
            raise SceneError("expected a 4x4 or 3x4 matrix of numbers (rows)", name) from None
        if a.shape not in ((4, 4), (3, 4)):
            raise SceneError(f"expected a 4x4 or 3x4 matrix (a list of rows), got shape {a.shape}", name)
        if not np.isfinite(a).all():
            raise SceneError("must be finite (NaN or Inf found)", name)
        if a.shape == (4, 4) and not np.array_equal(a[3], [0.0, 0.0, 0.0, 1.0]):
            raise SceneError(f"the last row must be [0, 0, 0, 1] (an affine transform), got {a[3].tolist()}", name)
        m3 = a[:3, :3]
        # scale -> rotate -> translate is M = R · diag(s): column j is R's column j times s_j
        s = np.linalg.norm(m3, axis=0)
        big = float(s.max())
        if big == 0.0 or float(s.min()) <= SINGULAR_TOLERANCE * big:
            raise SceneError(f"is singular: the 3x3 part maps an axis to (nearly) zero (column lengths "
                             f"{s.tolist()})", name)
        u = m3 / s
        cos = np.abs(u.T @ u - np.eye(3))
        worst = float(cos.max())
        if worst > SHEAR_TOLERANCE:
            i, j = np.unravel_index(int(np.argmax(cos)), cos.shape)
            angle = math.degrees(math.acos(min(1.0, float(np.clip(u[:, i] @ u[:, j], -1, 1)))))
            raise SceneError(f"has shear: its columns {i} and {j} meet at {angle:.4g} degrees, not 90 "
                             f"(warprt's pose is scale -> rotate -> translate; bake shear into the vertices)", name)
        if np.linalg.det(u) < 0.0:
            if not allow_mirror:
                raise SceneError("mirrors (negative determinant): a rotation cannot; give a negative scale "
                                 "instead", name)
            s = s * np.array([-1.0, 1.0, 1.0])
            u = u * np.array([-1.0, 1.0, 1.0])
        # the nearest rotation (polar factor), so the quaternion is exact for nearly orthogonal input
        w, _, vt = np.linalg.svd(u)
        r = w @ vt
        q = matrix_quaternion(r)
        return cls(translate=tuple(a[:3, 3]), scale=tuple(s), rotation_quaternion=tuple(q))  # type: ignore

    @property
    def uniform_scale(self) -> float | None:
        s = self.scale
        return s[0] if s[0] == s[1] == s[2] and s[0] > 0 else None

    def rotation_matrix(self) -> np.ndarray:
        if self.rotation_quaternion is not None:
            return quaternion_matrix(self.rotation_quaternion)
        rx, ry, rz = (math.radians(a) for a in self.rotate)
        cx, sx, cy, sy, cz, sz = math.cos(rx), math.sin(rx), math.cos(ry), math.sin(ry), math.cos(rz), math.sin(rz)
        mx = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
        my = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
        mz = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
        return mz @ my @ mx

    def quaternion(self) -> np.ndarray:
        """Rotation as a unit quaternion (x, y, z, w), Warp's layout."""
        if self.rotation_quaternion is not None:
            return np.array(self.rotation_quaternion)
        return matrix_quaternion(self.rotation_matrix())

    def matrix(self) -> np.ndarray:
        """The 4x4 affine matrix mapping object space to world space."""
        m = np.eye(4)
        m[:3, :3] = self.rotation_matrix() @ np.diag(self.scale)
        m[:3, 3] = self.translate
        return m

    def apply_point(self, p: Sequence[float]) -> Vec3:
        return tuple(float(c) for c in self.matrix() @ np.array([*p, 1.0]))[:3]  # type: ignore

    def apply_vector(self, v: Sequence[float]) -> Vec3:
        return tuple(float(c) for c in self.matrix()[:3, :3] @ np.asarray(v, dtype=float))  # type: ignore

    def apply_normal(self, n: Sequence[float]) -> Vec3:
        m = np.linalg.inv(self.matrix()[:3, :3]).T @ np.asarray(n, dtype=float)
        return tuple(float(c) for c in m / np.linalg.norm(m))  # type: ignore


TRANSFORM_FIELDS = ("translate", "rotate", "quaternion", "matrix", "scale")


def as_transform(x: Any, name: str) -> Transform | None:
    """A Transform, or a table of ``translate``/``rotate``/``scale`` with ``quaternion`` instead
    of ``rotate`` (``rotation_quaternion``, Python's older keyword, is the same field), or
    ``matrix`` alone (a 4x4 or 3x4 list of rows)."""
    if x is None or isinstance(x, Transform):
        return x
    if isinstance(x, Mapping) and "rotation_quaternion" in x:
        if "quaternion" in x:
            raise SceneError("give it once: quaternion and rotation_quaternion are the same field",
                             f"{name}.rotation_quaternion")
        x = {("quaternion" if k == "rotation_quaternion" else k): v for k, v in x.items()}
    if isinstance(x, Mapping):
        unknown = set(x) - set(TRANSFORM_FIELDS)
        if unknown:
            raise SceneError(f"unknown field(s) {sorted(unknown)}; expected translate, rotate (or quaternion), "
                             f"scale, or matrix alone", name)
        try:
            if "matrix" in x:
                others = sorted(set(x) - {"matrix"})
                if others:
                    raise SceneError(f"a matrix gives the whole transform: drop {', '.join(others)} or the matrix",
                                     "matrix")
                return Transform.from_matrix(x["matrix"], "matrix")
            if "quaternion" in x:
                if "rotate" in x:
                    raise SceneError("give the rotation once: rotate (Euler angles) or quaternion, not both",
                                     "quaternion")
                args = {k: v for k, v in x.items() if k != "quaternion"}
                q = as_quaternion(x["quaternion"], "quaternion")
                return Transform(**args, rotation_quaternion=q)
            return Transform(**x)
        except SceneError as e:
            raise e.within(name) from None
    raise SceneError(f"expected a table with translate/rotate/scale (or quaternion, or matrix), got {x!r}", name)


def same_hemisphere(q: np.ndarray, ref: np.ndarray) -> np.ndarray:
    """q or -q, whichever is nearer ref (so slerp from ref to it takes the short way round)."""
    return -q if float(np.dot(q, ref)) < 0.0 else q


def euler_quaternion(angles: Sequence[float]) -> np.ndarray:
    return Transform(rotate=angles).quaternion()  # type: ignore[arg-type]


def rotation_keys(keys: Sequence[tuple[float, Any]]) -> list[tuple[float, np.ndarray]]:
    """Rotation keyframes as (time, unit quaternion), ready for piecewise :func:`slerp`.

    ``keys`` are (time, value) with value ``("rotate", euler_degrees)`` or ``("quaternion", q)``.
    Slerp takes the shorter arc, so a quaternion pair never turns more than 180 degrees. Euler
    keys say more: 0 to 360 degrees about y is a full turn, which the user meant. Between two
    Euler keys whose angles differ by D = |Δx| + |Δy| + |Δz| >= 180 degrees, ``n = floor(D / 180)
    + 1`` equal steps are made, with keys inserted at the Euler-interpolated angles; each step
    then rotates by less than 180 degrees (a rotation's angle is at most the sum of its Euler
    angles), so slerp follows the direction the angles give. About one axis this is exact: the
    angle grows in proportion to time.
    """
    out: list[tuple[float, np.ndarray]] = []
    prev = None
    for t, (kind, value) in keys:
        if prev is not None and kind == "rotate" and prev[1][0] == "rotate":
            t0, (_, e0) = prev
            delta = np.subtract(value, e0)
            steps = int(math.floor(float(np.abs(delta).sum()) / EULER_STEP)) + 1
            for k in range(1, steps):
                f = k / steps
                out.append((t0 + (t - t0) * f, euler_quaternion(tuple(np.add(e0, delta * f)))))
        q = euler_quaternion(value) if kind == "rotate" else np.array(as_quaternion(value, "quaternion"))
        out.append((t, q))
        prev = (t, (kind, value))
    return out


def interpolate_rotation(keys: Sequence[tuple[float, np.ndarray]], t: float) -> np.ndarray:
    """The rotation at time t of keys from :func:`rotation_keys`: slerp between the keys around
    t, held before the first and after the last."""
    if t <= keys[0][0]:
        return keys[0][1]
    if t >= keys[-1][0]:
        return keys[-1][1]
    for (ta, qa), (tb, qb) in zip(keys, keys[1:]):
        if ta <= t <= tb:
            return slerp(qa, qb, (t - ta) / (tb - ta))
    return keys[-1][1]
