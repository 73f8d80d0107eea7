"""The render megakernel, specialised per :class:`Features` value.

Per pixel sample (one thread takes a row of pixels on the CPU, one pixel on CUDA, and their
samples pixel by pixel; camera rays go 8 at a time as a packet, from the next pixels too where a
pixel has fewer samples left):

1. camera sample: film position, lens position and time from the sampler (dimensions
   ``DIM_FILM``, ``DIM_LENS``, ``DIM_TIME``; with Sobol points, drawn for a packet's lanes at
   once, ``sampling.sobol_packet``);
2. the camera ray goes on a fixed-size per-thread stack (``STACK_SIZE`` entries of
   ``RayEntry``: origin, direction, throughput, depth, dimension key);
3. loop until the stack is empty: pop; nearest hit (``trace``); add throughput × (emission, or
   ambient + direct light from ``lights``; without secondary rays, a packet's area-light
   samples are drawn for its shading points together, ``lights.area_lights_packet``); push the
   mirror / glossy reflection and the refraction (or, under total internal reflection, the
   extra reflection) with their weights, unless the depth limit or the throughput cutoff stops
   them;
4. the sample, sanitised, goes into the pixel's ``film`` sums; where the render asks for AOVs
   (``RenderParams.aovs``, a run-time mask), the camera ray's first hit goes into the pixel's
   AOV sums (``aov.make_aov_add``), sample by sample like the film's, and the pass that ends the
   render writes the AOVs (``aov.aov_store``).

A push onto a full stack drops that ray and counts it (``overflow`` per pixel), so overflow is
defined behaviour. With at most two children per hit, depth d needs at most d + 1 entries; the
stack holds 16, so scenes with ``max_depth`` <= 15 never overflow.

Code for features a scene does not use is removed at compile time with ``wp.static``; each
``Features`` value compiles one Warp module (``module="unique"``), cached on disk by Warp.
"""

from __future__ import annotations

from types import SimpleNamespace

import warp as wp

from . import _warp, kernels
from ._warp import build_once
from .aov import AovData, make_aov_sample
from .camera import MODEL_PINHOLE, camera_frame, camera_packet, camera_ray, lens_packet
from .fast import (
    FAST_CAMERA_PACKET_RAYS, FAST_COLUMN_BLOCKS, FAST_MESH_PACKETS, FAST_SHADING_PACKETS, FAST_SOBOL_PACKETS,
)
from .film import FilmData, claim_block, luminance, packet_samples, sanitize
from .geometry import spawn_origin
from .lights import LightPacket, ShadePacket, make_lights, map_samples
from .records import KIND_MESH, KIND_NONE, CameraData, Features, RenderParams, SceneData
from .sampling import (
    SAMPLER_SOBOL, frame_from_z, hash2, pixel_key, sample_1d_keyed, sample_2d_keyed, sobol_packet, square_to_cos_power,
)
from .shading import fresnel, mul_sat, reflect, refract
from .accel import PacketU, horizon_open, lane, lane_i
from .textures import make_textures
from .trace import MESH_PACKET_MIN, PACKET, PACKET_MIN, CameraPacket, Hit, MeshPacket, PacketF, PacketI, make_trace

STACK_SIZE = 16
DIM_FILM, DIM_LENS, DIM_TIME = 0, 1, 2  # dimension keys of the camera sample
ROOT_KEY = 0x51ED270B  # dimension key of the camera ray's path vertex
KEY_GLOSSY_REFLECT, KEY_FROSTED_REFRACT = 1, 2  # lobe samples at a vertex: hash2(vertex key, ...)
KEY_REFRACTED, KEY_REFLECTED = 101, 102  # child vertices: hash2(vertex key, ...)


@wp.struct
class CameraSample:
    o: wp.vec3
    d: wp.vec3
    time: float


@wp.struct
class RayEntry:
    o: wp.vec3
    d: wp.vec3
    w: wp.vec3  # throughput
    depth: int
    key: wp.uint32  # dimension key of the path vertex this ray will find


@wp.func
def start_empty(film: FilmData, pixel: int):
    """The sums of a pixel without samples in the first pass (an adaptive count of 0)."""
    film.accum[pixel] = wp.vec3(0.0, 0.0, 0.0)
    film.accum_sq[pixel] = 0.0
    film.rays[pixel] = 0
    film.overflow[pixel] = 0


@wp.func(inline=True)
def lobe(u: wp.vec2, axis: wp.vec3, exponent: float) -> wp.vec3:
    return frame_from_z(axis, square_to_cos_power(u, exponent))


@wp.struct
class Facing:
    ng: wp.vec3
    n: wp.vec3


@wp.func(inline=True)
def toward_viewer(ng_in: wp.vec3, ns_in: wp.vec3, d: wp.vec3) -> Facing:
    """A hit's geometric and shading normals turned towards the viewer of a ray along d; a shading
    normal that still faces away falls back to the geometric one."""
    f = Facing()
    f.ng = ng_in
    f.n = ns_in
    if not (wp.dot(d, ng_in) < 0.0):
        f.ng = -ng_in
        f.n = -ns_in
    if wp.dot(f.n, d) > 0.0:
        f.n = f.ng  # a shading normal facing away from the viewer: fall back
    return f


def packets_for(device) -> bool:
    """Whether a device's kernels take camera rays in packets: on the CPU, not on CUDA.

    With packets a thread takes up to ``PACKET`` (8) camera samples at once (a pixel's, or the
    next pixels' too); they go through the analytic BVH and the meshes together where the scene
    has them (shape by shape otherwise), and with Sobol points and area lights their samples are
    drawn and shaded together (``sampling.sobol_packet``, ``lights.area_lights_packet``...), as
    clang vectors on the CPU. On CUDA, where a thread renders one pixel and the packet functions
    run lane by lane, the packet's per-thread arrays only cost, in time a sample and in compile,
    for the same images bit for bit (``python -m benchmarks.gpu --timing --packets on`` against
    ``--packets off`` measures it)."""
    return bool(device.is_cpu)


@build_once
def kernels_for(F: Features, packets: bool) -> SimpleNamespace:
    """The render kernel for a feature set, with camera rays in packets or one by one
    (:func:`packets_for`; the images are the same bit for bit). Built once per process and
    argument pair; ``kernels_for.built()`` lists the pairs built so far."""
    trace = make_trace(F)
    lights = make_lights(F)
    closest_hit = trace.closest_hit
    trace_packet = trace.trace_packet
    finish_hit = trace.finish_hit
    mesh_packet = trace.mesh_packet
    finish_packet_lane = trace.finish_packet_lane
    aov_sample = make_aov_sample(F)
    textured = make_textures(F)
    point_lights_direct = lights.point_lights_direct
    area_lights_direct = lights.area_lights_direct
    area_lights_packet = lights.area_lights_packet
    point_lights_packet = lights.point_lights_packet
    # a packet's shading points lit together (lights.point_lights_packet, lights.area_lights_packet):
    # with camera packets and no secondary rays (the camera ray is the only path vertex)
    shade_packets = packets and not F.secondary

    @wp.func(inline=True)
    def camera_from(cam: CameraData, params: RenderParams, uf: wp.vec2, ut: float, ul_in: wp.vec2, px: int,
                    py: int) -> CameraSample:
        """The camera ray of raster pixel (px, py) from its film position uf, time sample ut and
        lens position ul_in (the last two read only where the camera moves, or has a lens)."""
        time = cam.t_open
        if wp.static(F.motion):
            if params.moving != 0:
                # a rolling shutter exposes row py over [open, close] + py · line delay
                time = cam.t_open + cam.line_delay * float(py)
                if cam.t_close > cam.t_open:
                    time = time + (cam.t_close - cam.t_open) * ut
        ul = wp.vec2(0.5, 0.5)
        if wp.static(F.lens):
            if cam.lens_radius > 0.0:
                ul = ul_in
        ray = camera_ray(cam, float(px) + uf[0], float(py) + uf[1], ul, time)
        cs = CameraSample()
        cs.o = ray.o
        cs.d = ray.d
        cs.time = time
        return cs

    @wp.func(inline=True)
    def camera_sample(cam: CameraData, params: RenderParams, pkey: wp.uint32, s: int, px: int, py: int) -> CameraSample:
        """Sample s's camera ray of raster pixel (px, py): film position, lens position and time
        from the sampler (dimensions DIM_FILM, DIM_LENS, DIM_TIME)."""
        uf = sample_2d_keyed(params.sampler, pkey, s, params.spp, wp.uint32(DIM_FILM))
        ut = float(0.0)
        if wp.static(F.motion):
            if params.moving != 0 and cam.t_close > cam.t_open:
                ut = sample_1d_keyed(params.sampler, pkey, s, params.spp, wp.uint32(DIM_TIME))
        ul = wp.vec2(0.5, 0.5)
        if wp.static(F.lens):
            if cam.lens_radius > 0.0:
                ul = sample_2d_keyed(params.sampler, pkey, s, params.spp, wp.uint32(DIM_LENS))
        return camera_from(cam, params, uf, ut, ul, px, py)

    @wp.func(inline=True)
    def render_pixels(scene: SceneData, cam: CameraData, params: RenderParams, px0: int, py: int, pixel0: int,
                      n_pix: int, s0: int, s1: int, film: FilmData, sh: int, aov: AovData):
        """Samples [s0, s1) of the ``n_pix`` raster pixels of ``cam`` that fill 2^sh rows from
        (px0, py) column by column: pixel j is (px0 + (j >> sh), py + (j & (2^sh - 1))), added to
        film entry pixel0 + (j & (2^sh - 1)) · width + (j >> sh) (also the pixel's noise key: unique
        over everything one film holds; sh 0: a row). The samples are taken pixel by pixel, each
        pixel's in order, so its sums are the same whatever the grouping; with camera packets a
        packet takes PACKET samples in that order, from the next pixels too when a pixel has fewer
        left (an adaptive render's pilot and later passes, low spp), so that packets stay full: a
        column's pixels lie together, so a packet over several pixels covers a patch of the image
        (2 × 4 pixels at one sample a pixel in 4 rows) rather than a strip of a row. With AOVs
        (``params.aovs``), each camera sample's first hit goes into the pixel's AOV sums in the
        same order, held and stored with the film's sums."""
        rm = (1 << sh) - 1
        # the pixel whose sums are held (-1: none yet); the first pass starts the sums (the film
        # needs no zeroing), later passes add to them; a pixel without samples in a later pass
        # (adaptive sampling's count reached) is not touched
        cur = int(-1)
        pixel = int(0)
        pkey = wp.uint32(0)
        acc = wp.vec3(0.0, 0.0, 0.0)
        acc_sq = float(0.0)
        rays = int(0)
        dropped = int(0)
        # the AOVs asked for (0: none): each camera sample goes into its pixel's AOV sums (in
        # sample order, as into the film), and the pass that reaches the render's planned samples
        # writes the AOVs themselves (aov.make_aov_sample)
        aovs = params.aovs
        a_final = s1 >= aov.end
        if wp.static(F.secondary):
            stack = wp.zeros(shape=STACK_SIZE, dtype=RayEntry)
        # the camera rays of PACKET_MIN to PACKET samples go together, through the analytic BVH and
        # the meshes where the scene has them (trace_packet, mesh_packet: the same hits as one by
        # one, fewer node visits per ray)
        bvh = scene.bvh_root >= 0
        meshes = False
        if wp.static(F.meshes):
            meshes = scene.n_inst > 0
        # the gathering cursor: sample g_s of pixel g_j, whose samples end at g_end (the limit:
        # adaptive sampling's count for the pixel)
        g_j = int(0)
        g_s = s0
        g_end = wp.min(s1, film.limit[pixel0])
        g_key = pixel_key(params.seed, pixel0)
        lane_j = PacketI()
        lane_s = PacketI()
        lane_key = PacketU()
        # the lanes' pixel, first sample and key: p_j, one_s + k and p_key, or with ``mixed`` (a
        # packet over several pixels) lane_j, lane_s and lane_key
        p_j = int(0)
        p_key = wp.uint32(0)
        one_s = int(0)
        mixed = bool(False)
        # a camera at rest: its frame once, a packet's 8 rays at once (camera_packet for a pinhole,
        # lens_packet for a thin lens)
        # (the packets make the pinhole model's rays: the other models' go one by one)
        still = cam.model == MODEL_PINHOLE
        if wp.static(F.motion):
            if params.moving != 0 and (cam.t_close > cam.t_open or cam.line_delay > 0.0):
                still = False
        pinhole = still and cam.lens_radius <= 0.0
        lensed = False
        if wp.static(F.lens):
            lensed = still and cam.lens_radius > 0.0
        frame = camera_frame(cam, cam.t_open)
        while g_j < n_pix:
            lanes = int(0)
            mixed = bool(False)
            while g_j < n_pix:
                if g_s >= g_end:
                    # the pixel's samples are all taken: on to the next
                    if g_end <= s0 and s0 == 0:
                        start_empty(film, pixel0 + (g_j & rm) * cam.width + (g_j >> sh))
                    g_j += 1
                    g_s = s0
                    if g_j < n_pix:
                        g_pix = pixel0 + (g_j & rm) * cam.width + (g_j >> sh)
                        g_end = wp.min(s1, film.limit[g_pix])
                        g_key = pixel_key(params.seed, g_pix)
                    continue
                if lanes == 0:
                    p_j = g_j
                    p_key = g_key
                    one_s = g_s
                    if wp.static(not packets):
                        lanes = g_end - g_s  # one by one (packets_for): the pixel's samples one at a time
                        g_s = g_end
                        break
                    if g_end - g_s >= PACKET:
                        # a whole packet from this pixel
                        lanes = PACKET
                        g_s += PACKET
                        break
                    mixed = True  # up to PACKET samples, from the next pixels too
                lane_j[lanes] = g_j
                lane_s[lanes] = g_s
                lane_key[lanes] = g_key
                lanes += 1
                g_s += 1
                if lanes == PACKET:
                    break
            if lanes == 0:
                break
            packed = False
            keys = PacketU()
            idx = PacketI()
            pk = CameraPacket()
            mp = MeshPacket()
            mesh_packed = False
            if wp.static(packets):
                packed = lanes >= PACKET_MIN  # (without trees, for the lanes' vector sampling)
                if wp.static(F.meshes):
                    mesh_packed = meshes and lanes >= MESH_PACKET_MIN
                    packed = packed or mesh_packed
                    mesh_packed = mesh_packed and (scene.fast_off & FAST_MESH_PACKETS) == 0  # (warprt.fast)
                # with Sobol points, a packet's camera samples drawn together (sampling.sobol_packet;
                # lanes that go alone draw theirs alone)
                sobol = packed and params.sampler == SAMPLER_SOBOL and (scene.fast_off & FAST_SOBOL_PACKETS) == 0
                # each lane's pixel key and sample index, for the Sobol points and the packet's shading
                lane_keys = sobol
                if wp.static(shade_packets):
                    lane_keys = sobol or (packed and scene.n_alights > 0)
                if lane_keys:
                    if mixed:
                        keys = lane_key
                        idx = lane_s
                    else:
                        for k in range(lanes):
                            keys[k] = p_key
                            idx[k] = one_s + k
                ufx = PacketF()
                ufy = PacketF()
                utx = PacketF()
                uty = PacketF()
                ulx = PacketF()
                uly = PacketF()
                if sobol:
                    sobol_packet(keys, idx, wp.uint32(DIM_FILM), ufx, ufy)
                    if wp.static(F.motion):
                        if params.moving != 0 and cam.t_close > cam.t_open:
                            sobol_packet(keys, idx, wp.uint32(DIM_TIME), utx, uty)
                    if wp.static(F.lens):
                        if cam.lens_radius > 0.0:
                            sobol_packet(keys, idx, wp.uint32(DIM_LENS), ulx, uly)
                dxp = PacketF()
                dyp = PacketF()
                dzp = PacketF()
                oxp = PacketF()
                oyp = PacketF()
                ozp = PacketF()
                cam_packet = sobol and (pinhole or lensed) and (scene.fast_off & FAST_CAMERA_PACKET_RAYS) == 0
                if cam_packet:
                    fxp = PacketF()
                    fyp = PacketF()
                    for k in range(lanes):
                        jk = p_j
                        if mixed:
                            jk = lane_j[k]
                        fxp[k] = float(px0 + (jk >> sh)) + ufx[k]
                        fyp[k] = float(py + (jk & rm)) + ufy[k]
                    if pinhole:
                        camera_packet(cam.right, cam.top, cam.x_off, cam.y_off, cam.dist, cam.width, cam.height,
                                      frame.u, frame.v, frame.w, fxp, fyp, dxp, dyp, dzp)
                    else:
                        lens_packet(cam.right, cam.top, cam.x_off, cam.y_off, cam.dist, cam.focus, cam.lens_radius,
                                    cam.width, cam.height,
                                    frame.eye, frame.u, frame.v, frame.w, fxp, fyp, ulx, uly, oxp, oyp, ozp, dxp, dyp,
                                    dzp)
                for k in range(lanes):
                    jk = p_j
                    sk = one_s + k
                    kk = p_key
                    if mixed:
                        jk = lane_j[k]
                        sk = lane_s[k]
                        kk = lane_key[k]
                    # (the packet's own rays where the camera packet made them; the origin, direction
                    # and time as plain values, not a struct chosen between the branches, whose
                    # field-by-field selects cost time every sample)
                    co = frame.eye
                    cd = wp.vec3(dxp[k], dyp[k], dzp[k])
                    ct = cam.t_open
                    if cam_packet:
                        if lensed:
                            co = wp.vec3(oxp[k], oyp[k], ozp[k])
                    else:
                        cs = CameraSample()
                        if sobol:
                            cs = camera_from(cam, params, wp.vec2(ufx[k], ufy[k]), utx[k], wp.vec2(ulx[k], uly[k]),
                                             px0 + (jk >> sh), py + (jk & rm))
                        else:
                            cs = camera_sample(cam, params, kk, sk, px0 + (jk >> sh), py + (jk & rm))
                        co = cs.o
                        cd = cs.d
                        ct = cs.time
                    pk.ox[k] = co[0]
                    pk.oy[k] = co[1]
                    pk.oz[k] = co[2]
                    pk.dx[k] = cd[0]
                    pk.dy[k] = cd[1]
                    pk.dz[k] = cd[2]
                    pk.time[k] = ct
                    pk.best[k] = params.t_max
                    if cam.model != MODEL_PINHOLE:
                        if wp.length_sq(cd) == 0.0:
                            pk.best[k] = -1.0  # no ray (camera.model_ray): a miss, as an unused lane
                    pk.kind[k] = KIND_NONE
                    pk.index[k] = -1
                if packed:
                    for k in range(lanes, PACKET):
                        pk.best[k] = -1.0  # an unused lane: no box is entered for it
                    hits = trace_packet(scene, pk, params.t_min, lanes)
                    pk.best = hits.best
                    pk.kind = hits.kind
                    pk.index = hits.index
                    if wp.static(F.meshes):
                        if mesh_packed:
                            mp = mesh_packet(scene, pk, params.t_min, lanes)
            # with area lights, a packet's camera rays are shaded together: each lane's hit and
            # point lights first (the light its hit emits, or the background, for a lane that
            # shades nothing), then the area lights' draws for all lanes at once; the lanes then
            # go pixel by pixel as below, each with the sample it would have had alone
            shaded = False
            lit = int(0)  # the lanes with a shading point
            sp_ = ShadePacket()
            skip_ = PacketI()  # lanes on a mesh face with escape horizons: that instance + 1
            face_ = PacketI()  # and their face and side (2 face + side: accel.escape_horizons)
            lp = LightPacket()
            lr = PacketF()  # each lane's sample (rgb), or its light without the area lights
            lg = PacketF()
            lb = PacketF()
            l_rays = PacketI()
            if wp.static(shade_packets):
                shaded = packed and (scene.fast_off & FAST_SHADING_PACKETS) == 0  # (warprt.fast)
                if shaded:
                    sp_.key = keys
                    sp_.sample = idx
                    sp_.time = pk.time
                    if wp.static(F.area_lights):
                        if scene.split_tile > 0:  # each lane's pixel's count for "auto" lights
                            for k in range(lanes):
                                jj = p_j
                                if mixed:
                                    jj = lane_j[k]
                                sp_.ns[k] = map_samples(scene, px0 + (jj >> sh), py + (jj & rm))
                    for k in range(lanes):
                        # (the lanes read in place: accel.lane)
                        o = wp.vec3(lane(pk.ox, k), lane(pk.oy, k), lane(pk.oz, k))
                        d = wp.vec3(lane(pk.dx, k), lane(pk.dy, k), lane(pk.dz, k))
                        h = Hit()
                        if mesh_packed:
                            h = finish_packet_lane(scene, o, d, lane(pk.time, k), lane(pk.best, k), lane_i(pk.kind, k),
                                                   lane_i(pk.index, k), mp, k)
                        else:
                            h = finish_hit(scene, o, d, params.t_min, lane(pk.time, k), lane(pk.best, k),
                                           lane_i(pk.kind, k), lane_i(pk.index, k))
                        l_rays[k] = 1
                        if aovs != 0:
                            jj = p_j
                            sj = one_s + k
                            if mixed:
                                jj = lane_j[k]
                                sj = lane_s[k]
                            aov_sample(scene, cam, aov, aovs, pixel0 + (jj & rm) * cam.width + (jj >> sh), sj, s1, a_final,
                                       h, d, lane(pk.time, k))
                        L = wp.vec3(0.0, 0.0, 0.0)
                        if h.kind == KIND_NONE:
                            L += mul_sat(wp.vec3(1.0, 1.0, 1.0), scene.background)
                        else:
                            front = wp.dot(d, h.ng) < 0.0
                            fc = toward_viewer(h.ng, h.ns, d)
                            ng = fc.ng
                            n = fc.n
                            le = scene.mats[h.mat].emit
                            if wp.max(le) > 0.0:
                                if front:
                                    L += mul_sat(wp.vec3(1.0, 1.0, 1.0), le)
                            else:
                                v = -d
                                ka = scene.mats[h.mat].ka
                                kd = scene.mats[h.mat].kd
                                ks = scene.mats[h.mat].ks
                                if wp.static(F.textures):
                                    tm = textured(scene, h, lane(pk.time, k))
                                    ka = tm.ka
                                    kd = tm.kd
                                    ks = tm.ks
                                local = mul_sat(ka, scene.ambient)
                                origin = spawn_origin(h.p, ng, h.mag, 1.0)
                                L = local  # the local light so far (the lights are added below)
                                lit = lit | (1 << k)
                                if wp.static(F.meshes):
                                    # on a mesh face with escape horizons towards the viewer's
                                    # side, its shadow rays above them skip that mesh
                                    # (accel.escape_horizons, trace.occluded_packet)
                                    if h.kind == KIND_MESH:
                                        side = wp.where(front, 0, 1)
                                        if horizon_open(scene.insts[h.index].escape, h.face, side) != 0:
                                            skip_[k] = h.index + 1
                                            face_[k] = 2 * h.face + side
                                sp_.px[k] = h.p[0]
                                sp_.py[k] = h.p[1]
                                sp_.pz[k] = h.p[2]
                                sp_.ox[k] = origin[0]
                                sp_.oy[k] = origin[1]
                                sp_.oz[k] = origin[2]
                                sp_.gx[k] = ng[0]
                                sp_.gy[k] = ng[1]
                                sp_.gz[k] = ng[2]
                                sp_.nx[k] = n[0]
                                sp_.ny[k] = n[1]
                                sp_.nz[k] = n[2]
                                sp_.vx[k] = v[0]
                                sp_.vy[k] = v[1]
                                sp_.vz[k] = v[2]
                                sp_.kdr[k] = kd[0]
                                sp_.kdg[k] = kd[1]
                                sp_.kdb[k] = kd[2]
                                sp_.ksr[k] = ks[0]
                                sp_.ksg[k] = ks[1]
                                sp_.ksb[k] = ks[2]
                                if wp.max(ks) > 0.0:
                                    sp_.glossy = 1
                                sp_.p_exp[k] = scene.mats[h.mat].p
                        lr[k] = L[0]
                        lg[k] = L[1]
                        lb[k] = L[2]
                    if lit != 0:
                        # the point lights for all lanes at once (local + their sum, as alone)
                        if scene.n_plights > 0:
                            pl = point_lights_packet(scene, sp_, lanes, lit, skip_, face_)
                            for k in range(PACKET):
                                if (lit >> k) & 1 != 0:
                                    lr[k] = lr[k] + lane(pl.r, k)
                                    lg[k] = lg[k] + lane(pl.g, k)
                                    lb[k] = lb[k] + lane(pl.b, k)
                                    l_rays[k] += lane_i(pl.rays, k)
                        if wp.static(F.area_lights):
                            if scene.n_alights > 0:
                                lp = area_lights_packet(scene, params, sp_, lanes, lit, skip_, face_)
            # a shaded packet's samples as the film adds them, the 8 lanes at once (film.packet_samples)
            film_r = PacketF()
            film_g = PacketF()
            film_b = PacketF()
            film_y2 = PacketF()
            if wp.static(shade_packets):
                if shaded:
                    packet_samples(lr, lg, lb, lp.r, lp.g, lp.b, lit, params.clamp, film_r, film_g, film_b, film_y2)
            # the packet's lanes pixel by pixel: a pixel's sums are fetched before its lanes and
            # stored after them, never inside the loop over its samples (stores there kept the
            # compiler from hoisting the scene's loads out of it)
            k_lo = int(0)
            while k_lo < lanes:
                jk = p_j
                key = p_key
                k_hi = lanes
                if wp.static(packets):
                    if mixed:
                        jk = lane_j[k_lo]
                        key = lane_key[k_lo]
                        if lane_j[lanes - 1] != jk:
                            k_hi = k_lo + 1
                            while lane_j[k_hi] == jk:
                                k_hi += 1
                if jk != cur:
                    if cur >= 0:
                        film.accum[pixel] = acc
                        film.accum_sq[pixel] = acc_sq
                        film.rays[pixel] = rays
                        film.overflow[pixel] = dropped
                    cur = jk
                    pixel = pixel0 + (cur & rm) * cam.width + (cur >> sh)
                    pkey = key
                    acc = wp.vec3(0.0, 0.0, 0.0)
                    acc_sq = float(0.0)
                    rays = int(0)
                    dropped = int(0)
                    if s0 > 0:
                        acc = film.accum[pixel]
                        acc_sq = film.accum_sq[pixel]
                        rays = film.rays[pixel]
                        dropped = film.overflow[pixel]
                for k in range(k_lo, k_hi):
                    if wp.static(shade_packets):
                        if shaded:
                            rays += l_rays[k]
                            if (lit >> k) & 1 != 0:
                                rays += lane_i(lp.rays, k)  # (its area lights' shadow rays)
                            acc = acc + wp.vec3(film_r[k], film_g[k], film_b[k])
                            acc_sq = acc_sq + film_y2[k]
                            continue
                    s = one_s + k
                    if wp.static(packets):
                        if mixed:
                            s = lane_s[k]
                    first = RayEntry()
                    time = float(0.0)
                    if wp.static(packets):
                        time = lane(pk.time, k)
                        first.o = wp.vec3(lane(pk.ox, k), lane(pk.oy, k), lane(pk.oz, k))
                        first.d = wp.vec3(lane(pk.dx, k), lane(pk.dy, k), lane(pk.dz, k))
                    else:
                        cs = camera_sample(cam, params, pkey, s, px0 + (cur >> sh), py + (cur & rm))
                        time = cs.time
                        first.o = cs.o
                        first.d = cs.d
                    L = wp.vec3(0.0, 0.0, 0.0)
                    first.w = wp.vec3(1.0, 1.0, 1.0)
                    first.depth = 0
                    first.key = wp.uint32(ROOT_KEY)
                    # without secondary rays the loop below runs once, on the camera ray itself: no
                    # ray stack (a store and a load of a whole entry every sample)
                    e = first
                    if wp.static(F.secondary):
                        stack[0] = first
                    sp = int(1)
                    while sp > 0:
                        sp -= 1
                        if wp.static(F.secondary):
                            e = stack[sp]
                        rays += 1
                        t_lo = float(0.0)
                        t_hi = float(3.0e38)
                        if e.depth == 0:
                            t_lo = params.t_min
                            t_hi = params.t_max
                            if cam.model != MODEL_PINHOLE:
                                if wp.length_sq(e.d) == 0.0:
                                    t_hi = -1.0  # no ray (camera.model_ray): a miss
                        h = Hit()
                        if wp.static(packets):
                            if e.depth == 0 and packed:
                                # the packet found this camera ray's nearest analytic hit (and mesh hit)
                                if mesh_packed:
                                    h = finish_packet_lane(scene, e.o, e.d, time, lane(pk.best, k), lane_i(pk.kind, k),
                                                           lane_i(pk.index, k), mp, k)
                                else:
                                    h = finish_hit(scene, e.o, e.d, t_lo, time, lane(pk.best, k), lane_i(pk.kind, k),
                                                   lane_i(pk.index, k))
                            else:
                                h = closest_hit(scene, e.o, e.d, t_lo, t_hi, time)
                        else:
                            h = closest_hit(scene, e.o, e.d, t_lo, t_hi, time)
                        if aovs != 0 and e.depth == 0:  # the camera ray's first hit
                            aov_sample(scene, cam, aov, aovs, pixel, s, s1, a_final, h, e.d, time)
                        if h.kind == KIND_NONE:
                            L += mul_sat(e.w, scene.background)
                            continue
                        front = wp.dot(e.d, h.ng) < 0.0
                        fc = toward_viewer(h.ng, h.ns, e.d)
                        ng = fc.ng
                        n = fc.n
                        le = scene.mats[h.mat].emit
                        if wp.max(le) > 0.0:
                            if front:
                                L += mul_sat(e.w, le)
                            continue
                        v = -e.d
                        ka = scene.mats[h.mat].ka
                        kd = scene.mats[h.mat].kd
                        ks = scene.mats[h.mat].ks
                        km = scene.mats[h.mat].km
                        if wp.static(F.textures):
                            tm = textured(scene, h, time)
                            ka = tm.ka
                            kd = tm.kd
                            ks = tm.ks
                            km = tm.km
                        local = mul_sat(ka, scene.ambient)
                        origin = spawn_origin(h.p, ng, h.mag, 1.0)  # shadow rays leave from here
                        dl = point_lights_direct(scene, h.p, origin, kd, ks, scene.mats[h.mat].p, ng, n, v, time)
                        rays += int(dl[3])
                        local += wp.vec3(dl[0], dl[1], dl[2])
                        if wp.static(F.area_lights):
                            # a separate call: a scene without area lights keeps the point-light code
                            # small enough for the C++ compiler to inline
                            if scene.n_alights > 0:
                                al = area_lights_direct(scene, params, pkey, s, e.key, h.p, origin, ng, n, v,
                                                        kd, ks, scene.mats[h.mat].p, time,
                                                        map_samples(scene, px0 + (cur >> sh), py + (cur & rm)))
                                rays += int(al[3])
                                local += wp.vec3(al[0], al[1], al[2])
                        L += mul_sat(e.w, local)

                        if wp.static(F.secondary):
                            if e.depth < params.max_depth:
                                w_refl = km
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
                                                    ug = sample_2d_keyed(params.sampler, pkey, s, params.spp,
                                                                   hash2(e.key, wp.uint32(KEY_FROSTED_REFRACT)))
                                                    tdir = lobe(ug, tdir, frost)
                                            tw = mul_sat(e.w, w_refr)
                                            if wp.dot(tdir, ng) < 0.0 and wp.max(tw) > params.min_weight:
                                                if sp < STACK_SIZE:
                                                    child = RayEntry()
                                                    child.o = spawn_origin(h.p, ng, h.mag, -1.0)
                                                    child.d = tdir
                                                    child.w = tw
                                                    child.depth = e.depth + 1
                                                    child.key = hash2(e.key, wp.uint32(KEY_REFRACTED))
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
                                            ug = sample_2d_keyed(params.sampler, pkey, s, params.spp,
                                                           hash2(e.key, wp.uint32(KEY_GLOSSY_REFLECT)))
                                            r = lobe(ug, r, gloss)
                                    if wp.dot(r, ng) > 0.0:
                                        if sp < STACK_SIZE:
                                            child = RayEntry()
                                            child.o = spawn_origin(h.p, ng, h.mag, 1.0)
                                            child.d = r
                                            child.w = rw
                                            child.depth = e.depth + 1
                                            child.key = hash2(e.key, wp.uint32(KEY_REFLECTED))
                                            stack[sp] = child
                                            sp += 1
                                        else:
                                            dropped += 1
                    L = sanitize(L, params.clamp)
                    acc = acc + L
                    y = luminance(L)
                    acc_sq = acc_sq + y * y
                k_lo = k_hi
        if cur >= 0:
            film.accum[pixel] = acc
            film.accum_sq[pixel] = acc_sq
            film.rays[pixel] = rays
            film.overflow[pixel] = dropped

    @wp.kernel(module="unique", enable_backward=False, module_options=_warp.MODULE_OPTIONS)
    def render_kernel(scene: SceneData, cam: CameraData, params: RenderParams,
                      row0: int, stride: int, s0: int, s1: int, film: FilmData, run: int, block: int, aov: AovData):
        # this launch's pixels: blocks of ``block`` consecutive rows from rows row0, row0 + stride,
        # ... (an interleaved slice of the frame, render._slices), ``run`` consecutive pixels of
        # one row per thread (``run`` divides the width: a CPU task takes a whole row, so the
        # launch's arguments are copied once per row, not per pixel); or, with stride 0 (a CPU
        # pass's default, run = the width), each thread claims the next block of ``block`` rows
        # from the film's counter (film.claim_block) until none is left, so that the pool's
        # threads finish together however their cores are shared. With meshes, a CPU thread
        # takes a whole block, a block of 4 rows column by column (render_pixels: its packets over
        # several pixels cover patches, and the rays of neighbouring pixels follow each other
        # through the trees: ``column_blocks`` in ``warprt.fast``; scenes without meshes gain
        # nothing from that and pay for the film's four interleaved rows, so keep to rows). One
        # call site per kernel: render_pixels
        # is inlined
        t = wp.tid()
        px0 = int(0)
        py = int(0)
        whole = True  # the thread takes a whole block of rows (else ``run`` pixels of one row)
        if stride == 0:
            py = claim_block(film.claims) * block
        elif run >= cam.width and wp.static(F.meshes):
            py = row0 + t * stride
        else:
            k0 = t * run
            k = k0 / cam.width
            py = row0 + (k / block) * stride + k % block
            px0 = k0 % cam.width
            whole = False
        if py >= cam.height:
            return
        calls = int(1)
        if whole:
            calls = wp.min(block, cam.height - py)
        if wp.static(F.meshes):
            n_pix = run
            sh = int(0)
            if run >= cam.width and (scene.fast_off & FAST_COLUMN_BLOCKS) == 0:  # (warprt.fast: column_blocks)
                if calls == 4:
                    sh = 2
                calls = calls >> sh
                n_pix = cam.width << sh
            for r in range(calls):
                render_pixels(scene, cam, params, px0, py + r, (py + r) * cam.width + px0, n_pix, s0, s1, film, sh,
                              aov)
        else:
            for r in range(calls):
                render_pixels(scene, cam, params, px0, py + r, (py + r) * cam.width + px0, run, s0, s1, film, 0, aov)

    kernels.label(render_kernel, f"the render kernel for {F.key}" + ("" if packets else " (rays one by one)"))
    return SimpleNamespace(render=render_kernel, pixels=render_pixels, trace=trace)
