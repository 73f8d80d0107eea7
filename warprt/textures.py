"""Textures on the device: the pool of every texture a scene's materials name, their lookups, and
the surface coordinates (uv, or the point and normal in the shape's frame) they are looked up at.

The textures are **runtime data**: one array of ``TexRec`` rows and one array of linear RGB texels
per scene (or per batch), and each material row names its textures by index. A batch's worlds
switch textures by changing an index (``BatchRenderer.material_textures``); a new texture is a
new row and new texels, never a new kernel. The one kernel feature, ``Features.textures``, adds
the lookup code; a scene without textures compiles without it.

Bilinear filtering is warprt's own (four loads and three lerps in float32) rather than Warp's
``wp.Texture2D``: CUDA's texture units interpolate with 8-bit fixed-point weights (CUDA C
Programming Guide, "Linear Filtering"), which misses the float64 bilinear value by up to 1/512 of
the texel range, and the same kernel would then give different images on the CPU (software
filtering) and on CUDA; a pool indexed at run time also serves any number of textures through
one kernel argument. The module docstring of :mod:`warprt.scene.texture` gives the conventions.
"""

from __future__ import annotations

import math

import numpy as np
import warp as wp

from .geometry import abs3
from .records import KIND_BOX, KIND_MESH, KIND_RECT, KIND_SPHERE, TEX_BITMAP, TEX_CHECKER, \
    Features, MatRec, SceneData, TexRec, table
from .scene.texture import PROJECTIONS, WRAPS, Texture
from .trace import Hit, make_trace, to_object
from ._warp import build_once

PROJ_UV, PROJ_TRIPLANAR, PROJ_CUBIC = (PROJECTIONS.index(p) for p in ("uv", "triplanar", "cubic"))
WRAP_REPEAT, WRAP_CLAMP = (WRAPS.index(w) for w in ("repeat", "clamp"))
INV_2PI = 1.0 / (2.0 * math.pi)
INV_PI = 1.0 / math.pi


# --- host: the pool -----------------------------------------------------------------------


class TexturePool:
    """The textures of a scene (or a batch) as device tables: ``add`` gives a texture's row (a
    texture added twice, the same object, keeps its row); ``upload`` copies the rows and texels
    to the device."""

    def __init__(self):
        self.textures: list[Texture] = []
        self._rows: dict[int, int] = {}

    def add(self, tex: Texture | None) -> int:
        if tex is None:
            return -1
        if not isinstance(tex, Texture):
            raise TypeError(f"expected a warprt.Texture, got {type(tex).__name__}")
        row = self._rows.get(id(tex))
        if row is None:
            row = self._rows[id(tex)] = len(self.textures)
            self.textures.append(tex)
        return row

    def __len__(self) -> int:
        return len(self.textures)

    def upload(self, device) -> tuple["wp.array", "wp.array"]:
        """(texs, texels) on ``device``: one TexRec per texture, every bitmap's texels in one array."""
        rows, parts, off = [], [], 0
        for t in self.textures:
            c0, c1 = t.checker if t.checker is not None else ((0.0,) * 3, (0.0,) * 3)
            h, w = (0, 0) if t.texels is None else t.texels.shape[:2]
            rows.append(dict(kind=TEX_CHECKER if t.checker is not None else TEX_BITMAP, off=off, w=w, h=h,
                             wrap=WRAPS.index(t.wrap), proj=PROJECTIONS.index(t.projection), scale=t.scale,
                             sharp=t.sharpness, c0=c0, c1=c1))
            if t.texels is not None:
                parts.append(t.texels.reshape(-1, 3))
                off += w * h
        texels = np.concatenate(parts) if parts else np.zeros((1, 3), np.float32)
        return table(TexRec, rows, device), wp.array(texels, dtype=wp.vec3, device=device)


# --- device: lookups ------------------------------------------------------------------------


@wp.func
def texel_index(i: int, n: int, wrap: int) -> int:
    """Column or row i of n: wrapped around (repeat) or clamped to the edge."""
    if wrap == WRAP_REPEAT:
        r = i % n
        if r < 0:
            r += n
        return r
    return wp.clamp(i, 0, n - 1)


@wp.func
def bilinear(texels: wp.array(dtype=wp.vec3), t: TexRec, u_in: float, v_in: float) -> wp.vec3:
    """The bitmap at (u, v) (v up, (0, 0) the image's bottom-left corner), bilinear between the
    four texel centres around it."""
    u = u_in
    v = v_in
    if t.wrap == WRAP_REPEAT:
        u = u - wp.floor(u)
        v = v - wp.floor(v)
    else:
        u = wp.clamp(u, 0.0, 1.0)
        v = wp.clamp(v, 0.0, 1.0)
    x = u * float(t.w) - 0.5
    y = (1.0 - v) * float(t.h) - 0.5  # row 0 is the image's top
    xf = wp.floor(x)
    yf = wp.floor(y)
    fx = x - xf
    fy = y - yf
    i0 = texel_index(int(xf), t.w, t.wrap)
    i1 = texel_index(int(xf) + 1, t.w, t.wrap)
    j0 = texel_index(int(yf), t.h, t.wrap)
    j1 = texel_index(int(yf) + 1, t.h, t.wrap)
    top = texels[t.off + j0 * t.w + i0] * (1.0 - fx) + texels[t.off + j0 * t.w + i1] * fx
    bottom = texels[t.off + j1 * t.w + i0] * (1.0 - fx) + texels[t.off + j1 * t.w + i1] * fx
    return top * (1.0 - fy) + bottom * fy


@wp.func
def texture_2d(texels: wp.array(dtype=wp.vec3), t: TexRec, u_in: float, v_in: float) -> wp.vec3:
    """Texture t at the 2-D coordinates (u, v), before its scale."""
    u = u_in * t.scale
    v = v_in * t.scale
    if t.kind == TEX_CHECKER:
        s = wp.floor(u) + wp.floor(v)
        if s - 2.0 * wp.floor(0.5 * s) == 0.0:
            return t.c0
        return t.c1
    return bilinear(texels, t, u, v)


@wp.func
def texture_projected(texels: wp.array(dtype=wp.vec3), t: TexRec, x: wp.vec3, n: wp.vec3) -> wp.vec3:
    """Texture t projected along the axes onto the point x with normal n (both in the shape's
    frame): the x map reads (x_z, x_y), the y map (x_x, x_z), the z map (x_x, x_y); "cubic" takes
    the map of n's largest component, "triplanar" blends the three by |n_k|^sharpness."""
    a = abs3(n)
    if t.proj == PROJ_CUBIC:
        if a[0] >= a[1] and a[0] >= a[2]:
            return texture_2d(texels, t, x[2], x[1])
        if a[1] >= a[2]:
            return texture_2d(texels, t, x[0], x[2])
        return texture_2d(texels, t, x[0], x[1])
    wx = wp.pow(a[0], t.sharp)
    wy = wp.pow(a[1], t.sharp)
    wz = wp.pow(a[2], t.sharp)
    total = wx + wy + wz
    c = wp.vec3(0.0, 0.0, 0.0)
    if wx > 0.0:
        c += texture_2d(texels, t, x[2], x[1]) * wx
    if wy > 0.0:
        c += texture_2d(texels, t, x[0], x[2]) * wy
    if wz > 0.0:
        c += texture_2d(texels, t, x[0], x[1]) * wz
    if total > 0.0:
        return c / total
    return texture_2d(texels, t, x[0], x[1])


@wp.struct
class SurfacePoint:
    """Where a texture is looked up at a hit: the surface's uv, and the point and geometric normal
    in the shape's own frame (triplanar and cubic projections)."""

    uv: wp.vec2
    x: wp.vec3
    n: wp.vec3


@wp.func
def sphere_uv(d: wp.vec3) -> wp.vec2:
    """A sphere's uv at the unit direction d from its centre (longitude from +x towards -z, v = 1
    at the +y pole)."""
    u = wp.atan2(-d[2], d[0]) * INV_2PI
    if u < 0.0:
        u += 1.0
    return wp.vec2(u, 0.5 + wp.asin(wp.clamp(d[1], -1.0, 1.0)) * INV_PI)


@wp.func
def rect_uv(q: wp.vec3, e1: wp.vec3, e2: wp.vec3) -> wp.vec2:
    """(a, b) with q = a·e1 + b·e2 (q in the rectangle's plane, relative to its corner)."""
    e11 = wp.dot(e1, e1)
    e12 = wp.dot(e1, e2)
    e22 = wp.dot(e2, e2)
    q1 = wp.dot(q, e1)
    q2 = wp.dot(q, e2)
    det = e11 * e22 - e12 * e12
    return wp.vec2((q1 * e22 - q2 * e12) / det, (q2 * e11 - q1 * e12) / det)


@wp.func
def barycentric(p: wp.vec3, a: wp.vec3, b: wp.vec3, c: wp.vec3) -> wp.vec3:
    """The weights (wa, wb, wc) of p (in the triangle's plane) on the corners a, b, c."""
    ab = rect_uv(p - a, b - a, c - a)
    return wp.vec3(1.0 - ab[0] - ab[1], ab[0], ab[1])


@build_once
def make_textures(F: Features):
    """``surface_point`` and ``textured`` for the render kernel of feature set F."""
    trace = make_trace(F)
    sphere_center, instance_pose = trace.sphere_center, trace.instance_pose
    solid_pose, solid_rec = trace.solid_pose, trace.solid_rec

    @wp.func
    def surface_point(scene: SceneData, h: Hit, time: float) -> SurfacePoint:
        sp = SurfacePoint()
        sp.x = h.p
        sp.n = h.ng
        if h.kind == KIND_SPHERE:
            c = sphere_center(scene, h.index, time)
            sp.x = h.p - c
            sp.uv = sphere_uv(wp.normalize(sp.x))
        elif h.kind == KIND_RECT:
            rect = scene.rects[h.index]
            sp.uv = rect_uv(h.p - rect.c, rect.e1, rect.e2)
        if wp.static(F.meshes):
            if h.kind == KIND_MESH:
                inst = scene.insts[h.index]
                pose = instance_pose(scene, h.index, time)
                mesh = wp.mesh_get(inst.mesh)
                i0 = mesh.indices[h.face * 3 + 0]
                i1 = mesh.indices[h.face * 3 + 1]
                i2 = mesh.indices[h.face * 3 + 2]
                v0 = mesh.points[i0]
                v1 = mesh.points[i1]
                v2 = mesh.points[i2]
                sp.x = to_object(pose, h.p)
                sp.n = wp.normalize(wp.cross(v1 - v0, v2 - v0))
                if inst.uv_off >= 0:
                    w = barycentric(sp.x, v0, v1, v2)
                    sp.uv = (scene.uvs[inst.uv_off + i0] * w[0] + scene.uvs[inst.uv_off + i1] * w[1]
                             + scene.uvs[inst.uv_off + i2] * w[2])
        if wp.static(F.solids):
            if h.kind >= KIND_BOX:
                pose = solid_pose(solid_rec(scene, h.kind, h.index), time)
                sp.x = wp.quat_rotate_inv(pose.rot, h.p - pose.pos)
                sp.n = wp.quat_rotate_inv(pose.rot, h.ng)
        return sp

    @wp.func
    def texture_at(scene: SceneData, i: int, sp: SurfacePoint) -> wp.vec3:
        t = scene.texs[i]
        if t.proj == PROJ_UV:
            return texture_2d(scene.texels, t, sp.uv[0], sp.uv[1])
        return texture_projected(scene.texels, t, sp.x, sp.n)

    @wp.func
    def textured(scene: SceneData, h: Hit, time: float) -> MatRec:
        """Material h.mat at the hit: kd and ka times its texture, ks times its specular texture,
        km times its mirror texture (each where it has one)."""
        m = scene.mats[h.mat]
        if m.tex < 0 and m.tex_s < 0 and m.tex_m < 0:
            return m
        sp = surface_point(scene, h, time)
        if m.tex >= 0:
            c = texture_at(scene, m.tex, sp)
            m.kd = wp.cw_mul(m.kd, c)
            m.ka = wp.cw_mul(m.ka, c)
        if m.tex_s >= 0:
            m.ks = wp.cw_mul(m.ks, texture_at(scene, m.tex_s, sp))
        if m.tex_m >= 0:
            m.km = wp.cw_mul(m.km, texture_at(scene, m.tex_m, sp))
        return m

    return textured


__all__ = ["TexturePool", "make_textures", "bilinear", "texture_2d", "texture_projected"]
