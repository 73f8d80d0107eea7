"""Tracing: the nearest hit over every shape (``closest_hit``) and the light passing along a
shadow segment (``transmittance``, ``shadow``), with mesh instances posed at the ray's time.

``make_trace(features)`` builds these device functions for one :class:`Features` value (code a
scene does not use is removed with ``wp.static``); the render kernel, the AOV kernel and the
ray-query kernels all call the same ones. Functions that need no feature switch are defined at
module level.

Inlining: Warp passes structs to functions by value, and ``SceneData`` is about 700 bytes. The
hot functions (``closest_hit``, ``transmittance``, ``shadow`` and the small helpers they call)
are force-inlined (``@wp.func(inline=True)``): left to the C++ compiler, a kernel with the mesh,
area-light and secondary-ray code grew past its inlining budget, ``closest_hit`` became a real
call that copied the scene for every ray. The mesh helpers stay compiler-decided (marking them
``inline=False`` made mesh-heavy scenes slower: the copy per call again).
"""

from __future__ import annotations

from types import SimpleNamespace

import warp as wp

from .accel import (
    PACKET, PACKET_MISS, SHADOW_PACKET_MIN, PacketF, PacketI, StackDist, StackRefs, horizon_escapes, lane, lane_i,
    mesh_balls_hit, mesh_bins_packet, mesh_bins_ray, mesh_tree_occluded, mesh_tree_occluded_packet, mesh_tree_packet,
    mesh_tree_ray, packet_node, safe_inverse, slab,
)
from ._warp import build_once
from . import fast
from .fast import FAST_ANALYTIC_PACKETS
from .geometry import (
    SPAWN_REL, abs3, box_roots, capsule_roots, cylinder_roots, disk_extent, interval_hit, intersect_disk, light_cells,
    intersect_plane, intersect_rect, intersect_sphere, max_abs, plane_hits_packet, plane_leaf_packet, quat_rotate_mag,
    ray_box, box_hits_packet, rect_hits_packet, rect_leaf_packet, refine_on_plane, refine_on_sphere, spawn_offset,
    sphere_hits_packet, sphere_leaf_packet, sphere_roots,
)
from .records import (
    KIND_BOX, KIND_CAPSULE, KIND_CYLINDER, KIND_DISK, KIND_MESH, KIND_NONE, KIND_PLANE, KIND_RECT, KIND_SPHERE,
    Features, InstRec, SceneData, SolidRec,
)

# shadow_packets switched off (warprt.fast, as warprt is imported): a packet's shadow rays each alone
SHADOW_LANES_ALONE = fast.import_off("shadow_packets")
TIE = SPAWN_REL  # relative band within which an analytic hit beats a mesh hit: the spawn-offset factor 2^-17

# the fewest rays worth a packet through the analytic BVH: each node costs a packet the 8 lanes'
# tests whatever the lanes in use, so fewer rays go one by one (with the node tests as clang
# vectors, accel.packet_node, 2 rays in a packet take as long as alone and 3 take less)
PACKET_MIN = 3
# the fewest camera rays worth a packet through the meshes (mesh_packet: with 3 or 4 rays a packet
# is not faster than the rays one by one on every mesh)
MESH_PACKET_MIN = 5


@wp.struct
class PacketHits:
    """A camera packet's nearest analytic hits so far (``CameraPacket``'s best, kind and index),
    what ``trace_packet`` changes: returned alone, so that the packet's rays are not copied."""

    best: PacketF
    kind: PacketI
    index: PacketI


@wp.struct
class CameraPacket:
    """Up to PACKET camera rays of one pixel (origins, unit directions, times) and, per ray, the
    nearest analytic hit so far: its t (the ray's t_max before any; below 0 for an unused lane),
    kind and row."""

    ox: PacketF
    oy: PacketF
    oz: PacketF
    dx: PacketF
    dy: PacketF
    dz: PacketF
    time: PacketF
    best: PacketF
    kind: PacketI
    index: PacketI


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
    face: int  # a mesh's triangle (0 for other kinds)


@wp.struct
class Nearest:
    """The nearest analytic hit so far: its t (the ray's t_max before any), kind and row."""

    t: float
    kind: int
    index: int


@wp.struct
class MeshPacket:
    """Per lane of a camera packet, the nearest mesh hit (``mesh_nearest``'s): instance (-1 for
    none), t, face and barycentrics."""

    inst: PacketI
    t: PacketF
    face: PacketI
    u: PacketF
    v: PacketF


@wp.struct
class MeshHit:
    t: float
    index: int  # instance, -1 for none
    face: int
    u: float
    v: float


@wp.struct
class Pose:
    """A mesh instance's transform at one time: scale, then rotate, then translate."""

    pos: wp.vec3
    rot: wp.quat
    scl: wp.vec3
    plain: int  # 1: no rotation and unit scale (a translation at most): the maps below skip both


@wp.func(inline=True)
def plain_pose(pose: Pose) -> int:
    """1 where the pose neither rotates nor scales. The maps below then skip the rotation (by the
    unit quaternion: x·1 plus products of zeros) and the division by 1: the same coordinates, up
    to the sign of a zero one. Most instances neither rotate nor scale, and the maps run for
    every ray that meets an instance's box."""
    if pose.rot[0] == 0.0 and pose.rot[1] == 0.0 and pose.rot[2] == 0.0 and pose.rot[3] == 1.0:
        if pose.scl[0] == 1.0 and pose.scl[1] == 1.0 and pose.scl[2] == 1.0:
            return 1
    return 0


@wp.func(inline=True)
def to_object(pose: Pose, p: wp.vec3) -> wp.vec3:
    if pose.plain != 0:
        return p - pose.pos
    return wp.cw_div(wp.quat_rotate_inv(pose.rot, p - pose.pos), pose.scl)


@wp.func(inline=True)
def dir_to_object(pose: Pose, d: wp.vec3) -> wp.vec3:
    if pose.plain != 0:
        return d
    return wp.cw_div(wp.quat_rotate_inv(pose.rot, d), pose.scl)


@wp.func(inline=True)
def to_world(pose: Pose, p: wp.vec3) -> wp.vec3:
    if pose.plain != 0:
        return p + pose.pos
    return wp.quat_rotate(pose.rot, wp.cw_mul(p, pose.scl)) + pose.pos


@wp.func(inline=True)
def normal_to_world(pose: Pose, n: wp.vec3) -> wp.vec3:
    """Not normalised."""
    if pose.plain != 0:
        return n
    return wp.quat_rotate(pose.rot, wp.cw_div(n, pose.scl))


@wp.func
def turned_extent(q: wp.quat, e: wp.vec3) -> wp.vec3:
    """Half extents of the world box around a box of half extents e turned by q."""
    m = wp.quat_to_matrix(q)
    ext = wp.vec3(0.0)
    for k in range(3):
        ext[k] = wp.abs(m[k, 0]) * e[0] + wp.abs(m[k, 1]) * e[1] + wp.abs(m[k, 2]) * e[2]
    return ext


@wp.func
def turns(q0: wp.quat, q1: wp.quat) -> bool:
    """Whether the rotation at time 1 differs from the one at time 0."""
    for k in range(4):
        if q1[k] != q0[k]:
            return True
    return False


@wp.func
def swept_sphere_lo(p0: wp.vec3, p1: wp.vec3, rr: float) -> wp.vec3:
    """The lower corner of the boxes of the spheres of radius rr about p0 and p1 (the upper is
    ``swept_sphere_lo(-p0, -p1, rr)`` negated)."""
    return wp.min(p0, p1) - wp.vec3(rr, rr, rr)


@wp.func
def box_pad(lo: wp.vec3, hi: wp.vec3) -> wp.vec3:
    """Padding of a world box against float32 rounding: 1e-6 of its size and of its coordinates."""
    pad = (wp.max(hi - lo) + wp.max(abs3(lo) + abs3(hi))) * 1.0e-6 + 1.0e-30
    return wp.vec3(pad, pad, pad)


@wp.func
def instance_box(rec: InstRec) -> InstRec:
    """``rec`` with its world box (``lo``, ``hi``) from its object box (``olo``, ``ohi``) and pose:
    the transformed box, padded; when the pose at time 1 differs, the boxes of the sphere about
    the instance origin that holds the object, at both ends (a rotation by slerp keeps every point
    of the object within it, and the origin moves linearly)."""
    r = rec
    c = (rec.olo + rec.ohi) * 0.5
    e = (rec.ohi - rec.olo) * 0.5
    ext = turned_extent(rec.rot0, wp.cw_mul(abs3(rec.scl0), e))
    wc = wp.quat_rotate(rec.rot0, wp.cw_mul(c, rec.scl0)) + rec.pos0
    lo = wc - ext
    hi = wc + ext
    moved = wp.max(abs3(rec.pos1 - rec.pos0)) > 0.0 or wp.max(abs3(rec.scl1 - rec.scl0)) > 0.0
    if moved or turns(rec.rot0, rec.rot1):
        far = wp.max(abs3(rec.olo), abs3(rec.ohi))
        r0 = wp.length(wp.cw_mul(far, abs3(rec.scl0)))
        r1 = wp.length(wp.cw_mul(far, abs3(rec.scl1)))
        rr = wp.max(r0, r1)
        lo = swept_sphere_lo(rec.pos0, rec.pos1, rr)
        hi = -swept_sphere_lo(-rec.pos0, -rec.pos1, rr)
    r.lo = lo - box_pad(lo, hi)
    r.hi = hi + box_pad(lo, hi)
    return r


@wp.func(inline=True)
def posed_solid(base: SceneData, kind: int, row: int) -> SolidRec:
    """Row ``row`` of solid table ``kind``."""
    if kind == KIND_BOX:
        return base.boxes[row]
    if kind == KIND_CAPSULE:
        return base.capsules[row]
    return base.cylinders[row]


@wp.func(inline=True)
def solid_count(base: SceneData, kind: int) -> int:
    """Rows of solid table ``kind``."""
    if kind == KIND_BOX:
        return base.n_boxes
    if kind == KIND_CAPSULE:
        return base.n_capsules
    return base.n_cylinders


@wp.func
def solid_extent(kind: int, size: wp.vec3) -> wp.vec3:
    """Half extents of a solid's box in its own frame (as ``shapes.solid_extent``)."""
    if kind == KIND_BOX:
        return size
    if kind == KIND_CAPSULE:
        return wp.vec3(size[0], size[1] + size[0], size[0])
    return wp.vec3(size[0], size[1], size[0])


@wp.func
def solid_box(rec: SolidRec, kind: int) -> SolidRec:
    """``rec`` with its world box (``lo``, ``hi``), as ``instance_box`` does for an instance: the
    turned box, or, when the pose at time 1 differs, the boxes of the sphere about the centre
    that holds the solid at both ends; padded."""
    r = rec
    e = solid_extent(kind, rec.size)
    ext = turned_extent(rec.rot0, e)
    lo = rec.pos0 - ext
    hi = rec.pos0 + ext
    if wp.max(abs3(rec.pos1 - rec.pos0)) > 0.0 or turns(rec.rot0, rec.rot1):
        lo = swept_sphere_lo(rec.pos0, rec.pos1, wp.length(e))
        hi = -swept_sphere_lo(-rec.pos0, -rec.pos1, wp.length(e))
    r.lo = lo - box_pad(lo, hi)
    r.hi = hi + box_pad(lo, hi)
    return r


@build_once
def instance_box_kernel():
    """Object and world boxes of every mesh instance, from its asset's current points (one Warp
    module, run when a scene is built and when mesh points move)."""

    @wp.kernel(module="warprt_build", enable_backward=False)
    def instance_boxes(insts: wp.array(dtype=InstRec)):
        i = wp.tid()
        rec = insts[i]
        mesh = wp.mesh_get(rec.mesh)
        lo = wp.vec3(3.0e38, 3.0e38, 3.0e38)
        hi = wp.vec3(-3.0e38, -3.0e38, -3.0e38)
        for k in range(mesh.points.shape[0]):
            lo = wp.min(lo, mesh.points[k])
            hi = wp.max(hi, mesh.points[k])
        rec.olo = lo
        rec.ohi = hi
        insts[i] = instance_box(rec)

    return instance_boxes


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
def mesh_first_hit(inst: InstRec, o: wp.vec3, d: wp.vec3, t_max: float) -> MeshHit:
    """Nearest hit of instance ``inst``'s mesh along (o, d) (object space) in (0, t_max) on a
    triangle the ray really approaches (see ``leaves_face``); ``index`` 0 for a hit, -1 for none.
    A rejected hit (or one exactly at the origin) is stepped over by its rounding and the query
    repeated. The query is ``accel.mesh_bins_ray`` where the instance has the camera's bins and
    the ray comes from the eye, else ``accel.mesh_tree_ray`` (the CPU copy of the tree; Warp's on
    CUDA)."""
    r = MeshHit()
    r.index = -1
    mid = inst.mesh
    t0 = float(0.0)
    for _k in range(4):
        # a camera ray from the eye through the camera's bins, where the instance has them
        q = mesh_bins_ray(mid, inst.bins, inst.tree_tris, o + d * t0, d, t_max - t0)
        if q[0] == -2.0:
            q = mesh_tree_ray(mid, inst.tree_nodes, inst.tree_kids, inst.tree_tris, inst.tree_root,
                              o + d * t0, d, t_max - t0)
        if q[0] < 0.0:
            return r
        qt = q[0]
        face = int(q[3]) * 4096 + int(q[4])
        if qt > 0.0 and not leaves_face(mid, face, o, d):
            r.index = 0
            r.t = t0 + qt
            r.face = face
            r.u = q[1]
            r.v = q[2]
            return r
        mesh = wp.mesh_get(mid)
        v0 = mesh.points[mesh.indices[face * 3]]
        t0 = t0 + wp.max(qt, 0.0) + spawn_offset(max_abs(o) + max_abs(v0)) / wp.length(d)
        if t0 >= t_max:
            return r
    return r


@build_once
def make_trace(F: Features) -> SimpleNamespace:
    """The tracing device functions for one feature set (built once per process)."""

    @wp.func
    def instance_pose(scene: SceneData, i: int, time: float) -> Pose:
        """Instance i's pose at ``time`` (poses given at times 0 and 1; rotations by slerp)."""
        return inst_pose(scene.insts[i], time)

    @wp.func(inline=True)
    def inst_pose(inst: InstRec, time: float) -> Pose:
        """``instance_pose`` from the instance's record."""
        pose = Pose()
        pose.pos = inst.pos0
        pose.rot = inst.rot0
        pose.scl = inst.scl0
        if wp.static(F.motion):
            pose.pos = pose.pos + (inst.pos1 - pose.pos) * time
            pose.rot = wp.quat_slerp(pose.rot, inst.rot1, time)
            pose.scl = pose.scl + (inst.scl1 - pose.scl) * time
        pose.plain = plain_pose(pose)
        return pose

    @wp.func(inline=True)
    def sphere_center(scene: SceneData, i: int, time: float) -> wp.vec3:
        c = scene.spheres[i].c0
        if wp.static(F.motion):
            c = c + (scene.spheres[i].c1 - c) * time
        return c

    @wp.func(inline=True)
    def crossing(scene: SceneData, mat: int) -> wp.vec3:
        """Light passing one surface of material ``mat`` in a shadow ray: kt, or 0 when opaque."""
        if wp.static(F.refraction):
            return scene.mats[mat].kt
        return wp.vec3(0.0, 0.0, 0.0)

    @wp.func(inline=True)
    def solid_pose(rec: SolidRec, time: float) -> Pose:
        """A box's, capsule's or cylinder's frame at ``time`` (scale 1)."""
        pose = Pose()
        pose.pos = rec.pos0
        pose.rot = rec.rot0
        pose.scl = wp.vec3(1.0, 1.0, 1.0)
        if wp.static(F.motion):
            pose.pos = pose.pos + (rec.pos1 - pose.pos) * time
            pose.rot = wp.quat_slerp(pose.rot, rec.rot1, time)
        pose.plain = plain_pose(pose)
        return pose

    solid_rec = posed_solid

    @wp.func(inline=True)
    def solid_interval(k: int, rec: SolidRec, pose: Pose, o: wp.vec3, d: wp.vec3) -> wp.vec4:
        """The ray's interval inside solid ``rec`` of kind k posed at ``pose`` (see geometry)."""
        o_l = wp.quat_rotate_inv(pose.rot, o - pose.pos)
        d_l = wp.quat_rotate_inv(pose.rot, d)
        if k == KIND_BOX:
            return box_roots(o_l, d_l, rec.size)
        if k == KIND_CAPSULE:
            return capsule_roots(o_l, d_l, rec.size[0], rec.size[1])
        return cylinder_roots(o_l, d_l, rec.size[0], rec.size[1])

    @wp.func(inline=True)
    def solid_hit(scene: SceneData, o: wp.vec3, d: wp.vec3, t_min: float, t_max: float, time: float,
                  k: int, i: int) -> float:
        rec = solid_rec(scene, k, i)
        return interval_hit(solid_interval(k, rec, solid_pose(rec, time), o, d), t_min, t_max)

    @wp.func(inline=True)
    def solid_hit_boxed(scene: SceneData, o: wp.vec3, d: wp.vec3, inv_d: wp.vec3, t_min: float, t_max: float,
                        time: float, k: int, i: int) -> float:
        """``solid_hit`` after the solid's world box (a loop over a table has no BVH to cull)."""
        rec = solid_rec(scene, k, i)
        if not ray_box(o, inv_d, rec.lo, rec.hi, t_min, t_max):
            return -1.0
        return interval_hit(solid_interval(k, rec, solid_pose(rec, time), o, d), t_min, t_max)

    @wp.func
    def solid_details(rec: SolidRec, k: int, index: int, t: float, o: wp.vec3, d: wp.vec3, time: float) -> Hit:
        """The hit of solid (k, index) at t with its point refined onto the surface, its normal and
        material. The point is found in the solid's frame: on a box face the face's coordinate
        is set exactly and the others clamped to the face; on a cylinder side or a capsule the
        point is put at radius r from the axis (the segment)."""
        h = Hit()
        h.t = t
        h.kind = k
        h.index = index
        pose = solid_pose(rec, time)
        o_l = wp.quat_rotate_inv(pose.rot, o - pose.pos)
        d_l = wp.quat_rotate_inv(pose.rot, d)
        iv = solid_interval(k, rec, pose, o, d)
        entering = wp.abs(iv[0] - h.t) <= wp.abs(iv[1] - h.t)
        code = iv[3]
        out = float(1.0)  # the normal points along d where the ray leaves, against it where it enters
        if entering:
            code = iv[2]
            out = -1.0
        p = o_l + d_l * h.t
        n = wp.vec3(0.0)
        sz = rec.size
        if k == KIND_BOX:
            a = int(code)
            for j in range(3):
                p[j] = wp.clamp(p[j], -sz[j], sz[j])
            side = wp.where(d_l[a] * out >= 0.0, 1.0, -1.0)
            p[a] = side * sz[a]
            n[a] = side
        elif k == KIND_CYLINDER and code > 0.5:  # a cap
            side = wp.where(d_l[1] * out >= 0.0, 1.0, -1.0)
            p[1] = side * sz[1]
            rad = wp.sqrt(p[0] * p[0] + p[2] * p[2])
            if rad > sz[0]:
                p[0] = p[0] * (sz[0] / rad)
                p[2] = p[2] * (sz[0] / rad)
            n[1] = side
        else:  # a cylinder's side, or a capsule: from the nearest point of the axis segment
            axis = wp.vec3(0.0, wp.clamp(p[1], -sz[1], sz[1]), 0.0)
            v = p - axis
            lv = wp.length(v)
            if lv > 0.0:
                n = v / lv
            else:
                n = -d_l
            p = axis + n * sz[0]
        h.p = wp.quat_rotate(pose.rot, p) + pose.pos
        h.ng = wp.normalize(wp.quat_rotate(pose.rot, n))
        h.ns = h.ng
        h.mag = quat_rotate_mag(pose.rot, abs3(p)) + abs3(pose.pos) + abs3(h.p)
        h.mat = rec.mat
        return h

    @wp.func(inline=True)
    def solid_crossings(scene: SceneData, o: wp.vec3, d: wp.vec3, inv_d: wp.vec3, t_max: float, time: float,
                        k: int, i: int) -> wp.vec3:
        """Transmission through solid (k, i) along (o, d) over (0, t_max): kt per surface crossed
        (1 when the ray misses the solid's box)."""
        rec = solid_rec(scene, k, i)
        T = wp.vec3(1.0, 1.0, 1.0)
        if not ray_box(o, inv_d, rec.lo, rec.hi, 0.0, t_max):
            return T
        iv = solid_interval(k, rec, solid_pose(rec, time), o, d)
        if iv[0] <= iv[1]:
            for j in range(2):
                if iv[j] > 0.0 and iv[j] < t_max:
                    T = wp.cw_mul(T, crossing(scene, rec.mat))
        return T

    @wp.func(inline=True)
    def bounded_hit(scene: SceneData, o: wp.vec3, d: wp.vec3, t_min: float, t_max: float, time: float,
                    k: int, i: int) -> float:
        """The hit t of the bounded analytic shape (kind k, row i) in (t_min, t_max), or -1."""
        if k == KIND_SPHERE:
            return intersect_sphere(o, d, sphere_center(scene, i, time), scene.spheres[i].r, t_min, t_max)
        if k == KIND_RECT:
            return intersect_rect(o, d, scene.rects[i].c, scene.rects[i].e1, scene.rects[i].e2, t_min, t_max)
        if wp.static(F.solids):
            if k >= KIND_BOX:
                return solid_hit(scene, o, d, t_min, t_max, time, k, i)
        return intersect_disk(o, d, scene.disks[i].c, scene.disks[i].n, scene.disks[i].r, t_min, t_max)

    @wp.func(inline=True)
    def bounded_mat(scene: SceneData, k: int, i: int) -> int:
        if k == KIND_SPHERE:
            return scene.spheres[i].mat
        if k == KIND_RECT:
            return scene.rects[i].mat
        if wp.static(F.solids):
            if k >= KIND_BOX:
                return solid_rec(scene, k, i).mat
        return scene.disks[i].mat

    @wp.func
    def mesh_nearest(scene: SceneData, o: wp.vec3, d: wp.vec3, t_min: float, t_max: float, time: float) -> MeshHit:
        """Nearest triangle hit over all mesh instances in (t_min, t_max); index -1 for none."""
        best = float(t_max)
        r = MeshHit()
        r.index = -1
        start = o + d * t_min
        inv_d = wp.cw_div(wp.vec3(1.0, 1.0, 1.0), d)
        for i in range(scene.n_inst):
            if not ray_box(o, inv_d, scene.insts[i].lo, scene.insts[i].hi, t_min, best):
                continue  # the ray misses the instance's box before the nearest hit so far
            pose = instance_pose(scene, i, time)
            # (a hit exactly at t_min is outside the open range (t_min, t_max): mesh_first_hit
            # looks beyond it, as it does past a ray's own surface)
            q = mesh_first_hit(scene.insts[i], to_object(pose, start), dir_to_object(pose, d), best - t_min)
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
    def mesh_packet(scene: SceneData, pk: CameraPacket, t_min: float, lanes: int) -> MeshPacket:
        """``mesh_nearest`` for the first ``lanes`` rays of a camera packet at once, each bounded as
        ``finish_hit`` bounds it (its analytic hit, less the TIE band): per instance, the lanes
        whose ray meets its box go through its camera bins (``accel.mesh_bins_packet``) or its
        tree (``accel.mesh_tree_packet``) together, the same nearest triangle per lane as alone. A
        lane whose triangle is the one its ray leaves (or at t = 0), or a packet the tree cannot
        take, goes through ``mesh_first_hit`` alone."""
        mp = MeshPacket()
        bound = PacketF()  # each lane's search bound: its nearest hit so far
        for k in range(PACKET):
            mp.inst[k] = -1
            bound[k] = -1.0
        for k in range(lanes):
            bound[k] = lane(pk.best, k)
            if lane_i(pk.kind, k) != KIND_NONE:
                bound[k] = lane(pk.best, k) * (1.0 - TIE)
        for i in range(scene.n_inst):
            ox = PacketF()
            oy = PacketF()
            oz = PacketF()
            dx = PacketF()
            dy = PacketF()
            dz = PacketF()
            reach = PacketF()  # the lane's object-space t_max, < 0 for a lane that misses the box
            active = int(0)
            for k in range(PACKET):
                reach[k] = -1.0
            # the instance's box for all lanes at once (ray_box's test)
            inside = box_hits_packet(scene.insts[i].lo, scene.insts[i].hi, (1 << lanes) - 1, pk.ox, pk.oy, pk.oz, pk.dx,
                                     pk.dy, pk.dz, t_min, bound)
            if inside == 0:
                continue
            for k in range(lanes):
                if (inside >> k) & 1 != 0:
                    o = wp.vec3(lane(pk.ox, k), lane(pk.oy, k), lane(pk.oz, k))
                    d = wp.vec3(lane(pk.dx, k), lane(pk.dy, k), lane(pk.dz, k))
                    pose = instance_pose(scene, i, lane(pk.time, k))
                    so = to_object(pose, o + d * t_min)
                    sd = dir_to_object(pose, d)
                    ox[k] = so[0]
                    oy[k] = so[1]
                    oz[k] = so[2]
                    dx[k] = sd[0]
                    dy[k] = sd[1]
                    dz[k] = sd[2]
                    reach[k] = bound[k] - t_min
                    active += 1
            if active == 0:
                continue
            qt = PacketF()
            qu = PacketF()
            qv = PacketF()
            qf = PacketI()
            done = mesh_bins_packet(scene.insts[i].mesh, scene.insts[i].bins, scene.insts[i].tree_tris,
                                    scene.insts[i].prefetch, ox, oy, oz, dx, dy, dz, reach, qt, qu, qv, qf)
            if done == 0:
                done = mesh_tree_packet(scene.insts[i].mesh, scene.insts[i].wide, scene.insts[i].tree_tris,
                                        scene.insts[i].prefetch, ox, oy, oz, dx, dy, dz, reach, qt, qu, qv, qf)
            for k in range(lanes):
                if reach[k] < 0.0:
                    continue
                so = wp.vec3(ox[k], oy[k], oz[k])
                sd = wp.vec3(dx[k], dy[k], dz[k])
                q = MeshHit()
                q.index = -1
                if done != 0 and qt[k] < 0.0:
                    continue  # no triangle: as mesh_first_hit's first query finds
                if done != 0 and qt[k] > 0.0 and not leaves_face(scene.insts[i].mesh, qf[k], so, sd):
                    q.index = 0
                    q.t = qt[k]
                    q.face = qf[k]
                    q.u = qu[k]
                    q.v = qv[k]
                else:
                    q = mesh_first_hit(scene.insts[i], so, sd, reach[k])
                if q.index >= 0:
                    if q.t + t_min < bound[k]:
                        bound[k] = q.t + t_min
                        mp.t[k] = bound[k]
                        mp.inst[k] = i
                        mp.face[k] = q.face
                        mp.u[k] = q.u
                        mp.v[k] = q.v
        return mp

    @wp.func
    def mesh_details(scene: SceneData, index: int, t: float, o: wp.vec3, d: wp.vec3, face: int, bu: float,
                     bv: float, time: float) -> Hit:
        """The hit of instance ``index``'s triangle ``face`` at t with its point, normals and material.

        The point is taken, in object space, from the barycentrics or from the ray's crossing of
        the triangle's plane, whichever was computed from smaller coordinates (the barycentric
        point of a triangle 1e4 wide is off by ~1e-3 along the surface; the ray point seen from a
        far camera likewise), and then projected onto that plane."""
        h = Hit()
        h.t = t
        h.kind = KIND_MESH
        h.index = index
        h.face = face
        mid = scene.insts[index].mesh
        pose = instance_pose(scene, index, time)
        mesh = wp.mesh_get(mid)
        v0 = mesh.points[mesh.indices[face * 3 + 0]]
        v1 = mesh.points[mesh.indices[face * 3 + 1]]
        v2 = mesh.points[mesh.indices[face * 3 + 2]]
        tri_mag = wp.max(abs3(v0), wp.max(abs3(v1), abs3(v2)))
        n_obj = wp.mesh_eval_face_normal(mid, face)
        p_obj = wp.mesh_eval_position(mid, face, bu, bv)
        if max_abs(o) + h.t < max_abs(wp.cw_mul(tri_mag, pose.scl)) + max_abs(pose.pos):
            # the ray met the triangle's plane (in object space, like intersect_plane: exact for
            # an axis-aligned triangle) where Warp's t says, give or take its rounding
            o_obj = to_object(pose, o)
            d_obj = dir_to_object(pose, d)
            # (Warp's own t is off by up to ~0.3% on a triangle 1e4 times wider than the ray
            # length; the plane's t is used unless the ray grazes the plane)
            denom = wp.dot(n_obj, d_obj)
            if wp.abs(denom) > 1.0e-2 * wp.length(d_obj):
                t_plane = wp.dot(n_obj, v0 - o_obj) / denom
                if wp.abs(t_plane - h.t) <= 1.0e-2 * h.t:
                    p_obj = o_obj + d_obj * t_plane
                    h.t = t_plane
        p_obj = refine_on_plane(p_obj, v0, n_obj)
        h.p = to_world(pose, p_obj)
        # error bound: the triangle's coordinates (its plane), carried through scale and rotation,
        # plus the translation and the point itself (the rounding of the transform and of the
        # next ray's way back into object space)
        m_obj = wp.cw_mul(wp.max(tri_mag, abs3(p_obj)), abs3(pose.scl))
        h.mag = quat_rotate_mag(pose.rot, m_obj) + abs3(pose.pos) + abs3(h.p)
        h.ng = wp.normalize(normal_to_world(pose, n_obj))
        h.ns = h.ng
        if scene.insts[index].smooth != 0:
            off = scene.insts[index].nrm_off
            n0 = scene.normals[off + mesh.indices[face * 3 + 0]]
            n1 = scene.normals[off + mesh.indices[face * 3 + 1]]
            n2 = scene.normals[off + mesh.indices[face * 3 + 2]]
            ns_w = normal_to_world(pose, bu * n0 + bv * n1 + (1.0 - bu - bv) * n2)
            if wp.length(ns_w) > 0.0:
                h.ns = wp.normalize(ns_w)
        h.mat = scene.insts[index].mat
        return h

    @wp.func
    def trace_packet(scene: SceneData, pk: CameraPacket, t_min: float, lanes: int) -> PacketHits:
        """The nearest analytic hit (planes, then the BVH over the bounded shapes) of each of the
        first ``lanes`` rays of a packet, as ``closest_hit`` finds it for each ray alone: the
        same tests with the same bounds, so the same hit, bit for bit. The packet goes through
        the BVH together: a node is opened while any lane's ray meets its box before that lane's
        nearest hit, children nearest first by the least entry over the lanes, so the rays of
        one pixel share each node's load and the per-lane box tests (a fixed-length loop the
        C++ compiler vectorises) run side by side. Lanes from ``lanes`` on must have best < 0.
        With analytic_packets switched off (``warprt.fast``) each lane goes alone."""
        hits = PacketHits()
        hits.best = pk.best
        hits.kind = pk.kind
        hits.index = pk.index
        each = (scene.fast_off & FAST_ANALYTIC_PACKETS) != 0
        if scene.bvh_root < 0 or each:
            # no analytic BVH: the spheres, planes and rectangles each for all lanes at once, in the
            # loops' order (kinds and rows ascending: a hit replaces another only when strictly
            # nearer, as in analytic_nearest); with disks or solids, the analytic shapes ray by ray
            alone = scene.n_disks > 0 or each
            if wp.static(F.solids):
                alone = True
            if not alone:
                for i in range(scene.n_spheres):
                    sc = scene.spheres[i].c0
                    if wp.static(F.motion):
                        sphere_leaf_packet(sc, scene.spheres[i].c1 - sc, 1, scene.spheres[i].r, KIND_SPHERE, i, lanes,
                                           t_min, pk.ox, pk.oy, pk.oz, pk.dx, pk.dy, pk.dz, pk.time, hits.best, hits.kind,
                                           hits.index)
                    else:
                        sphere_leaf_packet(sc, sc, 0, scene.spheres[i].r, KIND_SPHERE, i, lanes, t_min, pk.ox, pk.oy,
                                           pk.oz, pk.dx, pk.dy, pk.dz, pk.time, hits.best, hits.kind, hits.index)
                for i in range(scene.n_planes):
                    plane_leaf_packet(scene.planes[i].p, scene.planes[i].n, KIND_PLANE, i, lanes, t_min, pk.ox, pk.oy,
                                      pk.oz, pk.dx, pk.dy, pk.dz, hits.best, hits.kind, hits.index)
                for i in range(scene.n_rects):
                    rect_leaf_packet(scene.rects[i].c, scene.rects[i].e1, scene.rects[i].e2, KIND_RECT, i, lanes, t_min,
                                     pk.ox, pk.oy, pk.oz, pk.dx, pk.dy, pk.dz, hits.best, hits.kind, hits.index)
                return hits
            for k in range(lanes):
                a = analytic_nearest(scene, wp.vec3(lane(pk.ox, k), lane(pk.oy, k), lane(pk.oz, k)),
                                     wp.vec3(lane(pk.dx, k), lane(pk.dy, k), lane(pk.dz, k)), t_min, lane(hits.best, k),
                                     lane(pk.time, k))
                hits.best[k] = a.t
                hits.kind[k] = a.kind
                hits.index[k] = a.index
            return hits
        inv_x = PacketF()
        inv_y = PacketF()
        inv_z = PacketF()
        for k in range(lanes):
            inv = safe_inverse(wp.vec3(lane(pk.dx, k), lane(pk.dy, k), lane(pk.dz, k)))
            inv_x[k] = inv[0]
            inv_y[k] = inv[1]
            inv_z[k] = inv[2]
        for i in range(scene.n_planes):
            plane_leaf_packet(scene.planes[i].p, scene.planes[i].n, KIND_PLANE, i, lanes, t_min, pk.ox, pk.oy, pk.oz,
                              pk.dx, pk.dy, pk.dz, hits.best, hits.kind, hits.index)
        far_all = float(0.0)  # the farthest any lane still searches
        for k in range(PACKET):
            far_all = wp.max(far_all, lane(hits.best, k))
        refs = StackRefs()
        entry = StackDist()
        refs[0] = scene.bvh_root
        sp = int(1)
        while sp > 0:
            sp -= 1
            if entry[sp] > far_all:
                continue
            ref = refs[sp]
            if ref >= 0:
                # the scalar traversal's test, lane by lane (an inactive lane's best < 0 fails it):
                # per child, the least entry over the lanes that meet it (PACKET_MISS: none)
                ee = packet_node(scene.bvh_nodes, ref, pk.ox, pk.oy, pk.oz, inv_x, inv_y, inv_z, hits.best)
                e0 = ee[0]
                e1 = ee[1]
                c0 = scene.bvh_nodes[ref].c0
                c1 = scene.bvh_nodes[ref].c1
                near = c0
                far = c1
                t_near = e0
                t_far = e1
                if e1 < e0:
                    near = c1
                    far = c0
                    t_near = e1
                    t_far = e0
                if t_far < PACKET_MISS:
                    refs[sp] = far
                    entry[sp] = t_far
                    sp += 1
                if t_near < PACKET_MISS:
                    refs[sp] = near
                    entry[sp] = t_near
                    sp += 1
                continue
            j = -ref - 1
            kk = scene.bvh_prims[j][0]
            ii = scene.bvh_prims[j][1]
            # a sphere or a rectangle for all lanes at once (the same tests and updates as below)
            if kk == KIND_SPHERE:
                sc = scene.spheres[ii].c0
                if wp.static(F.motion):
                    far_all = sphere_leaf_packet(sc, scene.spheres[ii].c1 - sc, 1, scene.spheres[ii].r, kk, ii, lanes,
                                                 t_min, pk.ox, pk.oy, pk.oz, pk.dx, pk.dy, pk.dz, pk.time, hits.best,
                                                 hits.kind, hits.index)
                else:
                    far_all = sphere_leaf_packet(sc, sc, 0, scene.spheres[ii].r, kk, ii, lanes, t_min, pk.ox, pk.oy,
                                                 pk.oz, pk.dx, pk.dy, pk.dz, pk.time, hits.best, hits.kind, hits.index)
                continue
            if kk == KIND_RECT:
                far_all = rect_leaf_packet(scene.rects[ii].c, scene.rects[ii].e1, scene.rects[ii].e2, kk, ii, lanes,
                                           t_min, pk.ox, pk.oy, pk.oz, pk.dx, pk.dy, pk.dz, hits.best, hits.kind, hits.index)
                continue
            far_all = float(0.0)
            for k in range(lanes):
                # (the lane's entries read in place: a copy of the vectors would wait for the
                # last lane's stores, accel.lane)
                lane_best = lane(hits.best, k)
                kind = lane_i(hits.kind, k)
                # the tie rule of closest_hit's leaves
                first = kind != KIND_NONE and (kk < kind or (kk == kind and ii < lane_i(hits.index, k)))
                t_hi = lane_best
                if first:
                    t_hi = lane_best * 1.0000002 + 1.0e-38
                t = bounded_hit(scene, wp.vec3(lane(pk.ox, k), lane(pk.oy, k), lane(pk.oz, k)),
                                wp.vec3(lane(pk.dx, k), lane(pk.dy, k), lane(pk.dz, k)),
                                t_min, t_hi, lane(pk.time, k), kk, ii)
                if t >= 0.0 and (t < lane_best or (first and t == lane_best)):
                    hits.best[k] = t
                    hits.kind[k] = kk
                    hits.index[k] = ii
                    lane_best = t
                far_all = wp.max(far_all, lane_best)
        return hits

    @wp.func(inline=True)
    def analytic_nearest(scene: SceneData, o: wp.vec3, d: wp.vec3, t_min: float, t_max: float,
                         time: float) -> Nearest:
        """The nearest analytic shape along (o, d) (unit d) in (t_min, t_max): t, kind, row."""
        best = float(t_max)
        kind = int(KIND_NONE)
        index = int(-1)
        # kinds in the order spheres, planes, rectangles, disks; a hit replaces another only when
        # strictly nearer. Many bounded shapes: planes first, then one BVH over the rest
        use_bvh = scene.bvh_root >= 0
        if not use_bvh:
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
        if use_bvh:
            # nearest child first; a child stays on the stack with its entry distance and is
            # dropped once a hit is nearer. Boxes entered at exactly ``best`` are still opened:
            # a shape the loops test first may take a hit at the same t (the tie rule below)
            inv_d = safe_inverse(d)
            refs = StackRefs()
            entry = StackDist()
            refs[0] = scene.bvh_root
            sp = int(1)
            while sp > 0:
                sp -= 1
                if entry[sp] > best:
                    continue
                ref = refs[sp]
                if ref >= 0:
                    nd = scene.bvh_nodes[ref]
                    s0 = slab(o, inv_d, nd.lo0, nd.hi0)
                    s1 = slab(o, inv_d, nd.lo1, nd.hi1)
                    h0 = s0[0] <= s0[1] and s0[1] >= 0.0 and s0[0] <= best
                    h1 = s1[0] <= s1[1] and s1[1] >= 0.0 and s1[0] <= best
                    if h0 and h1:
                        near = nd.c0
                        far = nd.c1
                        t_near = s0[0]
                        t_far = s1[0]
                        if s1[0] < s0[0]:
                            near = nd.c1
                            far = nd.c0
                            t_near = s1[0]
                            t_far = s0[0]
                        refs[sp] = far
                        entry[sp] = t_far
                        refs[sp + 1] = near
                        entry[sp + 1] = t_near
                        sp += 2
                    elif h0:
                        refs[sp] = nd.c0
                        entry[sp] = s0[0]
                        sp += 1
                    elif h1:
                        refs[sp] = nd.c1
                        entry[sp] = s1[0]
                        sp += 1
                    continue
                j = -ref - 1
                k = scene.bvh_prims[j][0]
                i = scene.bvh_prims[j][1]
                # ties as in the loops (kinds in KIND_* order, rows in table order): a shape the
                # loops would test before the current hit may also take it at the same t. Its
                # search bound is raised above ``best`` (intersections exclude t_max) and only
                # t == best is accepted there
                first = kind != KIND_NONE and (k < kind or (k == kind and i < index))
                t_hi = best
                if first:
                    t_hi = best * 1.0000002 + 1.0e-38
                t = bounded_hit(scene, o, d, t_min, t_hi, time, k, i)
                if t >= 0.0 and (t < best or (first and t == best)):
                    best = t
                    kind = k
                    index = i
        else:
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
            if wp.static(F.solids):
                inv_d = wp.cw_div(wp.vec3(1.0, 1.0, 1.0), d)
                for k in range(KIND_BOX, KIND_CYLINDER + 1):
                    for i in range(solid_count(scene, k)):
                        t = solid_hit_boxed(scene, o, d, inv_d, t_min, best, time, k, i)
                        if t >= 0.0:
                            best = t
                            kind = k
                            index = i
        r = Nearest()
        r.t = best
        r.kind = kind
        r.index = index
        return r

    @wp.func(inline=True)
    def closest_hit(scene: SceneData, o: wp.vec3, d: wp.vec3, t_min: float, t_max: float, time: float) -> Hit:
        """The nearest surface along (o, d) (unit d) in (t_min, t_max), refined onto its surface."""
        a = analytic_nearest(scene, o, d, t_min, t_max, time)
        return finish_hit(scene, o, d, t_min, time, a.t, a.kind, a.index)

    @wp.func(inline=True)
    def finish_hit(scene: SceneData, o: wp.vec3, d: wp.vec3, t_min: float, time: float, best_analytic: float,
                   kind_analytic: int, index_analytic: int) -> Hit:
        """``closest_hit`` from the nearest analytic hit on: the mesh instances (bounded by that
        hit), then the hit refined onto its surface. ``kind_analytic`` is KIND_NONE (and
        ``best_analytic`` the ray's t_max) where no analytic shape was hit."""
        m = MeshHit()
        m.index = -1
        if wp.static(F.meshes):
            if scene.n_inst > 0:
                # ties: a mesh must be nearer than an analytic hit by TIE relative to replace it.
                # Warp's triangle t and an analytic t for the same surface differ by ~9 ulps
                # either way; without the band a mesh on a plane z-fights in a noisy pattern
                mesh_t_max = best_analytic
                if kind_analytic != KIND_NONE:
                    mesh_t_max = best_analytic * (1.0 - TIE)
                m = mesh_nearest(scene, o, d, t_min, mesh_t_max, time)
        return nearer_hit(scene, o, d, time, best_analytic, kind_analytic, index_analytic, m)

    @wp.func(inline=True)
    def finish_packet_lane(scene: SceneData, o: wp.vec3, d: wp.vec3, time: float, best_analytic: float,
                           kind_analytic: int, index_analytic: int, mp: MeshPacket, k: int) -> Hit:
        """``finish_hit`` for lane k of a camera packet whose mesh hits ``mesh_packet`` found."""
        m = MeshHit()
        m.index = lane_i(mp.inst, k)
        m.t = lane(mp.t, k)
        m.face = lane_i(mp.face, k)
        m.u = lane(mp.u, k)
        m.v = lane(mp.v, k)
        return nearer_hit(scene, o, d, time, best_analytic, kind_analytic, index_analytic, m)

    @wp.func(inline=True)
    def nearer_hit(scene: SceneData, o: wp.vec3, d: wp.vec3, time: float, best_analytic: float,
                   kind_analytic: int, index_analytic: int, m: MeshHit) -> Hit:
        """The mesh hit ``m`` (found below the analytic hit's bound; index -1: none) where there
        is one, else the analytic hit, refined onto its surface."""
        best = best_analytic
        kind = kind_analytic
        index = index_analytic
        face = int(-1)
        bu = float(0.0)
        bv = float(0.0)
        if wp.static(F.meshes):
            if m.index >= 0:
                best = m.t
                kind = KIND_MESH
                index = m.index
                face = m.face
                bu = m.u
                bv = m.v
        return refine_hit(scene, o, d, time, best, kind, index, face, bu, bv)

    @wp.func(inline=True)
    def refine_hit(scene: SceneData, o: wp.vec3, d: wp.vec3, time: float, best: float, kind: int, index: int,
                   face: int, bu: float, bv: float) -> Hit:
        """The nearest hit (t, kind, row; a mesh's face and barycentrics) refined onto its surface."""
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
            # (the planar kinds' fields written in place, and a mesh's or solid's hit made by its
            # details function: a Hit passed by value to a function is copied in 8-byte words,
            # and the copy's first word, t and kind stored apart just above, waited for both
            # stores to complete)
            h.p = refine_on_plane(p, scene.planes[index].p, scene.planes[index].n)
            h.ng = scene.planes[index].n
            h.ns = h.ng
            h.mat = scene.planes[index].mat
            h.mag = wp.max(abs3(h.p), abs3(scene.planes[index].p))
        elif kind == KIND_RECT:
            rect = scene.rects[index]
            h.p = refine_on_plane(p, rect.c, rect.n)
            h.ng = rect.n
            h.ns = rect.n
            h.mat = rect.mat
            h.mag = abs3(rect.c) + abs3(rect.e1) + abs3(rect.e2)
        elif kind == KIND_DISK:
            disk = scene.disks[index]
            h.p = refine_on_plane(p, disk.c, disk.n)
            h.ng = disk.n
            h.ns = disk.n
            h.mat = disk.mat
            h.mag = abs3(disk.c) + disk_extent(disk.n, disk.r)
        if wp.static(F.meshes):
            if kind == KIND_MESH:
                return mesh_details(scene, index, best, o, d, face, bu, bv, time)
        if wp.static(F.solids):
            if kind >= KIND_BOX:
                return solid_details(solid_rec(scene, kind, index), kind, index, best, o, d, time)
        return h

    @wp.func(inline=True)
    def sphere_crossings(scene: SceneData, o: wp.vec3, d: wp.vec3, t_max: float, time: float, i: int) -> wp.vec3:
        """Transmission through sphere i along (o, d) over (0, t_max): kt per surface crossed."""
        roots = sphere_roots(o, d, sphere_center(scene, i, time), scene.spheres[i].r)
        T = wp.vec3(1.0, 1.0, 1.0)
        for k in range(2):
            if roots[k] > 0.0 and roots[k] < t_max:
                T = wp.cw_mul(T, crossing(scene, scene.spheres[i].mat))
        return T

    @wp.func(inline=True)
    def opaque_occluded(scene: SceneData, i: int, o_obj: wp.vec3, d_obj: wp.vec3, t_max: float) -> bool:
        """Whether a triangle of opaque instance i blocks the shadow ray (o_obj, d_obj) over
        (0, t_max), in its object space: first the interior balls (accel.py: a segment through
        one enters the solid), then any triangle the ray meets and does not leave (the CPU's tree
        copy stops at the first), else the nearest-hit loop, which steps over the face the ray
        leaves."""
        if scene.insts[i].n_balls > 0:
            if mesh_balls_hit(scene.insts[i].balls, scene.insts[i].n_balls, o_obj, d_obj, t_max) != 0:
                return True
        occ = mesh_tree_occluded(scene.insts[i].tree_nodes, scene.insts[i].tree_kids, scene.insts[i].tree_tris,
                                 scene.insts[i].tree_root, scene.insts[i].cones, o_obj, d_obj, t_max)
        if occ < 0:
            if mesh_first_hit(scene.insts[i], o_obj, d_obj, t_max).index >= 0:
                occ = 1
        return occ > 0

    @wp.func
    def mesh_transmittance(scene: SceneData, o: wp.vec3, d: wp.vec3, t_max: float, time: float) -> wp.vec3:
        T = wp.vec3(1.0, 1.0, 1.0)
        inv_d = wp.cw_div(wp.vec3(1.0, 1.0, 1.0), d)
        for i in range(scene.n_inst):
            if not ray_box(o, inv_d, scene.insts[i].lo, scene.insts[i].hi, 0.0, t_max):
                continue
            pose = instance_pose(scene, i, time)
            o_obj = to_object(pose, o)
            d_obj = dir_to_object(pose, d)
            kt = crossing(scene, scene.insts[i].mat)
            if wp.max(kt) <= 0.0:
                if opaque_occluded(scene, i, o_obj, d_obj, t_max):
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
                    q = mesh_first_hit(scene.insts[i], o_cur, d_obj, t_max - t0)
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
    def transmittance(scene: SceneData, o: wp.vec3, d: wp.vec3, t_max: float, time: float, own_rect: int) -> wp.vec3:
        """Fraction of light arriving along the shadow ray (o, d) over (0, t_max): 0 when an
        opaque surface blocks it; transparent surfaces multiply it by their kt per crossing.
        Rectangle ``own_rect`` (-1: none) is not tested: the ray ends short of a point of it, an
        area light's, and a line meets a rectangle's plane once (a point in that plane is no
        light's: a flat light reaches only what lies in front of it)."""
        T = wp.vec3(1.0, 1.0, 1.0)
        use_bvh = scene.bvh_root >= 0
        if not use_bvh:
            for i in range(scene.n_spheres):
                T = wp.cw_mul(T, sphere_crossings(scene, o, d, t_max, time, i))
                if wp.max(T) <= 0.0:
                    return wp.vec3(0.0, 0.0, 0.0)
        for i in range(scene.n_planes):
            if intersect_plane(o, d, scene.planes[i].p, scene.planes[i].n, 0.0, t_max) >= 0.0:
                T = wp.cw_mul(T, crossing(scene, scene.planes[i].mat))
                if wp.max(T) <= 0.0:
                    return wp.vec3(0.0, 0.0, 0.0)
        if use_bvh:
            # every box the segment (0, t_max) passes through, in any order
            inv_d = safe_inverse(d)
            refs = StackRefs()
            refs[0] = scene.bvh_root
            sp = int(1)
            while sp > 0:
                sp -= 1
                ref = refs[sp]
                if ref >= 0:
                    nd = scene.bvh_nodes[ref]
                    s0 = slab(o, inv_d, nd.lo0, nd.hi0)
                    s1 = slab(o, inv_d, nd.lo1, nd.hi1)
                    if s0[0] <= s0[1] and s0[1] >= 0.0 and s0[0] < t_max:
                        refs[sp] = nd.c0
                        sp += 1
                    if s1[0] <= s1[1] and s1[1] >= 0.0 and s1[0] < t_max:
                        refs[sp] = nd.c1
                        sp += 1
                    continue
                j = -ref - 1
                k = scene.bvh_prims[j][0]
                i = scene.bvh_prims[j][1]
                if k == KIND_SPHERE:
                    T = wp.cw_mul(T, sphere_crossings(scene, o, d, t_max, time, i))
                elif k >= KIND_BOX:
                    if wp.static(F.solids):
                        T = wp.cw_mul(T, solid_crossings(scene, o, d, wp.cw_div(wp.vec3(1.0, 1.0, 1.0), d), t_max,
                                                         time, k, i))
                elif k == KIND_RECT and i == own_rect:
                    continue
                elif bounded_hit(scene, o, d, 0.0, t_max, time, k, i) >= 0.0:
                    T = wp.cw_mul(T, crossing(scene, bounded_mat(scene, k, i)))
                if wp.max(T) <= 0.0:
                    return wp.vec3(0.0, 0.0, 0.0)
        else:
            for i in range(scene.n_rects):
                if i == own_rect:  # (the light's own)
                    continue
                if intersect_rect(o, d, scene.rects[i].c, scene.rects[i].e1, scene.rects[i].e2, 0.0, t_max) >= 0.0:
                    T = wp.cw_mul(T, crossing(scene, scene.rects[i].mat))
                    if wp.max(T) <= 0.0:
                        return wp.vec3(0.0, 0.0, 0.0)
            for i in range(scene.n_disks):
                if intersect_disk(o, d, scene.disks[i].c, scene.disks[i].n, scene.disks[i].r, 0.0, t_max) >= 0.0:
                    T = wp.cw_mul(T, crossing(scene, scene.disks[i].mat))
                    if wp.max(T) <= 0.0:
                        return wp.vec3(0.0, 0.0, 0.0)
            if wp.static(F.solids):
                inv_d = wp.cw_div(wp.vec3(1.0, 1.0, 1.0), d)
                for k in range(KIND_BOX, KIND_CYLINDER + 1):
                    for i in range(solid_count(scene, k)):
                        T = wp.cw_mul(T, solid_crossings(scene, o, d, inv_d, t_max, time, k, i))
                        if wp.max(T) <= 0.0:
                            return wp.vec3(0.0, 0.0, 0.0)
        if wp.static(F.meshes):
            if scene.n_inst > 0:
                T = wp.cw_mul(T, mesh_transmittance(scene, o, d, t_max, time))
        return T

    @wp.func(inline=True)
    def sphere_packet(scene: SceneData, i: int, lanes: int, ox: PacketF, oy: PacketF, oz: PacketF, dx: PacketF,
                      dy: PacketF, dz: PacketF, t_max: PacketF, time: PacketF) -> int:
        """``sphere_hits_packet`` for sphere i (its centre at each lane's time)."""
        c0 = scene.spheres[i].c0
        if wp.static(F.motion):
            return sphere_hits_packet(c0, scene.spheres[i].c1 - c0, 1, scene.spheres[i].r, lanes, ox, oy, oz, dx, dy,
                                      dz, t_max, time)
        return sphere_hits_packet(c0, c0, 0, scene.spheres[i].r, lanes, ox, oy, oz, dx, dy, dz, t_max, time)

    @wp.func(inline=True)
    def instance_occluded(scene: SceneData, i: int, o: wp.vec3, d: wp.vec3, t_max: float, time: float) -> bool:
        """Whether a triangle of opaque instance i blocks the shadow ray (o, d) over (0, t_max) whose
        box test passed (``mesh_transmittance``'s opaque branch)."""
        pose = instance_pose(scene, i, time)
        return opaque_occluded(scene, i, to_object(pose, o), dir_to_object(pose, d), t_max)

    @wp.func(inline=False)
    def mesh_lanes_occluded(inst: InstRec, n: int, lanes: int, ox: PacketF, oy: PacketF, oz: PacketF, dx: PacketF,
                            dy: PacketF, dz: PacketF, t_max: PacketF, time: PacketF) -> int:
        """The lanes (of the bit mask ``lanes``, all below n, each in the instance's box) whose shadow
        ray an opaque mesh instance blocks, their tree traversals together
        (``accel.mesh_tree_occluded_packet``), each lane's interior balls first: the answers
        ``instance_occluded`` gives each alone. -1 where the lanes are too few to be worth it
        (SHADOW_PACKET_MIN) or the packet cannot answer: the caller asks each lane alone. Out of
        line: kernels whose meshes are small never call it, and do not carry its code inline."""
        count = int(0)
        for k in range(n):
            count += (lanes >> k) & 1
        if count < SHADOW_PACKET_MIN:
            return -1
        pox = PacketF()
        poy = PacketF()
        poz = PacketF()
        pdx = PacketF()
        pdy = PacketF()
        pdz = PacketF()
        blocked = int(0)
        rest = int(0)
        for k in range(n):
            if (lanes >> k) & 1 != 0:
                pose = inst_pose(inst, time[k])
                o_obj = to_object(pose, wp.vec3(ox[k], oy[k], oz[k]))
                d_obj = dir_to_object(pose, wp.vec3(dx[k], dy[k], dz[k]))
                ball = int(0)
                if inst.n_balls > 0:
                    ball = mesh_balls_hit(inst.balls, inst.n_balls, o_obj, d_obj, t_max[k])
                if ball != 0:
                    blocked = blocked | (1 << k)
                else:
                    rest = rest | (1 << k)
                    pox[k] = o_obj[0]
                    poy[k] = o_obj[1]
                    poz[k] = o_obj[2]
                    pdx[k] = d_obj[0]
                    pdy[k] = d_obj[1]
                    pdz[k] = d_obj[2]
        if rest == 0:
            return blocked
        r = mesh_tree_occluded_packet(inst.wide, inst.tree_tris, inst.wide_cones, pox, poy, poz, pdx, pdy, pdz, t_max,
                                      rest)
        if r < 0:
            return -1
        return blocked | r

    @wp.func
    def lanes_occluded(scene: SceneData, n: int, lanes: int, ox: PacketF, oy: PacketF, oz: PacketF, dx: PacketF,
                       dy: PacketF, dz: PacketF, t_max: PacketF, time: PacketF, own_rect: int) -> int:
        """``occluded_packet``'s answer with shadow_packets switched off (``warprt.fast``): each
        lane's shadow ray alone through ``transmittance``. Compiled in only then: the same code
        behind a run-time test, even out of line, slowed the packets' kernels with everything on."""
        blocked = int(0)
        for k in range(n):
            if (lanes >> k) & 1 != 0:
                T = transmittance(scene, wp.vec3(ox[k], oy[k], oz[k]), wp.vec3(dx[k], dy[k], dz[k]), t_max[k], time[k],
                                  own_rect)
                if wp.max(T) <= 0.0:
                    blocked = (1 << k) | blocked
        return blocked

    @wp.func(inline=True)
    def leaf_blocks(scene: SceneData, n: int, kk: int, ii: int, lanes: int, ox: PacketF, oy: PacketF, oz: PacketF,
                    dx: PacketF, dy: PacketF, dz: PacketF, t_max: PacketF, time: PacketF, own_rect: int) -> int:
        """The lanes (of the bit mask ``lanes``, all below n) whose shadow ray (o, d) over (0, t_max)
        the analytic BVH's primitive (kind kk, row ii) blocks (rectangle ``own_rect`` never)."""
        hit = int(0)
        if kk == KIND_SPHERE:
            hit = sphere_packet(scene, ii, lanes, ox, oy, oz, dx, dy, dz, t_max, time)
        elif kk == KIND_RECT:
            if ii != own_rect:
                hit = rect_hits_packet(scene.rects[ii].c, scene.rects[ii].e1, scene.rects[ii].e2, lanes, ox, oy, oz, dx,
                                       dy, dz, t_max)
        else:
            for k in range(n):
                if (lanes >> k) & 1 != 0:
                    o = wp.vec3(ox[k], oy[k], oz[k])
                    d = wp.vec3(dx[k], dy[k], dz[k])
                    if kk >= KIND_BOX:
                        if wp.static(F.solids):
                            T = solid_crossings(scene, o, d, wp.cw_div(wp.vec3(1.0, 1.0, 1.0), d), t_max[k], time[k], kk,
                                                ii)
                            if wp.max(T) <= 0.0:
                                hit = hit | (1 << k)
                    elif bounded_hit(scene, o, d, 0.0, t_max[k], time[k], kk, ii) >= 0.0:
                        hit = hit | (1 << k)
        return hit

    @wp.func
    def occluded_packet(scene: SceneData, n: int, lanes: int, ox: PacketF, oy: PacketF, oz: PacketF, dx: PacketF,
                        dy: PacketF, dz: PacketF, t_max: PacketF, time: PacketF, skip: PacketI,
                        face: PacketI, own_rect: int, plight: int) -> int:
        """The lanes (of the bit mask ``lanes``, all below n) whose shadow ray (o, d) over (0, t_max)
        a surface blocks, in a kernel without transparent materials, where ``transmittance`` is 0
        or 1: the spheres (without the analytic BVH), planes and BVH for all lanes at once
        (``sphere_hits_packet``, ``plane_hits_packet``, ``packet_node``, ``rect_hits_packet``),
        the mesh instances' boxes for all lanes at once (``box_hits_packet``), then each lane in
        a box through its triangles. A lane's answer is its own: the tests are the scalar ones,
        and a node test looser than the scalar traversal's only adds leaves to test. A lane k with
        skip[k] = i + 1 leaves face and side face[k] (2 face + side) of instance i, which has
        escape horizons (``accel.escape_horizons``): where its ray passes them it cannot meet
        that instance's triangles, which are not tested for it (skip 0: none skipped). The rays
        end short of a point on rectangle ``own_rect`` (an area light's; -1: none), which they
        meet nowhere else and which is not tested. With ``plight`` >= 0 they go to point light
        ``plight``: where it has a light buffer (``accel.light_buffer``), the lanes within its
        reach test the primitives of their cell instead of walking the BVH, the lanes of one cell
        together; the answers are the walk's. With shadow_packets switched off (``warprt.fast``,
        when warprt is imported) each lane's answer is ``transmittance``'s, the lane alone."""
        if wp.static(SHADOW_LANES_ALONE):
            return lanes_occluded(scene, n, lanes, ox, oy, oz, dx, dy, dz, t_max, time, own_rect)
        blocked = int(0)
        left = lanes
        use_bvh = scene.bvh_root >= 0
        if not use_bvh:
            for i in range(scene.n_spheres):
                if left == 0:
                    return blocked
                blocked = blocked | sphere_packet(scene, i, left, ox, oy, oz, dx, dy, dz, t_max, time)
                left = lanes & ~blocked
        for i in range(scene.n_planes):
            if left == 0:
                return blocked
            blocked = blocked | plane_hits_packet(scene.planes[i].p, scene.planes[i].n, left, ox, oy, oz, dx, dy, dz,
                                                  t_max)
            left = lanes & ~blocked
        walk = int(0)  # the lanes that walk the BVH
        if use_bvh and left != 0:
            walk = left
            if plight >= 0:
                rec = scene.plights[plight]
                if rec.lb_cell0 >= 0:
                    # the light buffer: each lane's cell's primitives (accel.light_buffer)
                    cells = PacketI()
                    todo = light_cells(rec.pos, rec.lb_reach, rec.lb_res, rec.lb_cell0, left, ox, oy, oz, cells)
                    walk = left & ~todo
                    while todo != 0:
                        c = int(-1)
                        same = int(0)
                        for k in range(n):
                            if (todo >> k) & 1 != 0:
                                if c < 0:
                                    c = cells[k]
                                if cells[k] == c:
                                    same = same | (1 << k)
                        todo = todo & ~same
                        e = scene.lb_cells[c]
                        end = scene.lb_cells[c + 1]
                        while e < end and same != 0:
                            j = scene.lb_items[e]
                            e += 1
                            hit = leaf_blocks(scene, n, scene.bvh_prims[j][0], scene.bvh_prims[j][1], same, ox, oy, oz,
                                              dx, dy, dz, t_max, time, own_rect)
                            blocked = blocked | hit
                            same = same & ~hit
                    left = lanes & ~blocked
        if walk != 0:
            # the BVH for the lanes still lit together: a node opened while any of them meets a
            # child's box (with a blocked lane's length below every entry)
            inv_x = PacketF()
            inv_y = PacketF()
            inv_z = PacketF()
            reach = PacketF()
            for k in range(PACKET):
                inv = safe_inverse(wp.vec3(dx[k], dy[k], dz[k]))
                inv_x[k] = inv[0]
                inv_y[k] = inv[1]
                inv_z[k] = inv[2]
                reach[k] = wp.where((walk >> k) & 1 != 0, t_max[k], -PACKET_MISS)
            refs = StackRefs()
            refs[0] = scene.bvh_root
            sp = int(1)
            while sp > 0:
                sp -= 1
                ref = refs[sp]
                if ref >= 0:
                    ee = packet_node(scene.bvh_nodes, ref, ox, oy, oz, inv_x, inv_y, inv_z, reach)
                    if ee[0] < PACKET_MISS:
                        refs[sp] = scene.bvh_nodes[ref].c0
                        sp += 1
                    if ee[1] < PACKET_MISS:
                        refs[sp] = scene.bvh_nodes[ref].c1
                        sp += 1
                    continue
                j = -ref - 1
                hit = leaf_blocks(scene, n, scene.bvh_prims[j][0], scene.bvh_prims[j][1], walk, ox, oy, oz, dx, dy, dz,
                                  t_max, time, own_rect)
                if hit != 0:
                    blocked = blocked | hit
                    walk = walk & ~hit
                    if walk == 0:
                        break
                    for k in range(PACKET):
                        reach[k] = wp.where((walk >> k) & 1 != 0, reach[k], -PACKET_MISS)
            left = lanes & ~blocked
        if left == 0:
            return blocked
        if not use_bvh:
            # without the BVH: the rectangles for all lanes at once, the disks and solids lane by lane
            for i in range(scene.n_rects):
                if i == own_rect:  # (the light's own: never tested)
                    continue
                blocked = blocked | rect_hits_packet(scene.rects[i].c, scene.rects[i].e1, scene.rects[i].e2, left, ox,
                                                     oy, oz, dx, dy, dz, t_max)
                left = lanes & ~blocked
                if left == 0:
                    return blocked
            solids = False
            if wp.static(F.solids):
                solids = True
            if scene.n_disks > 0 or solids:
                for k in range(n):
                    if (left >> k) & 1 != 0:
                        o = wp.vec3(ox[k], oy[k], oz[k])
                        d = wp.vec3(dx[k], dy[k], dz[k])
                        for i in range(scene.n_disks):
                            if intersect_disk(o, d, scene.disks[i].c, scene.disks[i].n, scene.disks[i].r, 0.0,
                                              t_max[k]) >= 0.0:
                                blocked = blocked | (1 << k)
                        if wp.static(F.solids):
                            inv_d = wp.cw_div(wp.vec3(1.0, 1.0, 1.0), d)
                            for kk in range(KIND_BOX, KIND_CYLINDER + 1):
                                for i in range(solid_count(scene, kk)):
                                    T = solid_crossings(scene, o, d, inv_d, t_max[k], time[k], kk, i)
                                    if wp.max(T) <= 0.0:
                                        blocked = blocked | (1 << k)
                left = lanes & ~blocked
                if left == 0:
                    return blocked
        if wp.static(F.meshes):
            # each instance's box for all lanes at once, then each lane in it through the triangles
            for i in range(scene.n_inst):
                # (a lane whose ray leaves this instance's surface above the face's escape
                # horizons skips it: skip = i + 1)
                own = int(0)
                for k in range(n):
                    if skip[k] == i + 1:
                        if (left >> k) & 1 != 0:
                            d_obj = dir_to_object(instance_pose(scene, i, time[k]), wp.vec3(dx[k], dy[k], dz[k]))
                            if horizon_escapes(scene.insts[i].escape, scene.insts[i].frames, face[k], d_obj) != 0:
                                own = own | (1 << k)
                inside = box_hits_packet(scene.insts[i].lo, scene.insts[i].hi, left & ~own, ox, oy, oz, dx, dy, dz, 0.0,
                                         t_max)
                if inside == 0:
                    continue
                # a large mesh's lanes through its tree together (mesh_lanes_occluded), else, or
                # where that cannot answer, one by one
                done = False
                if scene.insts[i].shadow_packets != 0:
                    r = mesh_lanes_occluded(scene.insts[i], n, inside, ox, oy, oz, dx, dy, dz, t_max, time)
                    if r >= 0:
                        blocked = blocked | r
                        done = True
                if not done:
                    for k in range(n):
                        if (inside >> k) & 1 != 0:
                            if instance_occluded(scene, i, wp.vec3(ox[k], oy[k], oz[k]), wp.vec3(dx[k], dy[k], dz[k]),
                                                 t_max[k], time[k]):
                                blocked = blocked | (1 << k)
                left = lanes & ~blocked
                if left == 0:
                    return blocked
        return blocked

    @wp.func(inline=True)
    def shadow(scene: SceneData, origin: wp.vec3, target: wp.vec3, stop_short: float, time: float,
               own_rect: int) -> wp.vec3:
        """Transmittance from ``origin`` to ``target``, ending ``stop_short`` before the target
        (so the light's own surface never occludes it; a rectangle light's, ``own_rect``, is not
        tested at all: ``transmittance``)."""
        to_t = target - origin
        dist = wp.length(to_t)
        if dist <= stop_short:
            return wp.vec3(1.0, 1.0, 1.0)
        return transmittance(scene, origin, to_t / dist, dist - stop_short, time, own_rect)

    return SimpleNamespace(closest_hit=closest_hit, trace_packet=trace_packet, finish_hit=finish_hit,
                           mesh_packet=mesh_packet, finish_packet_lane=finish_packet_lane,
                           transmittance=transmittance, shadow=shadow, occluded_packet=occluded_packet,
                           sphere_center=sphere_center, instance_pose=instance_pose, solid_pose=solid_pose,
                           solid_rec=solid_rec)
