"""Direct light at a shading point: point and directional lights (one shadow ray each) and area lights
(stratified samples of their emitting shapes, each with a shadow ray).

Directions, distances and densities are taken from the surface point p; shadow rays start from
``origin``, p moved off the surface (see ``geometry.spawn_origin``). Each area-light sample acts
as a point light of lecture intensity Le·cosθ'·dA/π, so the diffuse term is exactly (kd/π)·E for
irradiance E. Which shape emits, and how a point of it is drawn, is ``shapes.sample_emitter``'s
business: nothing here depends on the shape kind.
"""

from __future__ import annotations

from types import SimpleNamespace

import warp as wp

from ._warp import build_once
from .accel import PACKET, PacketF, PacketI, PacketU
from .geometry import max_abs, spawn_offset
from .records import FALLOFF_DIRECTIONAL, KIND_RECT, Features, RenderParams, SceneData
from .sampling import SAMPLER_SOBOL, hash2, is_rectangle_edges, sample_2d_keyed, sobol_packet
from .shading import blinn_phong, mul_sat
from .shapes import prepare_emitter, rect_draw_packet, sample_emitter
from .trace import make_trace

LIGHT_DIM_BASE = 16  # dimension keys of area light j: hash2(path key, LIGHT_DIM_BASE + j)
ROOT_KEY = 0x51ED270B  # dimension key of the camera ray's path vertex


@wp.struct
class ShadePacket:
    """A camera packet's shading points, per lane: the point p, the shadow rays' origin, the
    geometric and shading normals turned towards the viewer (g, n), the direction to the viewer,
    the material's kd, ks and exponent, the time, and the pixel key and sample index."""

    px: PacketF
    py: PacketF
    pz: PacketF
    ox: PacketF
    oy: PacketF
    oz: PacketF
    gx: PacketF
    gy: PacketF
    gz: PacketF
    nx: PacketF
    ny: PacketF
    nz: PacketF
    vx: PacketF
    vy: PacketF
    vz: PacketF
    kdr: PacketF
    kdg: PacketF
    kdb: PacketF
    ksr: PacketF
    ksg: PacketF
    ksb: PacketF
    p_exp: PacketF
    time: PacketF
    key: PacketU
    sample: PacketI


@wp.struct
class LightPacket:
    """Per lane, the area lights' rgb and the shadow rays they used."""

    r: PacketF
    g: PacketF
    b: PacketF
    rays: PacketI


@build_once
def make_lights(F: Features) -> SimpleNamespace:
    """The direct-lighting device functions for one feature set (built once per process)."""
    shadow = make_trace(F).shadow
    transmittance = make_trace(F).transmittance

    @wp.func(inline=True)
    def one_area_light(scene: SceneData, params: RenderParams, j: int, pkey: wp.uint32, sample: int,
                       key: wp.uint32, p: wp.vec3, origin: wp.vec3, ng: wp.vec3, n: wp.vec3, v: wp.vec3,
                       kd: wp.vec3, ks: wp.vec3, p_exp: float, time: float) -> wp.vec4:
        """Area light j's part of ``area_lights_direct`` (rgb, shadow rays used in w)."""
        ns = scene.alights[j].samples
        acc = wp.vec3(0.0, 0.0, 0.0)
        rays = int(0)
        dim = hash2(key, wp.uint32(LIGHT_DIM_BASE + j))
        kind = scene.alights[j].kind
        row = scene.alights[j].shape
        prep = prepare_emitter(scene, kind, row, p, n, params.light_sampling)  # once for the ns draws
        if prep.ok == 0:
            return wp.vec4(0.0, 0.0, 0.0, 0.0)  # no light from it reaches p
        for k in range(ns):
            u = sample_2d_keyed(params.sampler, pkey, sample * ns + k, params.spp * ns, dim)
            e = sample_emitter(scene, kind, row, prep, p, u)
            if e.ok == 0:
                continue
            if wp.dot(ng, e.l) <= 0.0:
                continue
            f = blinn_phong(n, e.l, v, kd, ks, p_exp)
            if wp.max(f) <= 0.0:
                continue
            rays += 1
            T = shadow(scene, origin, e.y, 2.0 * spawn_offset(e.mag), time)
            if wp.max(T) <= 0.0:
                continue
            acc += mul_sat(mul_sat(T, f), wp.vec3(e.inv_pdf / wp.pi))
        L = mul_sat(scene.alights[j].le, acc) / float(ns)
        return wp.vec4(L[0], L[1], L[2], float(rays))

    @wp.func
    def area_lights_direct(scene: SceneData, params: RenderParams, pkey: wp.uint32, sample: int, key: wp.uint32,
                           p: wp.vec3, origin: wp.vec3, ng: wp.vec3, n: wp.vec3, v: wp.vec3, kd: wp.vec3, ks: wp.vec3,
                           p_exp: float, time: float) -> wp.vec4:
        """Direct light from the area lights: ``samples`` stratified shadow rays per light (rgb,
        shadow rays used in w). ``pkey`` is the pixel's ``pixel_key``; ``ng``/``n`` are the
        geometric/shading normals turned towards the viewer, ``v`` the direction to it."""
        L = wp.vec3(0.0, 0.0, 0.0)
        rays = int(0)
        for j in range(scene.n_alights):
            a = one_area_light(scene, params, j, pkey, sample, key, p, origin, ng, n, v, kd, ks, p_exp, time)
            L += wp.vec3(a[0], a[1], a[2])
            rays += int(a[3])
        return wp.vec4(L[0], L[1], L[2], float(rays))

    @wp.func
    def area_lights_packet(scene: SceneData, params: RenderParams, sp: ShadePacket, lanes: int,
                           live: int) -> LightPacket:
        """``area_lights_direct`` for the shading points of a camera packet (lanes 0 to ``lanes``
        - 1 whose bit is set in ``live``; their path key is the camera ray's, ROOT_KEY), each
        lane's sum the same as alone, bit for bit: a rectangle's draws for all lanes at once
        (``shapes.rect_draw_packet``), then each lane's shadow ray; other emitters, and lanes a
        rectangle is drawn for by solid angle, one lane at a time."""
        out = LightPacket()
        ux = PacketF()
        uy = PacketF()
        y0 = PacketF()
        y1 = PacketF()
        y2 = PacketF()
        l0 = PacketF()
        l1 = PacketF()
        l2 = PacketF()
        ip = PacketF()
        ar = PacketF()
        ag = PacketF()
        ab = PacketF()
        for j in range(scene.n_alights):
            ns = scene.alights[j].samples
            dim = hash2(wp.uint32(ROOT_KEY), wp.uint32(LIGHT_DIM_BASE + j))
            scalar = live
            if scene.alights[j].kind == KIND_RECT:
                rec = scene.rects[scene.alights[j].shape]
                area = wp.length(wp.cross(rec.e1, rec.e2))
                square = int(0)
                if is_rectangle_edges(rec.e1, rec.e2):
                    square = 1
                stop = 2.0 * spawn_offset(max_abs(rec.c) + max_abs(rec.e1) + max_abs(rec.e2))
                drawn = int(0)
                for k in range(PACKET):
                    ar[k] = 0.0
                    ag[k] = 0.0
                    ab[k] = 0.0
                for s in range(ns):
                    if params.sampler == SAMPLER_SOBOL:
                        idx = PacketI()
                        for k in range(lanes):
                            idx[k] = sp.sample[k] * ns + s
                        sobol_packet(sp.key, idx, dim, ux, uy)  # the 8 lanes' points at once
                    else:
                        for k in range(lanes):
                            if (live >> k) & 1 != 0:
                                u = sample_2d_keyed(params.sampler, sp.key[k], sp.sample[k] * ns + s, params.spp * ns,
                                                    dim)
                                ux[k] = u[0]
                                uy[k] = u[1]
                    m = rect_draw_packet(rec.c, rec.e1, rec.e2, rec.n, area, params.light_sampling, square, live,
                                         sp.px, sp.py, sp.pz, sp.nx, sp.ny, sp.nz, ux, uy, y0, y1, y2, l0, l1, l2, ip)
                    scalar = m >> 8
                    drawn = live & ~scalar
                    for k in range(lanes):
                        if (m >> k) & 1 == 0:
                            continue
                        l = wp.vec3(l0[k], l1[k], l2[k])
                        if wp.dot(wp.vec3(sp.gx[k], sp.gy[k], sp.gz[k]), l) <= 0.0:
                            continue
                        n = wp.vec3(sp.nx[k], sp.ny[k], sp.nz[k])
                        f = blinn_phong(n, l, wp.vec3(sp.vx[k], sp.vy[k], sp.vz[k]),
                                        wp.vec3(sp.kdr[k], sp.kdg[k], sp.kdb[k]), wp.vec3(sp.ksr[k], sp.ksg[k], sp.ksb[k]),
                                        sp.p_exp[k])
                        if wp.max(f) <= 0.0:
                            continue
                        out.rays[k] += 1
                        T = shadow(scene, wp.vec3(sp.ox[k], sp.oy[k], sp.oz[k]), wp.vec3(y0[k], y1[k], y2[k]), stop,
                                   sp.time[k])
                        if wp.max(T) <= 0.0:
                            continue
                        a = wp.vec3(ar[k], ag[k], ab[k]) + mul_sat(mul_sat(T, f), wp.vec3(ip[k] / wp.pi))
                        ar[k] = a[0]
                        ag[k] = a[1]
                        ab[k] = a[2]
                for k in range(lanes):
                    if (drawn >> k) & 1 != 0:
                        L = mul_sat(scene.alights[j].le, wp.vec3(ar[k], ag[k], ab[k])) / float(ns)
                        out.r[k] = out.r[k] + L[0]
                        out.g[k] = out.g[k] + L[1]
                        out.b[k] = out.b[k] + L[2]
            for k in range(lanes):
                if (scalar >> k) & 1 != 0:
                    q = one_area_light(scene, params, j, sp.key[k], sp.sample[k], wp.uint32(ROOT_KEY),
                                       wp.vec3(sp.px[k], sp.py[k], sp.pz[k]), wp.vec3(sp.ox[k], sp.oy[k], sp.oz[k]),
                                       wp.vec3(sp.gx[k], sp.gy[k], sp.gz[k]), wp.vec3(sp.nx[k], sp.ny[k], sp.nz[k]),
                                       wp.vec3(sp.vx[k], sp.vy[k], sp.vz[k]), wp.vec3(sp.kdr[k], sp.kdg[k], sp.kdb[k]),
                                       wp.vec3(sp.ksr[k], sp.ksg[k], sp.ksb[k]), sp.p_exp[k], sp.time[k])
                    out.r[k] = out.r[k] + q[0]
                    out.g[k] = out.g[k] + q[1]
                    out.b[k] = out.b[k] + q[2]
                    out.rays[k] += int(q[3])
        return out

    @wp.func(inline=True)
    def point_lights_direct(scene: SceneData, p: wp.vec3, origin: wp.vec3, mat: int, ng: wp.vec3, n: wp.vec3,
                            v: wp.vec3, time: float) -> wp.vec4:
        """Light reaching the viewer from the point lights (rgb, shadow rays used in w)."""
        kd = scene.mats[mat].kd
        ks = scene.mats[mat].ks
        p_exp = scene.mats[mat].p
        L = wp.vec3(0.0, 0.0, 0.0)
        rays = int(0)
        for i in range(scene.n_plights):
            directional = scene.plights[i].inv_sq == FALLOFF_DIRECTIONAL
            l = scene.plights[i].pos  # a directional light: the unit vector towards it
            dist = float(0.0)
            if not directional:
                to_light = scene.plights[i].pos - p  # shading uses the surface point itself
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
            # the shadow ray: to infinity towards a directional light; else to the light, ending
            # short of it (as ``shadow`` does; one transmittance call keeps the loop small)
            d_sh = l
            t_sh = float(3.0e38)
            T = wp.vec3(1.0, 1.0, 1.0)
            blocked_test = True
            if not directional:
                to_t = scene.plights[i].pos - origin
                dist_o = wp.length(to_t)
                stop_short = spawn_offset(max_abs(scene.plights[i].pos))
                if dist_o <= stop_short:
                    blocked_test = False
                else:
                    d_sh = to_t / dist_o
                    t_sh = dist_o - stop_short
            if blocked_test:
                T = transmittance(scene, origin, d_sh, t_sh, time)
            if wp.max(T) <= 0.0:
                continue
            I = scene.plights[i].intensity
            if scene.plights[i].inv_sq == 1:
                I = I / (dist * dist)
            L += mul_sat(T, mul_sat(I, f))
        return wp.vec4(L[0], L[1], L[2], float(rays))

    return SimpleNamespace(point_lights_direct=point_lights_direct, area_lights_direct=area_lights_direct,
                           area_lights_packet=area_lights_packet)
