"""Rays against triangle soups in float64, in numpy: an independent reference for warprt's mesh
hits and shadow tests (tests/test_mesh_shadows.py).

Triangles are grouped into clusters of ``CLUSTER`` along a Morton curve of their centroids; a ray
is tested against every cluster's box (slab test), then against the triangles of the clusters it
meets with Möller and Trumbore's test in float64. Each answer comes with a margin: how close the
ray passes to an edge of a triangle it meets or nearly meets (in barycentric units), or how close
the hit lies to the segment's ends, so a caller can leave out the rays whose answer float64 (or
float32, in the renderer) could flip.
"""

from __future__ import annotations

import numpy as np

CLUSTER = 32
NEAR = 1e-6  # barycentric and relative-t distance below which an answer is called doubtful


def _morton(p: np.ndarray) -> np.ndarray:
    lo, hi = p.min(0), p.max(0)
    q = ((p - lo) / np.maximum(hi - lo, 1e-300) * 1023).astype(np.uint64)

    def spread(x):
        x = (x | (x << np.uint64(16))) & np.uint64(0x030000FF)
        x = (x | (x << np.uint64(8))) & np.uint64(0x0300F00F)
        x = (x | (x << np.uint64(4))) & np.uint64(0x030C30C3)
        return (x | (x << np.uint64(2))) & np.uint64(0x09249249)

    return spread(q[:, 0]) | (spread(q[:, 1]) << np.uint64(1)) | (spread(q[:, 2]) << np.uint64(2))


class Triangles:
    """A triangle soup (N, 3, 3) float64 for nearest hits and segment tests."""

    def __init__(self, tris: np.ndarray):
        tris = np.asarray(tris, np.float64)
        order = np.argsort(_morton(tris.mean(1)), kind="stable")
        self.index = order  # position in the clustered order -> original triangle index
        self.tris = tris[order]
        n = len(tris)
        self.starts = np.arange(0, n, CLUSTER)
        lo = np.minimum.reduceat(self.tris.min(1), self.starts, axis=0)
        hi = np.maximum.reduceat(self.tris.max(1), self.starts, axis=0)
        pad = 1e-9 * (np.abs(lo).max() + np.abs(hi).max())
        self.lo, self.hi = lo - pad, hi + pad
        self.e1 = self.tris[:, 1] - self.tris[:, 0]
        self.e2 = self.tris[:, 2] - self.tris[:, 0]
        self.normals = np.cross(self.e1, self.e2)
        self.normals /= np.linalg.norm(self.normals, axis=1, keepdims=True)

    def _pairs(self, o, d, t_max, chunk=512):
        """(ray, triangle) pairs whose ray segment [0, t_max] meets the triangle's cluster box."""
        rays, tris = [], []
        n = len(self.tris)
        inv_all = 1.0 / np.where(d == 0.0, 1e-300, d)  # (a zero component: a huge slope, never NaN)
        for a in range(0, len(o), chunk):
            oo, inv, tm = o[a:a + chunk, None, :], inv_all[a:a + chunk, None, :], t_max[a:a + chunk, None]
            with np.errstate(over="ignore", invalid="ignore"):
                t0 = (self.lo[None] - oo) * inv
                t1 = (self.hi[None] - oo) * inv
            near = np.minimum(t0, t1).max(axis=2)
            far = np.maximum(t0, t1).min(axis=2)
            r, c = np.nonzero((near <= far) & (far >= 0) & (near <= tm))
            for k in range(CLUSTER):
                t = self.starts[c] + k
                ok = t < n
                rays.append(r[ok] + a)
                tris.append(t[ok])
        return np.concatenate(rays), np.concatenate(tris)

    def _hits(self, o, d, t_max):
        """Möller–Trumbore for every candidate pair: (ray, clustered triangle, t, margin) of the
        hits with 0 < t < t_max, and the least margin of each ray over all candidates."""
        r, k = self._pairs(o, d, t_max)
        e1, e2 = self.e1[k], self.e2[k]
        dd = d[r]
        pv = np.cross(dd, e2)
        det = (e1 * pv).sum(1)
        with np.errstate(divide="ignore", invalid="ignore"):
            inv = 1.0 / det
            tv = o[r] - self.tris[k, 0]
            u = (tv * pv).sum(1) * inv
            qv = np.cross(tv, e1)
            v = (dd * qv).sum(1) * inv
            t = (e2 * qv).sum(1) * inv
        w = 1.0 - u - v
        inside = (u > 0) & (v > 0) & (w > 0) & np.isfinite(t)
        # how near the ray passes to the triangle's boundary, in barycentric units: inside, the
        # least coordinate; outside, the largest amount one falls below 0 (a hair's miss counts)
        edge = np.where(inside, np.minimum(np.minimum(u, v), w), np.maximum(np.maximum(-u, -v), -w))
        close = np.where(np.isfinite(edge) & (t > 0) & (t < t_max[r]), edge, np.inf)
        margin = np.full(len(o), np.inf)
        np.minimum.at(margin, r, close)
        hit = inside & (t > 0) & (t < t_max[r])
        return r[hit], k[hit], t[hit], margin

    def nearest(self, o, d):
        """Nearest hit of each ray (o, d): (t (inf: none), original triangle index (-1), margin)."""
        o, d = np.asarray(o, np.float64), np.asarray(d, np.float64)
        r, k, t, margin = self._hits(o, d, np.full(len(o), np.inf))
        best = np.full(len(o), np.inf)
        np.minimum.at(best, r, t)
        tri = np.full(len(o), -1)
        first = t == best[r]
        tri[r[first]] = self.index[k[first]]
        # a second hit within NEAR of the first (an edge shared by two triangles) is doubtful too
        second = np.full(len(o), np.inf)
        np.minimum.at(second, r[~first], t[~first])
        with np.errstate(invalid="ignore"):
            gap = np.abs(second - best) / np.maximum(best, 1e-300)
        margin = np.minimum(margin, np.where(np.isfinite(gap), gap, np.inf))
        return best, tri, margin

    def blocked(self, o, d, t_max, skip):
        """Whether each segment o + t d, 0 < t < t_max, meets a triangle other than the
        original-index triangle ``skip`` (the one the segment starts on), and a margin: the least
        barycentric distance to an edge over the triangles it meets or nearly meets, and the
        distance of a hit to the segment's ends relative to its length."""
        o, d = np.asarray(o, np.float64), np.asarray(d, np.float64)
        t_max = np.asarray(t_max, np.float64)
        r, k, t, margin = self._hits(o, d, t_max)
        mine = self.index[k] == np.asarray(skip)[r]
        r, t = r[~mine], t[~mine]
        out = np.zeros(len(o), bool)
        out[r] = True
        ends = np.minimum(t, t_max[r] - t) / t_max[r]
        end_margin = np.full(len(o), np.inf)
        np.minimum.at(end_margin, r, ends)
        return out, np.minimum(margin, end_margin)
