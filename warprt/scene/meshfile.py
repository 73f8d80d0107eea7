"""Mesh files on the host: reading them through trimesh (vertices, faces, texture coordinates),
with a small bounded cache of parsed files, and the check of per-vertex texture coordinates.
The description reads a file's UVs through it when a material maps a texture by uv (the builder
then finds the parsed file in the cache)."""

from __future__ import annotations

import os
import threading
from collections import OrderedDict
from typing import Any

import numpy as np

from ..errors import SceneError

CACHE_ENTRIES = 16  # parsed mesh files kept (least recently used goes first)

_file_cache: "OrderedDict[tuple, tuple]" = OrderedDict()
_file_lock = threading.Lock()


def read_mesh_file(path: str) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """A mesh file's vertices, faces and per-vertex texture coordinates (None where the file has
    none), read through trimesh without processing (vertex order kept; trimesh splits vertices
    whose UVs differ and puts every format's UVs in OBJ's convention, v = 0 at the image's
    bottom)."""
    try:
        st = os.stat(path)
    except OSError:
        raise SceneError(f"mesh file not found: {path!r}", "file") from None
    key = (path, st.st_mtime_ns, st.st_size)
    with _file_lock:
        if key in _file_cache:
            _file_cache.move_to_end(key)
            return _file_cache[key]
    import trimesh

    try:
        loaded = trimesh.load(path, force="mesh", process=False)
    except Exception as e:  # trimesh raises many types for unreadable files
        raise SceneError(f"cannot read mesh file {os.path.basename(path)!r}: {e}", "file") from None
    v = np.asarray(getattr(loaded, "vertices", np.zeros((0, 3))), dtype=np.float64)
    f = np.asarray(getattr(loaded, "faces", np.zeros((0, 3))), dtype=np.int64)
    if len(v) == 0 or len(f) == 0:
        raise SceneError(f"mesh file {os.path.basename(path)!r} holds no triangles", "file")
    uv = getattr(getattr(loaded, "visual", None), "uv", None)
    if uv is not None:
        try:
            uv = validate_uv(uv, len(v))
        except SceneError as e:
            raise SceneError(f"mesh file {os.path.basename(path)!r}: {e.problem}", "file") from None
    with _file_lock:
        _file_cache[key] = (v, f, uv)
        while len(_file_cache) > CACHE_ENTRIES:
            _file_cache.popitem(last=False)
    return v, f, uv


def validate_uv(uv: Any, n_vertices: int) -> np.ndarray:
    """Per-vertex texture coordinates as a read-only float64 (N, 2) array, else a SceneError on
    ``uv`` naming the shape it has or the first bad value."""
    try:
        a = np.array(uv, dtype=np.float64)
    except (TypeError, ValueError):
        raise SceneError(f"expected ({n_vertices}, 2) numbers (one (u, v) per vertex), got {type(uv).__name__}",
                         "uv") from None
    if a.shape != (n_vertices, 2):
        raise SceneError(f"expected shape ({n_vertices}, 2) (one (u, v) per vertex), got {a.shape}", "uv")
    bad = ~np.isfinite(a).all(axis=1) | (np.abs(np.nan_to_num(a)) > 1e30).any(axis=1)
    if bad.any():
        i = int(np.argmax(bad))
        raise SceneError(f"uv[{i}] = {a[i].tolist()} is not a finite coordinate (|u|, |v| <= 1e30)", "uv")
    a.setflags(write=False)
    return a


__all__ = ["CACHE_ENTRIES", "read_mesh_file", "validate_uv"]
