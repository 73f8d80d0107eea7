"""Mesh assets on the host: reading files (through trimesh), checking triangles, vertex normals,
new vertex positions, and a small bounded cache of parsed files.

A mesh *asset* is one set of vertices and faces (a file, or inline arrays identified by their
content); the builder turns each into one ``wp.Mesh`` and every mesh shape into an instance of
it, so re-posing or re-lighting a scene never rebuilds a BVH.
"""

from __future__ import annotations

import hashlib
import warnings

import numpy as np
import warp as wp

from .errors import RenderError, SceneError
from .scene.description import Mesh, validate_arrays


def prepare_mesh(v: np.ndarray, f: np.ndarray, degenerate: str = "error") -> tuple[np.ndarray, np.ndarray]:
    """Check a triangle mesh and return float32 vertices and int32 faces.

    NaN/Inf vertices, out-of-range indices and empty meshes raise; zero-area faces raise unless
    ``degenerate="drop"``, which removes them (with a warning).
    """
    v, f = validate_arrays(v, f)
    a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    area2 = np.linalg.norm(np.cross(b - a, c - a), axis=1)
    edge = np.maximum(np.maximum(np.linalg.norm(b - a, axis=1), np.linalg.norm(c - a, axis=1)),
                      np.linalg.norm(c - b, axis=1))
    bad = (area2 <= 1e-12 * edge * edge) | (f[:, 0] == f[:, 1]) | (f[:, 1] == f[:, 2]) | (f[:, 0] == f[:, 2])
    if bad.any():
        if degenerate == "error":
            raise SceneError(
                f"{int(bad.sum())} of {len(f)} faces have zero area (first: face {int(np.argmax(bad))}); "
                "fix the mesh or set degenerate = \"drop\"", "faces")
        warnings.warn(f"dropping {int(bad.sum())} zero-area faces of {len(f)}", stacklevel=3)
        f = f[~bad]
        if len(f) == 0:
            raise SceneError("every face has zero area: nothing is left to render", "faces")
    v32 = v.astype(np.float32)
    return v32, f.astype(np.int32)


def vertex_normals(v: np.ndarray, f: np.ndarray) -> np.ndarray:
    """Area-weighted vertex normals (unit; a vertex with no area gets +z)."""
    fn = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]]).astype(np.float64)
    n = np.zeros((len(v), 3))
    for k in range(3):
        np.add.at(n, f[:, k], fn)
    length = np.linalg.norm(n, axis=1, keepdims=True)
    out = np.where(length > 0, n / np.where(length > 0, length, 1), np.array([0.0, 0.0, 1.0]))
    return out.astype(np.float32)


def asset_key(m: Mesh) -> tuple:
    """Meshes with the same file, or the same inline arrays (by content), share one asset."""
    if m.file is not None:
        return ("file", m.file, m.degenerate)
    h = hashlib.blake2b(digest_size=16)
    for a in (m.vertices, m.faces) + (() if m.uv is None else (m.uv,)):
        h.update(str(a.shape).encode())
        h.update(np.ascontiguousarray(a).tobytes())
    return ("arrays", h.hexdigest(), m.degenerate)


def as_points(points, count: int, device) -> "np.ndarray | object":
    """Validate new vertex positions: (count, 3) numbers, or a wp.array of vec3 on ``device``."""
    if isinstance(points, wp.array):
        if points.dtype != wp.vec3 or points.shape != (count,):
            raise RenderError(f"points must be a wp.array of {count} vec3, got "
                              f"{getattr(points.dtype, '__name__', points.dtype)} {points.shape}")
        if points.device != device:
            raise RenderError(f"points are on {points.device}, the scene on {device}")
        from .checks import check_points

        check_points(points)  # on the device: NaN, Inf or huge coordinates named, not rendered
        return points
    if isinstance(points, (str, bytes)) or points is None:
        raise RenderError(f"points must be ({count}, 3) numbers or a wp.array of vec3, got {points!r:.60}")
    try:
        p64 = np.asarray(points, dtype=np.float64)
    except (TypeError, ValueError):
        raise RenderError(f"points must be ({count}, 3) numbers, got {type(points).__name__}") from None
    if p64.shape != (count, 3):
        raise RenderError(f"points must have shape ({count}, 3), got {p64.shape}")
    from .checks import VERTEX_LIMIT, describe_point

    bad = ~np.isfinite(p64).all(axis=1) | (np.abs(np.nan_to_num(p64)) > VERTEX_LIMIT).any(axis=1)
    if bad.any():
        i = int(np.argmax(bad))
        raise RenderError(f"points[{i}]: {describe_point(p64[i], limit=VERTEX_LIMIT)}")
    return p64.astype(np.float32)
