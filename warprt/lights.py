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
from .geometry import max_abs, spawn_offset
from .records import FALLOFF_DIRECTIONAL, Features, RenderParams, SceneData
from .sampling import hash2, sample_2d_keyed
from .shading import blinn_phong, mul_sat
from .shapes import prepare_emitter, sample_emitter
from .trace import make_trace

LIGHT_DIM_BASE = 16  # dimension keys of area light j: hash2(path key, LIGHT_DIM_BASE + j)


@build_once
def make_lights(F: Features) -> SimpleNamespace:
    """The direct-lighting device functions for one feature set (built once per process)."""
    shadow = make_trace(F).shadow
    transmittance = make_trace(F).transmittance

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
            ns = scene.alights[j].samples
            acc = wp.vec3(0.0, 0.0, 0.0)
            dim = hash2(key, wp.uint32(LIGHT_DIM_BASE + j))
            kind = scene.alights[j].kind
            row = scene.alights[j].shape
            prep = prepare_emitter(scene, kind, row, p, n, params.light_sampling)  # once for the ns draws
            if prep.ok == 0:
                continue  # no light from it reaches p
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
            L += mul_sat(scene.alights[j].le, acc) / float(ns)
        return wp.vec4(L[0], L[1], L[2], float(rays))

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

    return SimpleNamespace(point_lights_direct=point_lights_direct, area_lights_direct=area_lights_direct)
