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

Inlining: Warp passes structs to functions by value, and ``SceneData`` (eleven arrays) is about
700 bytes. The hot functions (``closest_hit``, ``transmittance``, ``shadow``, ``direct_light``
and the small helpers they call) are force-inlined (``@wp.func(inline=True)``): left to the C++
compiler, a kernel with the mesh, area-light and secondary-ray code grew past its inlining
budget, ``closest_hit`` became a real call that copied the scene for every ray, and the
all-features kernel ran a plain scene 1.55x slower than the ``basic`` one (1.06-1.09x with the
hints; the showcase, which uses every feature, 14% faster; about 1.5 s more cold compile for
the full kernel). The mesh helpers stay compiler-decided: marking them ``inline=False`` made
mesh-heavy scenes slower (the copy per call again).
"""

from __future__ import annotations

import threading
from types import SimpleNamespace

import warp as wp

from .build import (
    KIND_DISK, KIND_MESH, KIND_NONE, KIND_PLANE, KIND_RECT, KIND_SPHERE, LIGHT_RECT, LIGHT_SPHERE, CameraData,
    Features, RenderParams, SceneData,
)
from .geometry import (
    MISS, SPAWN_REL, abs3, disk_extent, intersect_disk, intersect_plane, intersect_rect, intersect_sphere, max_abs,
    quat_rotate_mag, refine_on_plane, refine_on_sphere, spawn_offset, spawn_origin, sphere_roots,
)
from .sampling import frame_from_z, hash2, sample_1d, sample_2d, square_to_cone, square_to_cos_power, square_to_disk
from .shading import blinn_phong, fresnel, reflect, refract


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
    mag: wp.vec3  # per-component magnitude bound of the coordinates p was computed from (spawn offsets)
    mat: int


@wp.struct
class MeshHit:
    t: float
    index: int  # instance, -1 for none
    face: int
    u: float
    v: float


@wp.func(inline=True)
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


@wp.func(inline=True)
def sanitize(c: wp.vec3, clamp: float) -> wp.vec3:
    """NaN -> 0, everything else clamped to [0, clamp] (overflow guard)."""
    out = wp.vec3(0.0, 0.0, 0.0)
    for k in range(3):
        x = c[k]
        if not wp.isnan(x):
            out[k] = wp.clamp(x, 0.0, clamp)
    return out


FLT_MAX = 3.4028234663852886e38  # the largest float32
TIE = SPAWN_REL  # relative band within which an analytic hit beats a mesh hit: the spawn-offset factor 2^-17


@wp.func(inline=True)
def mul_sat(a: wp.vec3, b: wp.vec3) -> wp.vec3:
    """a·b per component for non-negative colours, never NaN or Inf: a zero (or NaN) factor gives
    0 even against Inf, and a product beyond the float32 range saturates at FLT_MAX. An
    overflowing light term times a zero weight (a coloured mirror, a coloured glass's
    transmittance) is then 0, not a NaN that ``sanitize`` would turn into the loss of every
    other contribution to that channel of the sample. Bit-identical to ``cw_mul`` otherwise."""
    out = wp.vec3(0.0, 0.0, 0.0)
    for k in range(3):
        if a[k] > 0.0 and b[k] > 0.0:
            out[k] = wp.min(a[k] * b[k], FLT_MAX)
    return out


@wp.func
def leaves_face(mid: wp.uint64, face: int, o: wp.vec3, d: wp.vec3) -> bool:
    """True when the ray (o, d) (object space) cannot meet the plane of triangle ``face`` at t > 0:
    it starts on that plane, or on the side it moves away from. Warp's triangle test works in
    coordinates relative to the ray origin and is not sign-exact for an origin within its
    rounding (ulps of the triangle's coordinates) of the plane: a ray leaving a triangle 800 units
    wide can "hit" it again at t ~ 1e-4. The plane test here is exact for axis-aligned triangles
    and otherwise errs far less than the spawn offset."""
    mesh = wp.mesh_get(mid)
    v0 = mesh.points[mesh.indices[face * 3]]
    n = wp.mesh_eval_face_normal(mid, face)
    return wp.dot(n, o - v0) * wp.dot(n, d) >= 0.0


@wp.func
def mesh_first_hit(mid: wp.uint64, o: wp.vec3, d: wp.vec3, t_max: float) -> MeshHit:
    """Nearest hit of mesh ``mid`` along (o, d) (object space) in (0, t_max) on a triangle the ray
    really approaches (see ``leaves_face``); ``index`` 0 for a hit, -1 for none. A rejected hit
    (or one exactly at the origin) is stepped over by its rounding and the query repeated."""
    r = MeshHit()
    r.index = -1
    t0 = float(0.0)
    for _k in range(4):
        q = wp.mesh_query_ray(mid, o + d * t0, d, t_max - t0)
        if not q.result:
            return r
        if q.t > 0.0 and not leaves_face(mid, q.face, o, d):
            r.index = 0
            r.t = t0 + q.t
            r.face = q.face
            r.u = q.u
            r.v = q.v
            return r
        mesh = wp.mesh_get(mid)
        v0 = mesh.points[mesh.indices[q.face * 3]]
        t0 = t0 + wp.max(q.t, 0.0) + spawn_offset(max_abs(o) + max_abs(v0)) / wp.length(d)
        if t0 >= t_max:
            return r
    return r


def _make_kernels(F: Features):
    """Build the device functions and the render kernel for one feature set."""

    @wp.func
    def instance_pose_pos(scene: SceneData, i: int, time: float) -> wp.vec3:
        p = scene.insts[i].pos0
        if wp.static(F.motion):
            p = p + (scene.insts[i].pos1 - p) * time
        return p

    @wp.func
    def instance_pose_rot(scene: SceneData, i: int, time: float) -> wp.quat:
        q = scene.insts[i].rot0
        if wp.static(F.motion):
            q = wp.quat_slerp(q, scene.insts[i].rot1, time)
        return q

    @wp.func
    def instance_pose_scl(scene: SceneData, i: int, time: float) -> wp.vec3:
        s = scene.insts[i].scl0
        if wp.static(F.motion):
            s = s + (scene.insts[i].scl1 - s) * time
        return s

    @wp.func(inline=True)
    def sphere_center(scene: SceneData, i: int, time: float) -> wp.vec3:
        c = scene.spheres[i].c0
        if wp.static(F.motion):
            c = c + (scene.spheres[i].c1 - c) * time
        return c

    @wp.func
    def mesh_nearest(scene: SceneData, o: wp.vec3, d: wp.vec3, t_min: float, t_max: float, time: float) -> MeshHit:
        """Nearest triangle hit over all mesh instances in (t_min, t_max); index -1 for none."""
        best = float(t_max)
        r = MeshHit()
        r.index = -1
        start = o + d * t_min
        for i in range(scene.n_inst):
            pos = instance_pose_pos(scene, i, time)
            rot = instance_pose_rot(scene, i, time)
            scl = instance_pose_scl(scene, i, time)
            o_obj = wp.cw_div(wp.quat_rotate_inv(rot, start - pos), scl)
            d_obj = wp.cw_div(wp.quat_rotate_inv(rot, d), scl)
            # (a hit exactly at t_min is outside the open range (t_min, t_max): mesh_first_hit
            # looks beyond it, as it does past a ray's own surface)
            q = mesh_first_hit(scene.insts[i].mesh, o_obj, d_obj, best - t_min)
            if q.index >= 0:
                if q.t + t_min < best:
                    best = q.t + t_min
                    r.t = best
                    r.index = i
                    r.face = q.face
                    r.u = q.u
                    r.v = q.v
        return r

    @wp.func
    def mesh_details(scene: SceneData, h_in: Hit, o: wp.vec3, d: wp.vec3, face: int, bu: float, bv: float,
                     time: float) -> Hit:
        """h_in with the point, normals and material of its mesh hit filled in.

        The point is taken, in object space, from the barycentrics or from the ray's crossing of
        the triangle's plane, whichever was computed from smaller coordinates (the barycentric
        point of a triangle 1e4 wide is off by ~1e-3 along the surface; the ray point seen from a
        far camera likewise), and then projected onto that plane."""
        h = h_in
        index = h.index
        mid = scene.insts[index].mesh
        pos = instance_pose_pos(scene, index, time)
        rot = instance_pose_rot(scene, index, time)
        scl = instance_pose_scl(scene, index, time)
        mesh = wp.mesh_get(mid)
        v0 = mesh.points[mesh.indices[face * 3 + 0]]
        v1 = mesh.points[mesh.indices[face * 3 + 1]]
        v2 = mesh.points[mesh.indices[face * 3 + 2]]
        tri_mag = wp.max(abs3(v0), wp.max(abs3(v1), abs3(v2)))
        n_obj = wp.mesh_eval_face_normal(mid, face)
        p_obj = wp.mesh_eval_position(mid, face, bu, bv)
        if max_abs(o) + h.t < max_abs(wp.cw_mul(tri_mag, scl)) + max_abs(pos):
            # the ray met the triangle's plane (in object space, like intersect_plane: exact for
            # an axis-aligned triangle) where Warp's t says, give or take its rounding
            o_obj = wp.cw_div(wp.quat_rotate_inv(rot, o - pos), scl)
            d_obj = wp.cw_div(wp.quat_rotate_inv(rot, d), scl)
            # (Warp's own t is off by up to ~0.3% on a triangle 1e4 times wider than the ray
            # length; the plane's t is used unless the ray grazes the plane)
            denom = wp.dot(n_obj, d_obj)
            if wp.abs(denom) > 1.0e-2 * wp.length(d_obj):
                t_plane = wp.dot(n_obj, v0 - o_obj) / denom
                if wp.abs(t_plane - h.t) <= 1.0e-2 * h.t:
                    p_obj = o_obj + d_obj * t_plane
                    h.t = t_plane
        p_obj = refine_on_plane(p_obj, v0, n_obj)
        h.p = wp.quat_rotate(rot, wp.cw_mul(p_obj, scl)) + pos
        # error bound: the triangle's coordinates (its plane), carried through scale and rotation,
        # plus the translation and the point itself (the rounding of the transform and of the
        # next ray's way back into object space)
        m_obj = wp.cw_mul(wp.max(tri_mag, abs3(p_obj)), abs3(scl))
        h.mag = quat_rotate_mag(rot, m_obj) + abs3(pos) + abs3(h.p)
        h.ng = wp.normalize(wp.quat_rotate(rot, wp.cw_div(n_obj, scl)))
        h.ns = h.ng
        if scene.insts[index].smooth != 0:
            off = scene.insts[index].nrm_off
            n0 = scene.normals[off + mesh.indices[face * 3 + 0]]
            n1 = scene.normals[off + mesh.indices[face * 3 + 1]]
            n2 = scene.normals[off + mesh.indices[face * 3 + 2]]
            ns_obj = bu * n0 + bv * n1 + (1.0 - bu - bv) * n2
            ns_w = wp.quat_rotate(rot, wp.cw_div(ns_obj, scl))
            if wp.length(ns_w) > 0.0:
                h.ns = wp.normalize(ns_w)
        h.mat = scene.insts[index].mat
        return h

    @wp.func(inline=True)
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
                t = intersect_sphere(o, d, sphere_center(scene, i, time), scene.spheres[i].r, t_min, best)
                if t >= 0.0:
                    best = t
                    kind = KIND_SPHERE
                    index = i
        else:
            for i in range(scene.n_spheres):
                t = intersect_sphere(o, d, sphere_center(scene, i, time), scene.spheres[i].r, t_min, best)
                if t >= 0.0:
                    best = t
                    kind = KIND_SPHERE
                    index = i
        for i in range(scene.n_planes):
            t = intersect_plane(o, d, scene.planes[i].p, scene.planes[i].n, t_min, best)
            if t >= 0.0:
                best = t
                kind = KIND_PLANE
                index = i
        for i in range(scene.n_rects):
            t = intersect_rect(o, d, scene.rects[i].c, scene.rects[i].e1, scene.rects[i].e2, t_min, best)
            if t >= 0.0:
                best = t
                kind = KIND_RECT
                index = i
        for i in range(scene.n_disks):
            t = intersect_disk(o, d, scene.disks[i].c, scene.disks[i].n, scene.disks[i].r, t_min, best)
            if t >= 0.0:
                best = t
                kind = KIND_DISK
                index = i
        if wp.static(F.meshes):
            if scene.n_inst > 0:
                # ties: a mesh must be nearer than an analytic hit by TIE relative to replace it.
                # Warp's triangle t and an analytic t for the same surface differ by ~9 ulps
                # either way; without the band a mesh on a plane z-fights in a noisy pattern
                mesh_t_max = best
                if kind != KIND_NONE:
                    mesh_t_max = best * (1.0 - TIE)
                m = mesh_nearest(scene, o, d, t_min, mesh_t_max, time)
                if m.index >= 0:
                    best = m.t
                    kind = KIND_MESH
                    index = m.index
                    face = m.face
                    bu = m.u
                    bv = m.v

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
            r = scene.spheres[index].r
            h.p = refine_on_sphere(p, c, r)
            h.ng = wp.normalize(h.p - c)
            h.ns = h.ng
            h.mag = abs3(c) + abs3(h.ng) * r  # the centre, and the radius along each axis
            h.mat = scene.spheres[index].mat
        elif kind == KIND_PLANE:
            n = scene.planes[index].n
            h.p = refine_on_plane(p, scene.planes[index].p, n)
            h.ng = n
            h.ns = n
            h.mag = wp.max(abs3(h.p), abs3(scene.planes[index].p))
            h.mat = scene.planes[index].mat
        elif kind == KIND_RECT:
            n = scene.rects[index].n
            c = scene.rects[index].c
            h.p = refine_on_plane(p, c, n)
            h.ng = n
            h.ns = n
            h.mag = abs3(c) + abs3(scene.rects[index].e1) + abs3(scene.rects[index].e2)
            h.mat = scene.rects[index].mat
        elif kind == KIND_DISK:
            n = scene.disks[index].n
            c = scene.disks[index].c
            h.p = refine_on_plane(p, c, n)
            h.ng = n
            h.ns = n
            h.mag = abs3(c) + disk_extent(n, scene.disks[index].r)
            h.mat = scene.disks[index].mat
        if wp.static(F.meshes):
            if kind == KIND_MESH:
                h = mesh_details(scene, h, o, d, face, bu, bv, time)
        return h

    @wp.func(inline=True)
    def crossing(scene: SceneData, mat: int) -> wp.vec3:
        """Light passing one surface of material ``mat`` in a shadow ray: kt, or 0 when opaque."""
        if wp.static(F.refraction):
            return scene.mats[mat].kt
        return wp.vec3(0.0, 0.0, 0.0)

    @wp.func(inline=True)
    def sphere_crossings(scene: SceneData, o: wp.vec3, d: wp.vec3, t_max: float, time: float, i: int) -> wp.vec3:
        """Transmission through sphere i along (o, d) over (0, t_max): kt per surface crossed."""
        roots = sphere_roots(o, d, sphere_center(scene, i, time), scene.spheres[i].r)
        T = wp.vec3(1.0, 1.0, 1.0)
        for k in range(2):
            if roots[k] > 0.0 and roots[k] < t_max:
                T = wp.cw_mul(T, crossing(scene, scene.spheres[i].mat))
        return T

    @wp.func
    def mesh_transmittance(scene: SceneData, o: wp.vec3, d: wp.vec3, t_max: float, time: float) -> wp.vec3:
        T = wp.vec3(1.0, 1.0, 1.0)
        for i in range(scene.n_inst):
            pos = instance_pose_pos(scene, i, time)
            rot = instance_pose_rot(scene, i, time)
            scl = instance_pose_scl(scene, i, time)
            o_obj = wp.cw_div(wp.quat_rotate_inv(rot, o - pos), scl)
            d_obj = wp.cw_div(wp.quat_rotate_inv(rot, d), scl)
            kt = crossing(scene, scene.insts[i].mat)
            if wp.max(kt) <= 0.0:
                if wp.mesh_query_ray_anyhit(scene.insts[i].mesh, o_obj, d_obj, t_max):
                    # any hit at all: make sure it is not the surface the ray leaves
                    if mesh_first_hit(scene.insts[i].mesh, o_obj, d_obj, t_max).index >= 0:
                        return wp.vec3(0.0, 0.0, 0.0)
            else:
                # transparent mesh: walk its crossings one by one. Each crossing is rebuilt on its
                # triangle from the barycentrics (error: ulps of the mesh coordinates, not of the
                # ray's length) and the walk goes on from just past it; o + d·t from a far origin
                # is off by more than the step and found the same crossing again (kt², kt³...)
                t0 = float(0.0)  # ray parameter of o_cur
                d_len = wp.length(d_obj)
                o_cur = o_obj
                for _k in range(64):
                    q = mesh_first_hit(scene.insts[i].mesh, o_cur, d_obj, t_max - t0)
                    if q.index < 0:
                        break
                    T = wp.cw_mul(T, kt)
                    p_s = wp.mesh_eval_position(scene.insts[i].mesh, q.face, q.u, q.v)
                    step = spawn_offset(max_abs(p_s)) / d_len
                    t0 = t0 + q.t + step
                    o_cur = p_s + d_obj * step
                    if t0 >= t_max or wp.max(T) <= 0.0:
                        break
            if wp.max(T) <= 0.0:
                return wp.vec3(0.0, 0.0, 0.0)
        return T

    @wp.func(inline=True)
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
            if intersect_plane(o, d, scene.planes[i].p, scene.planes[i].n, 0.0, t_max) >= 0.0:
                T = wp.cw_mul(T, crossing(scene, scene.planes[i].mat))
                if wp.max(T) <= 0.0:
                    return wp.vec3(0.0, 0.0, 0.0)
        for i in range(scene.n_rects):
            if intersect_rect(o, d, scene.rects[i].c, scene.rects[i].e1, scene.rects[i].e2, 0.0, t_max) >= 0.0:
                T = wp.cw_mul(T, crossing(scene, scene.rects[i].mat))
                if wp.max(T) <= 0.0:
                    return wp.vec3(0.0, 0.0, 0.0)
        for i in range(scene.n_disks):
            if intersect_disk(o, d, scene.disks[i].c, scene.disks[i].n, scene.disks[i].r, 0.0, t_max) >= 0.0:
                T = wp.cw_mul(T, crossing(scene, scene.disks[i].mat))
                if wp.max(T) <= 0.0:
                    return wp.vec3(0.0, 0.0, 0.0)
        if wp.static(F.meshes):
            if scene.n_inst > 0:
                T = wp.cw_mul(T, mesh_transmittance(scene, o, d, t_max, time))
        return T

    @wp.func(inline=True)
    def shadow(scene: SceneData, origin: wp.vec3, target: wp.vec3, stop_short: float, time: float) -> wp.vec3:
        """Transmittance from ``origin`` to ``target``, ending ``stop_short`` before the target
        (so the light's own surface never occludes it)."""
        to_t = target - origin
        dist = wp.length(to_t)
        if dist <= stop_short:
            return wp.vec3(1.0, 1.0, 1.0)
        return transmittance(scene, origin, to_t / dist, dist - stop_short, time)

    @wp.func
    def area_lights_direct(scene: SceneData, params: RenderParams, pixel: int, sample: int, key: wp.uint32,
                           p: wp.vec3, origin: wp.vec3, ng: wp.vec3, n: wp.vec3, v: wp.vec3, kd: wp.vec3, ks: wp.vec3,
                           p_exp: float, time: float) -> wp.vec4:
        """Direct light from the area lights: ``samples`` stratified shadow rays per light (rgb, rays in w).
        Directions, distances and densities are taken from the surface point p; the shadow rays
        start from ``origin``, p moved off the surface."""
        L = wp.vec3(0.0, 0.0, 0.0)
        rays = int(0)
        for j in range(scene.n_alights):
            kind = scene.alights[j].kind
            idx = scene.alights[j].shape
            ns = scene.alights[j].samples
            le = scene.alights[j].le
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
                    c = scene.spheres[idx].c0
                    r = scene.spheres[idx].r
                    to_c = c - p
                    dc = wp.length(to_c)
                    if dc <= r or r <= 0.0:
                        continue
                    s = r / dc
                    omc = s * s / (1.0 + wp.sqrt(wp.max(0.0, 1.0 - s * s)))  # 1 - cos θmax
                    l = frame_from_z(to_c / dc, square_to_cone(u, omc))
                    t = intersect_sphere(p, l, c, r, 0.0, 3.0e38)
                    if t < 0.0:
                        t = wp.dot(to_c, l)  # grazing the silhouette: use the tangent point
                    dist = t
                    y = p + l * t
                    inv_pdf = 2.0 * wp.pi * omc
                    y_mag = max_abs(c) + r
                else:
                    ln = wp.vec3(0.0, 0.0, 0.0)
                    area = float(0.0)
                    if kind == LIGHT_RECT:
                        e1 = scene.rects[idx].e1
                        e2 = scene.rects[idx].e2
                        y = scene.rects[idx].c + u[0] * e1 + u[1] * e2
                        ln = scene.rects[idx].n
                        area = wp.length(wp.cross(e1, e2))
                        y_mag = max_abs(scene.rects[idx].c) + max_abs(e1) + max_abs(e2)
                    else:
                        ln = scene.disks[idx].n
                        r = scene.disks[idx].r
                        dsk = square_to_disk(u) * r
                        y = scene.disks[idx].c + frame_from_z(ln, wp.vec3(dsk[0], dsk[1], 0.0))
                        area = wp.pi * r * r
                        y_mag = max_abs(scene.disks[idx].c) + r
                    to_y = y - p
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
                T = shadow(scene, origin, y, 2.0 * spawn_offset(y_mag), time)
                if wp.max(T) <= 0.0:
                    continue
                acc += mul_sat(mul_sat(T, f), wp.vec3(inv_pdf / wp.pi))
            L += mul_sat(le, acc) / float(ns)
        return wp.vec4(L[0], L[1], L[2], float(rays))

    @wp.func(inline=True)
    def direct_light(scene: SceneData, h: Hit, ng: wp.vec3, n: wp.vec3, v: wp.vec3, time: float) -> wp.vec4:
        """Light reaching the viewer from the point lights (rgb, shadow rays used in w); the area
        lights are summed by ``area_lights_direct``, where each light sample acts as a point light
        of lecture intensity Le cosθ' dA / π, so the diffuse term is exactly (kd/π)·E for
        irradiance E.

        ``ng``/``n`` are the geometric/shading normals turned towards the viewer.
        """
        kd = scene.mats[h.mat].kd
        ks = scene.mats[h.mat].ks
        p_exp = scene.mats[h.mat].p
        origin = spawn_origin(h.p, ng, h.mag, 1.0)
        L = wp.vec3(0.0, 0.0, 0.0)
        rays = int(0)
        for i in range(scene.n_plights):
            to_light = scene.plights[i].pos - h.p  # shading uses the surface point itself
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
            T = shadow(scene, origin, scene.plights[i].pos, spawn_offset(max_abs(scene.plights[i].pos)), time)
            if wp.max(T) <= 0.0:
                continue
            I = scene.plights[i].intensity
            if scene.plights[i].inv_sq != 0:
                I = I / (dist * dist)
            L += mul_sat(T, mul_sat(I, f))
        return wp.vec4(L[0], L[1], L[2], float(rays))

    @wp.func(inline=True)
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
                if params.moving != 0 and cam.t_close > cam.t_open:
                    ut = sample_1d(params.sampler, params.seed, pixel, s, params.spp, wp.uint32(DIM_TIME))
                    time = cam.t_open + (cam.t_close - cam.t_open) * ut
            ul = wp.vec2(0.5, 0.5)
            if wp.static(F.lens):
                if cam.lens_radius > 0.0:
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
                    L += mul_sat(e.w, scene.background)
                    continue
                front = wp.dot(e.d, h.ng) < 0.0
                ng = h.ng
                n = h.ns
                if not front:
                    ng = -ng
                    n = -n
                if wp.dot(n, e.d) > 0.0:
                    n = ng  # a shading normal facing away from the viewer: fall back
                le = scene.mats[h.mat].emit
                if wp.max(le) > 0.0:
                    if front:
                        L += mul_sat(e.w, le)
                    continue
                v = -e.d
                local = mul_sat(scene.mats[h.mat].ka, scene.ambient)
                dl = direct_light(scene, h, ng, n, v, time)
                rays += int(dl[3])
                local += wp.vec3(dl[0], dl[1], dl[2])
                if wp.static(F.area_lights):
                    # called from the kernel, not from direct_light: a scene without area lights
                    # keeps direct_light small enough for the C++ compiler to inline (see
                    # docs/architecture.md, "Features and compile cost")
                    if scene.n_alights > 0:
                        al = area_lights_direct(scene, params, pixel, s, e.key, h.p,
                                                spawn_origin(h.p, ng, h.mag, 1.0), ng, n, v, scene.mats[h.mat].kd,
                                                scene.mats[h.mat].ks, scene.mats[h.mat].p, time)
                        rays += int(al[3])
                        local += wp.vec3(al[0], al[1], al[2])
                L += mul_sat(e.w, local)

                if wp.static(F.secondary):
                    if e.depth < params.max_depth:
                        w_refl = scene.mats[h.mat].km
                        if wp.static(F.refraction):
                            kt = scene.mats[h.mat].kt
                            if wp.max(kt) > 0.0:
                                ior = scene.mats[h.mat].ior
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
                                    mode = scene.mats[h.mat].fresnel
                                    if mode > 0:
                                        fr = fresnel(mode, -wp.dot(e.d, n), eta_i, eta_t)
                                        w_refl = w_refl + kt * fr
                                        w_refr = kt * (1.0 - fr)
                                    if wp.static(F.glossy):
                                        frost = scene.mats[h.mat].frost
                                        if frost > 0.0:
                                            ug = sample_2d(params.sampler, params.seed, pixel, s, params.spp,
                                                           hash2(e.key, wp.uint32(2)))
                                            tdir = lobe(ug, tdir, frost)
                                    tw = mul_sat(e.w, w_refr)
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
                        rw = mul_sat(e.w, w_refl)
                        if wp.max(rw) > params.min_weight:
                            r = reflect(e.d, n)
                            if wp.static(F.glossy):
                                gloss = scene.mats[h.mat].gloss
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

    return SimpleNamespace(render=render_kernel, closest_hit=closest_hit, sphere_center=sphere_center,
                           instance_pos=instance_pose_pos, instance_rot=instance_pose_rot,
                           instance_scl=instance_pose_scl)


_cache: dict[Features, SimpleNamespace] = {}
_cache_lock = threading.Lock()


def kernels_for(features: Features) -> SimpleNamespace:
    """The render kernel and its device functions for a feature set, built once per process."""
    with _cache_lock:
        if features not in _cache:
            _cache[features] = _make_kernels(features)
        return _cache[features]
