"""The render megakernel, specialised per :class:`Features` value.

Per pixel sample (one thread owns one pixel and loops over its samples):

1. camera sample: film position, lens position and time from the sampler (dimensions 0, 1, 2);
2. the camera ray goes on a fixed-size per-thread stack (``STACK_SIZE`` entries of
   ``RayEntry``: origin, direction, throughput, depth, dimension key);
3. loop until the stack is empty: pop; nearest hit over every shape in [t_min, t_max); add
   throughput × (emission, or ambient + direct light from point and area lights with shadow rays);
   push the mirror / glossy reflection and the refraction (or, under total internal reflection,
   the extra reflection) with their weights, unless the depth limit or the throughput cutoff
   stops them.

A push onto a full stack drops that ray and counts it (``overflow`` per pixel), so overflow is
defined behaviour. With at most two children per hit, depth d needs at most d + 1 entries; the
stack holds 16, so scenes with ``max_depth`` <= 15 never overflow.

Code for features a scene does not use is removed at compile time with ``wp.static``; each
``Features`` value compiles one Warp module (``module="unique"``), cached on disk by Warp.
"""

from __future__ import annotations

import threading

import warp as wp

from . import _warp
from .build import (
    KIND_DISK, KIND_MESH, KIND_NONE, KIND_PLANE, KIND_RECT, KIND_SPHERE, LIGHT_RECT, LIGHT_SPHERE, CameraData,
    Features, RenderParams, SceneData,
)
from .geometry import (
    MISS, intersect_disk, intersect_plane, intersect_rect, intersect_sphere, max_abs, refine_on_plane,
    refine_on_sphere, spawn_offset, spawn_origin, sphere_roots,
)
from .sampling import frame_from_z, hash2, sample_2d, square_to_cone, square_to_cos_power, square_to_disk
from .shading import blinn_phong, fresnel, reflect, refract

_warp.init()

STACK_SIZE = 16
DIM_FILM, DIM_LENS, DIM_TIME = 0, 1, 2
ROOT_KEY = 0x51ED270B


@wp.struct
class Ray:
    o: wp.vec3
    d: wp.vec3


@wp.struct
class RayEntry:
    o: wp.vec3
    d: wp.vec3
    w: wp.vec3  # throughput
    depth: int
    key: wp.uint32  # dimension key of the path vertex this ray will find


@wp.struct
class Hit:
    t: float  # -1 for a miss
    kind: int  # KIND_* of the shape hit
    index: int  # index in that shape kind's table
    p: wp.vec3  # hit point refined onto the surface
    ng: wp.vec3  # unit geometric normal (not flipped)
    ns: wp.vec3  # unit shading normal (not flipped)
    mag: float  # magnitude bound of the coordinates p was computed from (for spawn offsets)
    mat: int


@wp.func
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
def luminance(c: wp.vec3) -> float:
    return 0.2126 * c[0] + 0.7152 * c[1] + 0.0722 * c[2]


@wp.func
def sanitize(c: wp.vec3, clamp: float) -> wp.vec3:
    """NaN -> 0, everything else clamped to [0, clamp] (overflow guard)."""
    out = wp.vec3(0.0, 0.0, 0.0)
    for k in range(3):
        x = c[k]
        if not wp.isnan(x):
            out[k] = wp.clamp(x, 0.0, clamp)
    return out


def _make_kernels(F: Features):
    """Build the device functions and the render kernel for one feature set."""

    @wp.func
    def instance_pose_pos(scene: SceneData, i: int, time: float) -> wp.vec3:
        p = scene.ins_pos0[i]
        if wp.static(F.motion):
            p = p + (scene.ins_pos1[i] - p) * time
        return p

    @wp.func
    def instance_pose_rot(scene: SceneData, i: int, time: float) -> wp.quat:
        q = scene.ins_rot0[i]
        if wp.static(F.motion):
            q = wp.quat_slerp(q, scene.ins_rot1[i], time)
        return q

    @wp.func
    def instance_pose_scl(scene: SceneData, i: int, time: float) -> wp.vec3:
        s = scene.ins_scl0[i]
        if wp.static(F.motion):
            s = s + (scene.ins_scl1[i] - s) * time
        return s

    @wp.func
    def sphere_center(scene: SceneData, i: int, time: float) -> wp.vec3:
        c = scene.sph_c0[i]
        if wp.static(F.motion):
            c = c + (scene.sph_c1[i] - c) * time
        return c

    @wp.func
    def closest_hit(scene: SceneData, o: wp.vec3, d: wp.vec3, t_min: float, t_max: float, time: float) -> Hit:
        best = float(t_max)
        kind = int(KIND_NONE)
        index = int(-1)
        face = int(-1)
        bu = float(0.0)
        bv = float(0.0)
        if scene.sph_bvh != wp.uint64(0):
            query = wp.bvh_query_ray(scene.sph_bvh, o, d)
            i = int(0)
            while wp.bvh_query_next(query, i, best):
                t = intersect_sphere(o, d, sphere_center(scene, i, time), scene.sph_r[i], t_min, best)
                if t >= 0.0:
                    best = t
                    kind = KIND_SPHERE
                    index = i
        else:
            for i in range(scene.n_spheres):
                t = intersect_sphere(o, d, sphere_center(scene, i, time), scene.sph_r[i], t_min, best)
                if t >= 0.0:
                    best = t
                    kind = KIND_SPHERE
                    index = i
        for i in range(scene.n_planes):
            t = intersect_plane(o, d, scene.pln_p[i], scene.pln_n[i], t_min, best)
            if t >= 0.0:
                best = t
                kind = KIND_PLANE
                index = i
        for i in range(scene.n_rects):
            t = intersect_rect(o, d, scene.rct_c[i], scene.rct_e1[i], scene.rct_e2[i], t_min, best)
            if t >= 0.0:
                best = t
                kind = KIND_RECT
                index = i
        for i in range(scene.n_disks):
            t = intersect_disk(o, d, scene.dsk_c[i], scene.dsk_n[i], scene.dsk_r[i], t_min, best)
            if t >= 0.0:
                best = t
                kind = KIND_DISK
                index = i
        if wp.static(F.meshes):
            start = o + d * t_min
            for i in range(scene.n_inst):
                pos = instance_pose_pos(scene, i, time)
                rot = instance_pose_rot(scene, i, time)
                scl = instance_pose_scl(scene, i, time)
                o_obj = wp.cw_div(wp.quat_rotate_inv(rot, start - pos), scl)
                d_obj = wp.cw_div(wp.quat_rotate_inv(rot, d), scl)
                q = wp.mesh_query_ray(scene.ins_mesh[i], o_obj, d_obj, best - t_min)
                if q.result:
                    if q.t + t_min < best:
                        best = q.t + t_min
                        kind = KIND_MESH
                        index = i
                        face = q.face
                        bu = q.u
                        bv = q.v

        h = Hit()
        h.t = -1.0
        h.kind = kind
        h.index = index
        if kind == KIND_NONE:
            return h
        h.t = best
        p = o + d * best
        if kind == KIND_SPHERE:
            c = sphere_center(scene, index, time)
            r = scene.sph_r[index]
            h.p = refine_on_sphere(p, c, r)
            h.ng = wp.normalize(h.p - c)
            h.ns = h.ng
            h.mag = max_abs(c) + r
            h.mat = scene.sph_mat[index]
        elif kind == KIND_PLANE:
            n = scene.pln_n[index]
            h.p = refine_on_plane(p, scene.pln_p[index], n)
            h.ng = n
            h.ns = n
            h.mag = wp.max(max_abs(h.p), max_abs(scene.pln_p[index]))
            h.mat = scene.pln_mat[index]
        elif kind == KIND_RECT:
            n = scene.rct_n[index]
            c = scene.rct_c[index]
            h.p = refine_on_plane(p, c, n)
            h.ng = n
            h.ns = n
            h.mag = max_abs(c) + max_abs(scene.rct_e1[index]) + max_abs(scene.rct_e2[index])
            h.mat = scene.rct_mat[index]
        elif kind == KIND_DISK:
            n = scene.dsk_n[index]
            c = scene.dsk_c[index]
            h.p = refine_on_plane(p, c, n)
            h.ng = n
            h.ns = n
            h.mag = max_abs(c) + scene.dsk_r[index]
            h.mat = scene.dsk_mat[index]
        if wp.static(F.meshes):
            if kind == KIND_MESH:
                mid = scene.ins_mesh[index]
                pos = instance_pose_pos(scene, index, time)
                rot = instance_pose_rot(scene, index, time)
                scl = instance_pose_scl(scene, index, time)
                p_obj = wp.mesh_eval_position(mid, face, bu, bv)
                h.p = wp.quat_rotate(rot, wp.cw_mul(p_obj, scl)) + pos
                n_obj = wp.mesh_eval_face_normal(mid, face)
                h.ng = wp.normalize(wp.quat_rotate(rot, wp.cw_div(n_obj, scl)))
                h.ns = h.ng
                if scene.ins_smooth[index] != 0:
                    mesh = wp.mesh_get(mid)
                    off = scene.ins_nrm_off[index]
                    n0 = scene.normals[off + mesh.indices[face * 3 + 0]]
                    n1 = scene.normals[off + mesh.indices[face * 3 + 1]]
                    n2 = scene.normals[off + mesh.indices[face * 3 + 2]]
                    ns_obj = bu * n0 + bv * n1 + (1.0 - bu - bv) * n2
                    ns_w = wp.quat_rotate(rot, wp.cw_div(ns_obj, scl))
                    if wp.length(ns_w) > 0.0:
                        h.ns = wp.normalize(ns_w)
                h.mag = max_abs(h.p) + max_abs(pos)
                h.mat = scene.ins_mat[index]
        return h

    @wp.func
    def crossing(scene: SceneData, mat: int) -> wp.vec3:
        """Light passing one surface of material ``mat`` in a shadow ray: kt, or 0 when opaque."""
        if wp.static(F.refraction):
            return scene.mat_kt[mat]
        return wp.vec3(0.0, 0.0, 0.0)

    @wp.func
    def sphere_crossings(scene: SceneData, o: wp.vec3, d: wp.vec3, t_max: float, time: float, i: int) -> wp.vec3:
        """Transmission through sphere i along (o, d) over (0, t_max): kt per surface crossed."""
        roots = sphere_roots(o, d, sphere_center(scene, i, time), scene.sph_r[i])
        T = wp.vec3(1.0, 1.0, 1.0)
        for k in range(2):
            if roots[k] > 0.0 and roots[k] < t_max:
                T = wp.cw_mul(T, crossing(scene, scene.sph_mat[i]))
        return T

    @wp.func
    def transmittance(scene: SceneData, o: wp.vec3, d: wp.vec3, t_max: float, time: float) -> wp.vec3:
        """Fraction of light arriving along the shadow ray (o, d) over (0, t_max): 0 when an
        opaque surface blocks it; transparent surfaces multiply it by their kt per crossing."""
        T = wp.vec3(1.0, 1.0, 1.0)
        if scene.sph_bvh != wp.uint64(0):
            query = wp.bvh_query_ray(scene.sph_bvh, o, d)
            i = int(0)
            while wp.bvh_query_next(query, i, t_max):
                T = wp.cw_mul(T, sphere_crossings(scene, o, d, t_max, time, i))
                if wp.max(T) <= 0.0:
                    return wp.vec3(0.0, 0.0, 0.0)
        else:
            for i in range(scene.n_spheres):
                T = wp.cw_mul(T, sphere_crossings(scene, o, d, t_max, time, i))
                if wp.max(T) <= 0.0:
                    return wp.vec3(0.0, 0.0, 0.0)
        for i in range(scene.n_planes):
            if intersect_plane(o, d, scene.pln_p[i], scene.pln_n[i], 0.0, t_max) >= 0.0:
                T = wp.cw_mul(T, crossing(scene, scene.pln_mat[i]))
                if wp.max(T) <= 0.0:
                    return wp.vec3(0.0, 0.0, 0.0)
        for i in range(scene.n_rects):
            if intersect_rect(o, d, scene.rct_c[i], scene.rct_e1[i], scene.rct_e2[i], 0.0, t_max) >= 0.0:
                T = wp.cw_mul(T, crossing(scene, scene.rct_mat[i]))
                if wp.max(T) <= 0.0:
                    return wp.vec3(0.0, 0.0, 0.0)
        for i in range(scene.n_disks):
            if intersect_disk(o, d, scene.dsk_c[i], scene.dsk_n[i], scene.dsk_r[i], 0.0, t_max) >= 0.0:
                T = wp.cw_mul(T, crossing(scene, scene.dsk_mat[i]))
                if wp.max(T) <= 0.0:
                    return wp.vec3(0.0, 0.0, 0.0)
        if wp.static(F.meshes):
            for i in range(scene.n_inst):
                pos = instance_pose_pos(scene, i, time)
                rot = instance_pose_rot(scene, i, time)
                scl = instance_pose_scl(scene, i, time)
                o_obj = wp.cw_div(wp.quat_rotate_inv(rot, o - pos), scl)
                d_obj = wp.cw_div(wp.quat_rotate_inv(rot, d), scl)
                kt = crossing(scene, scene.ins_mat[i])
                if wp.max(kt) <= 0.0:
                    if wp.mesh_query_ray_anyhit(scene.ins_mesh[i], o_obj, d_obj, t_max):
                        return wp.vec3(0.0, 0.0, 0.0)
                else:
                    # transparent mesh: walk its crossings one by one
                    t0 = float(0.0)
                    d_len = wp.length(d_obj)
                    for _k in range(64):
                        q = wp.mesh_query_ray(scene.ins_mesh[i], o_obj + d_obj * t0, d_obj, t_max - t0)
                        if not q.result:
                            break
                        T = wp.cw_mul(T, kt)
                        t0 = t0 + q.t
                        t0 = t0 + spawn_offset(max_abs(o_obj + d_obj * t0)) / d_len
                        if t0 >= t_max or wp.max(T) <= 0.0:
                            break
                if wp.max(T) <= 0.0:
                    return wp.vec3(0.0, 0.0, 0.0)
        return T

    @wp.func
    def direct_light(scene: SceneData, params: RenderParams, pixel: int, sample: int, key: wp.uint32,
                     h: Hit, ng: wp.vec3, n: wp.vec3, v: wp.vec3, time: float) -> wp.vec4:
        """Light reaching the viewer from the point lights and area lights (rgb, rays used in w).

        ``ng``/``n`` are the geometric/shading normals turned towards the viewer. Each area light
        sample acts as a point light of lecture intensity Le cosθ' dA / π, so the diffuse term is
        exactly (kd/π)·E for irradiance E.
        """
        kd = scene.mat_kd[h.mat]
        ks = scene.mat_ks[h.mat]
        p_exp = scene.mat_p[h.mat]
        origin = spawn_origin(h.p, ng, h.mag, 1.0)
        L = wp.vec3(0.0, 0.0, 0.0)
        rays = int(0)
        for i in range(scene.n_plights):
            to_light = scene.plt_pos[i] - origin
            dist = wp.length(to_light)
            if dist <= 0.0:
                continue
            l = to_light / dist
            if wp.dot(ng, l) <= 0.0:
                continue
            f = blinn_phong(n, l, v, kd, ks, p_exp)
            if wp.max(f) <= 0.0:
                continue
            rays += 1
            T = transmittance(scene, origin, l, dist - spawn_offset(max_abs(scene.plt_pos[i])), time)
            if wp.max(T) <= 0.0:
                continue
            I = scene.plt_int[i]
            if scene.plt_inv_sq[i] != 0:
                I = I / (dist * dist)
            L += wp.cw_mul(T, wp.cw_mul(I, f))
        if wp.static(F.area_lights):
            for j in range(scene.n_alights):
                kind = scene.alt_kind[j]
                idx = scene.alt_shape[j]
                ns = scene.alt_samples[j]
                le = scene.alt_le[j]
                acc = wp.vec3(0.0, 0.0, 0.0)
                dim = hash2(key, wp.uint32(16 + j))
                for k in range(ns):
                    u = sample_2d(params.sampler, params.seed, pixel, sample * ns + k, params.spp * ns, dim)
                    y = wp.vec3(0.0, 0.0, 0.0)
                    l = wp.vec3(0.0, 0.0, 0.0)
                    dist = float(0.0)
                    inv_pdf = float(0.0)  # 1 / (solid-angle density)
                    y_mag = float(0.0)
                    if kind == LIGHT_SPHERE:
                        c = scene.sph_c0[idx]
                        r = scene.sph_r[idx]
                        to_c = c - origin
                        dc = wp.length(to_c)
                        if dc <= r or r <= 0.0:
                            continue
                        s = r / dc
                        omc = s * s / (1.0 + wp.sqrt(wp.max(0.0, 1.0 - s * s)))  # 1 - cos θmax
                        l = frame_from_z(to_c / dc, square_to_cone(u, omc))
                        t = intersect_sphere(origin, l, c, r, 0.0, 3.0e38)
                        if t < 0.0:
                            t = wp.dot(to_c, l)  # grazing the silhouette: use the tangent point
                        dist = t
                        inv_pdf = 2.0 * wp.pi * omc
                        y_mag = max_abs(c) + r
                    else:
                        ln = wp.vec3(0.0, 0.0, 0.0)
                        area = float(0.0)
                        if kind == LIGHT_RECT:
                            e1 = scene.rct_e1[idx]
                            e2 = scene.rct_e2[idx]
                            y = scene.rct_c[idx] + u[0] * e1 + u[1] * e2
                            ln = scene.rct_n[idx]
                            area = wp.length(wp.cross(e1, e2))
                            y_mag = max_abs(scene.rct_c[idx]) + max_abs(e1) + max_abs(e2)
                        else:
                            ln = scene.dsk_n[idx]
                            r = scene.dsk_r[idx]
                            dsk = square_to_disk(u) * r
                            y = scene.dsk_c[idx] + frame_from_z(ln, wp.vec3(dsk[0], dsk[1], 0.0))
                            area = wp.pi * r * r
                            y_mag = max_abs(scene.dsk_c[idx]) + r
                        to_y = y - origin
                        dist = wp.length(to_y)
                        if dist <= 0.0 or area <= 0.0:
                            continue
                        l = to_y / dist
                        cos_l = -wp.dot(ln, l)
                        if cos_l <= 0.0:
                            continue  # the back of a one-sided emitter
                        inv_pdf = area * cos_l / (dist * dist)
                    if wp.dot(ng, l) <= 0.0:
                        continue
                    f = blinn_phong(n, l, v, kd, ks, p_exp)
                    if wp.max(f) <= 0.0:
                        continue
                    rays += 1
                    T = transmittance(scene, origin, l, dist - 2.0 * spawn_offset(y_mag), time)
                    if wp.max(T) <= 0.0:
                        continue
                    acc += wp.cw_mul(T, f) * (inv_pdf / wp.pi)
                L += wp.cw_mul(le, acc) / float(ns)
        return wp.vec4(L[0], L[1], L[2], float(rays))

    @wp.func
    def lobe(u: wp.vec2, axis: wp.vec3, exponent: float) -> wp.vec3:
        return frame_from_z(axis, square_to_cos_power(u, exponent))

    @wp.kernel(module="unique", enable_backward=False)
    def render_kernel(scene: SceneData, cam: CameraData, params: RenderParams,
                      x0: int, y0: int, tile_w: int, tile_h: int, s0: int, s1: int,
                      accum: wp.array(dtype=wp.vec3), accum_sq: wp.array(dtype=float),
                      ray_count: wp.array(dtype=int), overflow: wp.array(dtype=int)):
        tid = wp.tid()
        px = x0 + tid % tile_w
        py = y0 + tid / tile_w
        if px >= cam.width or py >= cam.height:
            return
        pixel = py * cam.width + px
        acc = accum[pixel]
        acc_sq = accum_sq[pixel]
        rays = int(0)
        dropped = int(0)
        stack = wp.zeros(shape=STACK_SIZE, dtype=RayEntry)
        for s in range(s0, s1):
            # --- camera sample: film, lens, time
            uf = sample_2d(params.sampler, params.seed, pixel, s, params.spp, wp.uint32(DIM_FILM))
            time = cam.t_open
            if wp.static(F.motion):
                ut = sample_2d(params.sampler, params.seed, pixel, s, params.spp, wp.uint32(DIM_TIME))
                time = cam.t_open + (cam.t_close - cam.t_open) * ut[0]
            ul = wp.vec2(0.5, 0.5)
            if wp.static(F.lens):
                ul = sample_2d(params.sampler, params.seed, pixel, s, params.spp, wp.uint32(DIM_LENS))
            ray = camera_ray(cam, float(px) + uf[0], float(py) + uf[1], ul, time)

            L = wp.vec3(0.0, 0.0, 0.0)
            first = RayEntry()
            first.o = ray.o
            first.d = ray.d
            first.w = wp.vec3(1.0, 1.0, 1.0)
            first.depth = 0
            first.key = wp.uint32(ROOT_KEY)
            stack[0] = first
            sp = int(1)
            while sp > 0:
                sp -= 1
                e = stack[sp]
                rays += 1
                t_lo = float(0.0)
                t_hi = float(3.0e38)
                if e.depth == 0:
                    t_lo = params.t_min
                    t_hi = params.t_max
                h = closest_hit(scene, e.o, e.d, t_lo, t_hi, time)
                if h.kind == KIND_NONE:
                    L += wp.cw_mul(e.w, scene.background)
                    continue
                front = wp.dot(e.d, h.ng) < 0.0
                ng = h.ng
                n = h.ns
                if not front:
                    ng = -ng
                    n = -n
                if wp.dot(n, e.d) > 0.0:
                    n = ng  # a shading normal facing away from the viewer: fall back
                le = scene.mat_emit[h.mat]
                if wp.max(le) > 0.0:
                    if front:
                        L += wp.cw_mul(e.w, le)
                    continue
                v = -e.d
                local = wp.cw_mul(scene.mat_ka[h.mat], scene.ambient)
                dl = direct_light(scene, params, pixel, s, e.key, h, ng, n, v, time)
                rays += int(dl[3])
                local += wp.vec3(dl[0], dl[1], dl[2])
                L += wp.cw_mul(e.w, local)

                if wp.static(F.secondary):
                    if e.depth < params.max_depth:
                        w_refl = scene.mat_km[h.mat]
                        if wp.static(F.refraction):
                            kt = scene.mat_kt[h.mat]
                            if wp.max(kt) > 0.0:
                                ior = scene.mat_ior[h.mat]
                                eta_i = float(1.0)
                                eta_t = float(ior)
                                if not front:
                                    eta_i = ior
                                    eta_t = 1.0
                                tdir = refract(e.d, n, eta_i / eta_t)
                                if wp.length(tdir) == 0.0:
                                    w_refl = w_refl + kt  # total internal reflection
                                else:
                                    w_refr = kt
                                    mode = scene.mat_fresnel[h.mat]
                                    if mode > 0:
                                        fr = fresnel(mode, -wp.dot(e.d, n), eta_i, eta_t)
                                        w_refl = w_refl + kt * fr
                                        w_refr = kt * (1.0 - fr)
                                    if wp.static(F.glossy):
                                        frost = scene.mat_frost[h.mat]
                                        if frost > 0.0:
                                            ug = sample_2d(params.sampler, params.seed, pixel, s, params.spp,
                                                           hash2(e.key, wp.uint32(2)))
                                            tdir = lobe(ug, tdir, frost)
                                    tw = wp.cw_mul(e.w, w_refr)
                                    if wp.dot(tdir, ng) < 0.0 and wp.max(tw) > params.min_weight:
                                        if sp < STACK_SIZE:
                                            child = RayEntry()
                                            child.o = spawn_origin(h.p, ng, h.mag, -1.0)
                                            child.d = tdir
                                            child.w = tw
                                            child.depth = e.depth + 1
                                            child.key = hash2(e.key, wp.uint32(101))
                                            stack[sp] = child
                                            sp += 1
                                        else:
                                            dropped += 1
                        rw = wp.cw_mul(e.w, w_refl)
                        if wp.max(rw) > params.min_weight:
                            r = reflect(e.d, n)
                            if wp.static(F.glossy):
                                gloss = scene.mat_gloss[h.mat]
                                if gloss > 0.0:
                                    ug = sample_2d(params.sampler, params.seed, pixel, s, params.spp,
                                                   hash2(e.key, wp.uint32(1)))
                                    r = lobe(ug, r, gloss)
                            if wp.dot(r, ng) > 0.0:
                                if sp < STACK_SIZE:
                                    child = RayEntry()
                                    child.o = spawn_origin(h.p, ng, h.mag, 1.0)
                                    child.d = r
                                    child.w = rw
                                    child.depth = e.depth + 1
                                    child.key = hash2(e.key, wp.uint32(102))
                                    stack[sp] = child
                                    sp += 1
                                else:
                                    dropped += 1
            L = sanitize(L, params.clamp)
            acc = acc + L
            y = luminance(L)
            acc_sq = acc_sq + y * y
        accum[pixel] = acc
        accum_sq[pixel] = acc_sq
        ray_count[pixel] = ray_count[pixel] + rays
        overflow[pixel] = overflow[pixel] + dropped

    return render_kernel, closest_hit


_cache: dict[Features, object] = {}
_cache_lock = threading.Lock()


def kernels_for(features: Features):
    """(render kernel, closest_hit func) for a feature set, built once per process."""
    with _cache_lock:
        if features not in _cache:
            _cache[features] = _make_kernels(features)
        return _cache[features]
