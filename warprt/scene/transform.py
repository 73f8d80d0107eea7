"""Object-to-world transforms: scale, then rotate (Euler angles, degrees), then translate; and
their quaternions (Warp's x, y, z, w layout) for the device."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Mapping, Sequence

import numpy as np

from ..errors import SceneError
from .values import Vec3, as_vec3, checked_keywords, set_field


@checked_keywords
@dataclass(frozen=True)
class Transform:
    """Scale, then rotate (Euler angles in degrees about x, then y, then z), then translate."""

    translate: Vec3 = (0.0, 0.0, 0.0)
    rotate: Vec3 = (0.0, 0.0, 0.0)  # degrees about x, then y, then z (extrinsic)
    scale: Vec3 | float = (1.0, 1.0, 1.0)

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

    @property
    def uniform_scale(self) -> float | None:
        s = self.scale
        return s[0] if s[0] == s[1] == s[2] and s[0] > 0 else None

    def rotation_matrix(self) -> np.ndarray:
        rx, ry, rz = (math.radians(a) for a in self.rotate)
        cx, sx, cy, sy, cz, sz = math.cos(rx), math.sin(rx), math.cos(ry), math.sin(ry), math.cos(rz), math.sin(rz)
        mx = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
        my = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
        mz = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
        return mz @ my @ mx

    def quaternion(self) -> np.ndarray:
        """Rotation as a unit quaternion (x, y, z, w), Warp's layout."""
        m = self.rotation_matrix()
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


def as_transform(x: Any, name: str) -> Transform | None:
    if x is None or isinstance(x, Transform):
        return x
    if isinstance(x, Mapping):
        unknown = set(x) - {"translate", "rotate", "scale"}
        if unknown:
            raise SceneError(f"unknown field(s) {sorted(unknown)}; expected translate, rotate, scale", name)
        try:
            return Transform(**x)
        except SceneError as e:
            raise e.within(name) from None
    raise SceneError(f"expected a table with translate/rotate/scale, got {x!r}", name)


def same_hemisphere(q: np.ndarray, ref: np.ndarray) -> np.ndarray:
    """q or -q, whichever is nearer ref (so slerp from ref to it takes the short way round)."""
    return -q if float(np.dot(q, ref)) < 0.0 else q
