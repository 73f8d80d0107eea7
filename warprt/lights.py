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
from .accel import PACKET, PacketF, PacketI, PacketU, lane, lane_add, lane_addi, lane_i
from .fast import FAST_SOBOL_PACKETS
from .geometry import max_abs, shadow_rays_packet, spawn_offset
from .records import FALLOFF_DIRECTIONAL, KIND_RECT, Features, RenderParams, SceneData
from .sampling import (SAMPLER_SOBOL, SplitDraws, hash2, is_rectangle_edges, is_split_order, light_sample_2d,
                       sobol_packet, sobol_split_draw, sobol_split_setup)
from .shading import blinn_phong, mul_sat, phong_power
from .shapes import RectKnots, prepare_emitter, rect_draw_packet, rect_setup_packet, sample_emitter
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
    ns: PacketI  # the lane's pixel's shadow rays per camera sample for "auto" lights (map_samples)
    glossy: int  # 1 when a lane's material has a specular colour (ks > 0); 0: every lobe is kd · n·l


@wp.struct
class LightPacket:
    """Per lane, the area lights' rgb and the shadow rays they used."""

    r: PacketF
    g: PacketF
    b: PacketF
    rays: PacketI


# A point (or directional) light seen from a camera packet's 8 shading points at once, as clang
# vectors on the CPU: what ``point_lights_direct`` computes for each lane before the material's
# colours (the direction and distance to the light, n·l, the half vector's length and n·h) and
# its shadow ray, the same operations in the same order (Warp's C++ compiler fuses nothing), so
# each lane's values are the scalar loop's bit for bit. On CUDA the same operations lane by lane.
_POINT_LIGHT_PACKET = r"""
int res = 0;
#if defined(__clang__) && !defined(__CUDA_ARCH__)
typedef float v8 __attribute__((ext_vector_type(8)));
typedef int i8 __attribute__((ext_vector_type(8)));
v8 Px, Py, Pz, Ox, Oy, Oz, Gx, Gy, Gz, Nx, Ny, Nz, Vx, Vy, Vz;
__builtin_memcpy(&Px, &px, 32); __builtin_memcpy(&Py, &py, 32); __builtin_memcpy(&Pz, &pz, 32);
__builtin_memcpy(&Ox, &ox, 32); __builtin_memcpy(&Oy, &oy, 32); __builtin_memcpy(&Oz, &oz, 32);
__builtin_memcpy(&Gx, &gx, 32); __builtin_memcpy(&Gy, &gy, 32); __builtin_memcpy(&Gz, &gz, 32);
__builtin_memcpy(&Nx, &nx, 32); __builtin_memcpy(&Ny, &ny, 32); __builtin_memcpy(&Nz, &nz, 32);
__builtin_memcpy(&Vx, &vx, 32); __builtin_memcpy(&Vy, &vy, 32); __builtin_memcpy(&Vz, &vz, 32);
auto vsqrt = [](v8 x) -> v8 { return __builtin_elementwise_sqrt(x); };
i8 ok;
for (int l = 0; l < 8; ++l) ok[l] = (lanes >> l) & 1 ? -1 : 0;
v8 lx = (v8)(pos[0]), ly = (v8)(pos[1]), lz = (v8)(pos[2]), dist = (v8)(0.0f);
if (directional == 0) {
    const v8 tx = pos[0] - Px, ty = pos[1] - Py, tz = pos[2] - Pz;
    dist = vsqrt((tx * tx + ty * ty) + tz * tz);
    ok &= ~(dist <= 0.0f);
    lx = tx / dist; ly = ty / dist; lz = tz / dist;
}
ok &= ~(((Gx * lx + Gy * ly) + Gz * lz) <= 0.0f);
const v8 nl = (Nx * lx + Ny * ly) + Nz * lz;
ok &= ~(nl <= 0.0f);  // blinn_phong is 0 there
const v8 hx = lx + Vx, hy = ly + Vy, hz = lz + Vz;
const v8 hl = vsqrt((hx * hx + hy * hy) + hz * hz);
const v8 ch = (Nx * (hx / hl) + Ny * (hy / hl)) + Nz * (hz / hl);
v8 sx = lx, sy = ly, sz = lz, st = (v8)(3.0e38f);
i8 test = ok;
if (directional == 0) {
    const v8 ux = pos[0] - Ox, uy = pos[1] - Oy, uz = pos[2] - Oz;
    const v8 dn = vsqrt((ux * ux + uy * uy) + uz * uz);
    test &= ~(dn <= stop);
    sx = ux / dn; sy = uy / dn; sz = uz / dn;
    st = dn - stop;
}
__builtin_memcpy(&out_dist, &dist, 32); __builtin_memcpy(&out_nl, &nl, 32);
__builtin_memcpy(&out_hl, &hl, 32); __builtin_memcpy(&out_nh, &ch, 32);
__builtin_memcpy(&out_dx, &sx, 32); __builtin_memcpy(&out_dy, &sy, 32); __builtin_memcpy(&out_dz, &sz, 32);
__builtin_memcpy(&out_t, &st, 32);
for (int l = 0; l < 8; ++l) res |= (ok[l] ? 1 << l : 0) | (test[l] ? 1 << (16 + l) : 0);
#else
for (int l = 0; l < 8; ++l) {
    if (!((lanes >> l) & 1)) continue;
    float lx = pos[0], ly = pos[1], lz = pos[2], dist = 0.0f;
    if (directional == 0) {
        const float tx = pos[0] - px[l], ty = pos[1] - py[l], tz = pos[2] - pz[l];
        dist = sqrtf((tx * tx + ty * ty) + tz * tz);
        if (dist <= 0.0f) continue;
        lx = tx / dist; ly = ty / dist; lz = tz / dist;
    }
    if (((gx[l] * lx + gy[l] * ly) + gz[l] * lz) <= 0.0f) continue;
    const float nl = (nx[l] * lx + ny[l] * ly) + nz[l] * lz;
    if (nl <= 0.0f) continue;
    const float hx = lx + vx[l], hy = ly + vy[l], hz = lz + vz[l];
    const float hl = sqrtf((hx * hx + hy * hy) + hz * hz);
    out_dist[l] = dist; out_nl[l] = nl; out_hl[l] = hl;
    out_nh[l] = (nx[l] * (hx / hl) + ny[l] * (hy / hl)) + nz[l] * (hz / hl);
    out_dx[l] = lx; out_dy[l] = ly; out_dz[l] = lz; out_t[l] = 3.0e38f;
    res |= 1 << l;
    if (directional == 0) {
        const float ux = pos[0] - ox[l], uy = pos[1] - oy[l], uz = pos[2] - oz[l];
        const float dn = sqrtf((ux * ux + uy * uy) + uz * uz);
        if (dn <= stop) continue;
        out_dx[l] = ux / dn; out_dy[l] = uy / dn; out_dz[l] = uz / dn; out_t[l] = dn - stop;
    }
    res |= 1 << (16 + l);
}
#endif
return res;
"""


@wp.func_native(_POINT_LIGHT_PACKET)
def point_light_packet(pos: wp.vec3, directional: int, stop: float, lanes: int, px: PacketF, py: PacketF,
                       pz: PacketF, ox: PacketF, oy: PacketF, oz: PacketF, gx: PacketF, gy: PacketF, gz: PacketF,
                       nx: PacketF, ny: PacketF, nz: PacketF, vx: PacketF, vy: PacketF, vz: PacketF,
                       out_dist: wp.ref[PacketF], out_nl: wp.ref[PacketF], out_hl: wp.ref[PacketF],
                       out_nh: wp.ref[PacketF], out_dx: wp.ref[PacketF], out_dy: wp.ref[PacketF],
                       out_dz: wp.ref[PacketF], out_t: wp.ref[PacketF]) -> int:
    """For each lane in the bit mask ``lanes`` (point p, shadow-ray origin o, normals g and n turned
    towards the viewer, direction v to the viewer) and the light at ``pos`` (a unit vector towards
    it when ``directional``; ``stop``: where the shadow ray ends short of it): the distance to the
    light, n·l, |l + v|, n·(l + v)/|l + v| and the shadow ray's direction and length. Returns bit
    l set where the light can reach lane l (in front of g and n), bit 16 + l where its shadow
    ray is to be traced (``point_lights_direct``'s tests)."""
    ...



# The Blinn-Phong geometry of a packet's 8 shading points towards given unit directions l (an
# area light's samples), as ``blinn_phong`` computes it before the material's colours: which lanes
# see l in front of both normals (g·l > 0, the test before the call, and n·l > 0), n·l, |l + v|
# and n·(l + v)/|l + v|, the same operations in the same order. On CUDA lane by lane.
_LOBE_PACKET = r"""
int res = 0;
#if defined(__clang__) && !defined(__CUDA_ARCH__)
typedef float v8 __attribute__((ext_vector_type(8)));
typedef int i8 __attribute__((ext_vector_type(8)));
v8 Lx, Ly, Lz, Gx, Gy, Gz, Nx, Ny, Nz, Vx, Vy, Vz;
__builtin_memcpy(&Lx, &lx, 32); __builtin_memcpy(&Ly, &ly, 32); __builtin_memcpy(&Lz, &lz, 32);
__builtin_memcpy(&Gx, &gx, 32); __builtin_memcpy(&Gy, &gy, 32); __builtin_memcpy(&Gz, &gz, 32);
__builtin_memcpy(&Nx, &nx, 32); __builtin_memcpy(&Ny, &ny, 32); __builtin_memcpy(&Nz, &nz, 32);
__builtin_memcpy(&Vx, &vx, 32); __builtin_memcpy(&Vy, &vy, 32); __builtin_memcpy(&Vz, &vz, 32);
i8 ok;
for (int l = 0; l < 8; ++l) ok[l] = (lanes >> l) & 1 ? -1 : 0;
ok &= ~(((Gx * Lx + Gy * Ly) + Gz * Lz) <= 0.0f);
const v8 nl = (Nx * Lx + Ny * Ly) + Nz * Lz;
ok &= ~(nl <= 0.0f);
const v8 hx = Lx + Vx, hy = Ly + Vy, hz = Lz + Vz;
const v8 hl = __builtin_elementwise_sqrt((hx * hx + hy * hy) + hz * hz);
const v8 nh = (Nx * (hx / hl) + Ny * (hy / hl)) + Nz * (hz / hl);
__builtin_memcpy(&out_nl, &nl, 32); __builtin_memcpy(&out_hl, &hl, 32); __builtin_memcpy(&out_nh, &nh, 32);
for (int l = 0; l < 8; ++l) res |= ok[l] ? 1 << l : 0;
#else
for (int l = 0; l < 8; ++l) {
    if (!((lanes >> l) & 1)) continue;
    if (((gx[l] * lx[l] + gy[l] * ly[l]) + gz[l] * lz[l]) <= 0.0f) continue;
    const float nl = (nx[l] * lx[l] + ny[l] * ly[l]) + nz[l] * lz[l];
    if (nl <= 0.0f) continue;
    const float hx = lx[l] + vx[l], hy = ly[l] + vy[l], hz = lz[l] + vz[l];
    const float hl = sqrtf((hx * hx + hy * hy) + hz * hz);
    out_nl[l] = nl; out_hl[l] = hl;
    out_nh[l] = (nx[l] * (hx / hl) + ny[l] * (hy / hl)) + nz[l] * (hz / hl);
    res |= 1 << l;
}
#endif
return res;
"""


@wp.func_native(_LOBE_PACKET)
def lobe_packet(lanes: int, lx: PacketF, ly: PacketF, lz: PacketF, gx: PacketF, gy: PacketF, gz: PacketF,
                nx: PacketF, ny: PacketF, nz: PacketF, vx: PacketF, vy: PacketF, vz: PacketF,
                out_nl: wp.ref[PacketF], out_hl: wp.ref[PacketF], out_nh: wp.ref[PacketF]) -> int:
    """See above: bit l set where lane l (of the bit mask ``lanes``) sees l in front of g and n."""
    ...


# (the pieces both share: the lanes' colours and sums as vectors, ``sat``, and ``sat`` for a lane)
_SUMS_VECTORS = r"""
typedef float v8 __attribute__((ext_vector_type(8)));
typedef int i8 __attribute__((ext_vector_type(8)));
const i8 on = ((i8){1, 2, 4, 8, 16, 32, 64, 128} & lit) != 0;
const v8 zero = 0.0f, big = 3.4028234663852886e38f, one = 1.0f;
auto sat = [&](v8 x, v8 y) {
    const v8 p = x * y;
    return ((x > 0.0f) & (y > 0.0f)) ? (p <= big ? p : big) : zero;
};
v8 F0, F1, F2, O0, O1, O2;
__builtin_memcpy(&F0, &fr, 32); __builtin_memcpy(&F1, &fg, 32); __builtin_memcpy(&F2, &fb, 32);
__builtin_memcpy(&O0, &out_r, 32); __builtin_memcpy(&O1, &out_g, 32); __builtin_memcpy(&O2, &out_b, 32);
"""
_SUMS_STORE = r"""
__builtin_memcpy(&out_r, &O0, 32); __builtin_memcpy(&out_g, &O1, 32); __builtin_memcpy(&out_b, &O2, 32);
"""
_SAT_LANE = r"""
auto sat = [](float x, float y) {
    const float p = x * y;
    return x > 0.0f && y > 0.0f ? (p <= 3.4028234663852886e38f ? p : 3.4028234663852886e38f) : 0.0f;
};
"""


def _sums(snippet: str) -> str:
    """A sums snippet with the shared pieces (``@VECTORS@``, ``@STORE@``, ``@SAT_LANE@``) in place."""
    return snippet.replace("@VECTORS@\n", _SUMS_VECTORS.lstrip("\n")).replace(
        "@STORE@\n", _SUMS_STORE.lstrip("\n")).replace("@SAT_LANE@\n", _SAT_LANE.lstrip("\n"))


# A point light's share for a packet's lanes in ``lit`` (a bit mask), at once (clang vectors; lane
# by lane on CUDA), each lane's the scalar loop's bit for bit: its intensity I (over dist² when
# ``inv_sq``), mul_sat(1, mul_sat(I, f)) for the lane's colour f, added to the lane's sums.
# mul_sat(x, y) is (x > 0 and y > 0) ? min(x·y, FLT_MAX) : 0 per channel (``shading.mul_sat``).
_POINT_SUMS = _sums(r"""
#if defined(__clang__) && !defined(__CUDA_ARCH__)
@VECTORS@
v8 D;
__builtin_memcpy(&D, &dist, 32);
const v8 dd = D * D;
const v8 I0 = inv_sq ? intensity[0] / dd : (v8)(intensity[0]);
const v8 I1 = inv_sq ? intensity[1] / dd : (v8)(intensity[1]);
const v8 I2 = inv_sq ? intensity[2] / dd : (v8)(intensity[2]);
const v8 L0 = sat(one, sat(I0, F0)), L1 = sat(one, sat(I1, F1)), L2 = sat(one, sat(I2, F2));
O0 = on ? O0 + L0 : O0; O1 = on ? O1 + L1 : O1; O2 = on ? O2 + L2 : O2;
@STORE@
#else
@SAT_LANE@
for (int l = 0; l < 8; ++l) {
    if (!((lit >> l) & 1)) continue;
    const float dd = dist[l] * dist[l];
    const float f[3] = {fr[l], fg[l], fb[l]};
    float L[3];
    for (int c = 0; c < 3; ++c) L[c] = sat(1.0f, sat(inv_sq ? intensity[c] / dd : intensity[c], f[c]));
    out_r[l] = out_r[l] + L[0]; out_g[l] = out_g[l] + L[1]; out_b[l] = out_b[l] + L[2];
}
#endif
""")


@wp.func_native(_POINT_SUMS)
def point_sums(lit: int, intensity: wp.vec3, inv_sq: int, dist: PacketF, fr: PacketF, fg: PacketF, fb: PacketF,
               out_r: wp.ref[PacketF], out_g: wp.ref[PacketF], out_b: wp.ref[PacketF]):
    """See above."""
    ...


# An area light's draw for a packet's lanes in ``lanes`` (bit mask) with Lambertian materials, at
# once (clang vectors; lane by lane on CUDA), each lane's the scalar loop's bit for bit: its
# colour f = kd·(n·l) into fr, fg, fb, and where max(f) > 0 (or NaN, as ``wp.max(f) <= 0``
# reads it) its bit in the result and one more shadow ray in ``rays``.
_DIFFUSE_LANES = r"""
int res = 0;
#if defined(__clang__) && !defined(__CUDA_ARCH__)
typedef float v8 __attribute__((ext_vector_type(8)));
typedef int i8 __attribute__((ext_vector_type(8)));
const i8 on = ((i8){1, 2, 4, 8, 16, 32, 64, 128} & lanes) != 0;
v8 KR, KG, KB, NL;
i8 R;
__builtin_memcpy(&KR, &kdr, 32); __builtin_memcpy(&KG, &kdg, 32); __builtin_memcpy(&KB, &kdb, 32);
__builtin_memcpy(&NL, &nl, 32); __builtin_memcpy(&R, &rays, 32);
const v8 F0 = KR * NL, F1 = KG * NL, F2 = KB * NL;
const v8 m01 = F0 > F1 ? F0 : F1;
const v8 mx = m01 > F2 ? m01 : F2;
const i8 go = on & ~(mx <= 0.0f);
R -= go;  // (-1 a lane that goes)
__builtin_memcpy(&fr, &F0, 32); __builtin_memcpy(&fg, &F1, 32); __builtin_memcpy(&fb, &F2, 32);
__builtin_memcpy(&rays, &R, 32);
for (int l = 0; l < 8; ++l) res |= go[l] ? 1 << l : 0;
#else
for (int l = 0; l < 8; ++l) {
    if (!((lanes >> l) & 1)) continue;
    const float f0 = kdr[l] * nl[l], f1 = kdg[l] * nl[l], f2 = kdb[l] * nl[l];
    const float m01 = f0 > f1 ? f0 : f1;
    const float mx = m01 > f2 ? m01 : f2;
    if (mx <= 0.0f) continue;
    fr[l] = f0; fg[l] = f1; fb[l] = f2;
    rays[l] = rays[l] + 1;
    res |= 1 << l;
}
#endif
return res;
"""


@wp.func_native(_DIFFUSE_LANES)
def diffuse_lanes(lanes: int, kdr: PacketF, kdg: PacketF, kdb: PacketF, nl: PacketF, fr: wp.ref[PacketF],
                  fg: wp.ref[PacketF], fb: wp.ref[PacketF], rays: wp.ref[PacketI]) -> int:
    """See above."""
    ...


# An area light's unblocked draws for a packet's lanes in ``lit`` (bit mask), at once (clang
# vectors; lane by lane on CUDA), each lane's the scalar loop's bit for bit:
# mul_sat(mul_sat(1, f), ip / π) for its colour f and weight ip, added to its sums (``_POINT_SUMS``'
# ``sat``).
_AREA_SUMS = _sums(r"""
#if defined(__clang__) && !defined(__CUDA_ARCH__)
@VECTORS@
v8 W;
__builtin_memcpy(&W, &ip, 32);
W = W / 3.14159265358979323846f;
const v8 L0 = sat(sat(one, F0), W), L1 = sat(sat(one, F1), W), L2 = sat(sat(one, F2), W);
O0 = on ? O0 + L0 : O0; O1 = on ? O1 + L1 : O1; O2 = on ? O2 + L2 : O2;  // (the lanes no shadow ray was blocked for)
@STORE@
#else
@SAT_LANE@
for (int l = 0; l < 8; ++l) {
    if (!((lit >> l) & 1)) continue;  // (not drawn, or blocked)
    const float w = ip[l] / 3.14159265358979323846f;
    out_r[l] = out_r[l] + sat(sat(1.0f, fr[l]), w);
    out_g[l] = out_g[l] + sat(sat(1.0f, fg[l]), w);
    out_b[l] = out_b[l] + sat(sat(1.0f, fb[l]), w);
}
#endif
""")


@wp.func_native(_AREA_SUMS)
def area_sums(lit: int, ip: PacketF, fr: PacketF, fg: PacketF, fb: PacketF, out_r: wp.ref[PacketF],
              out_g: wp.ref[PacketF], out_b: wp.ref[PacketF]):
    """See above."""
    ...


@wp.func(inline=True)
def lobe_colour(sp: ShadePacket, k: int, nl: float, hl: float, nh: float) -> wp.vec3:
    """``blinn_phong``'s colour for lane k of a packet's shading points from its n·l, |l + v| and
    n·(l + v)/|l + v| (``lobe_packet``, ``point_light_packet``): the same operations."""
    ks = wp.vec3(lane(sp.ksr, k), lane(sp.ksg, k), lane(sp.ksb, k))
    spec = float(0.0)
    if hl > 0.0 and wp.max(ks) > 0.0:
        spec = phong_power(nh, lane(sp.p_exp, k))
    return wp.vec3(lane(sp.kdr, k), lane(sp.kdg, k), lane(sp.kdb, k)) * nl + ks * spec

@wp.func(inline=True)
def map_samples(scene: SceneData, x: int, y: int) -> int:
    """The shadow rays per camera sample that the split map (``DeviceScene.set_light_map``) gives
    "auto" lights at raster pixel (x, y); 0 without a map."""
    if scene.split_tile <= 0:
        return 0
    return scene.split_n[(y // scene.split_tile) * scene.split_tx + x // scene.split_tile]


@wp.func(inline=True)
def light_count(scene: SceneData, j: int, map_n: int) -> int:
    """Area light j's shadow rays per camera sample: its row's, or where the row holds 0 (an
    "auto" light under a split map) the pixel's ``map_n``."""
    ns = scene.alights[j].samples
    if ns == 0:
        ns = wp.max(map_n, 1)
    return ns


@build_once
def make_lights(F: Features) -> SimpleNamespace:
    """The direct-lighting device functions for one feature set (built once per process)."""
    shadow = make_trace(F).shadow
    transmittance = make_trace(F).transmittance
    occluded_packet = make_trace(F).occluded_packet

    @wp.func(inline=True)
    def one_area_light(scene: SceneData, params: RenderParams, j: int, pkey: wp.uint32, sample: int,
                       key: wp.uint32, p: wp.vec3, origin: wp.vec3, ng: wp.vec3, n: wp.vec3, v: wp.vec3,
                       kd: wp.vec3, ks: wp.vec3, p_exp: float, time: float, map_n: int) -> wp.vec4:
        """Area light j's part of ``area_lights_direct`` (rgb, shadow rays used in w); ``map_n``:
        the pixel's count for "auto" lights (``map_samples``)."""
        ns = light_count(scene, j, map_n)
        acc = wp.vec3(0.0, 0.0, 0.0)
        rays = int(0)
        dim = hash2(key, wp.uint32(LIGHT_DIM_BASE + j))
        kind = scene.alights[j].kind
        row = scene.alights[j].shape
        own_rect = int(-1)  # (a rectangle light's shadow rays never test the rectangle: trace.transmittance)
        if kind == KIND_RECT:
            own_rect = row
        prep = prepare_emitter(scene, kind, row, p, n, params.light_sampling)  # once for the ns draws
        if prep.ok == 0:
            return wp.vec4(0.0, 0.0, 0.0, 0.0)  # no light from it reaches p
        for k in range(ns):
            u = light_sample_2d(params.sampler, pkey, sample, ns, k, params.spp, dim)
            e = sample_emitter(scene, kind, row, prep, p, u)
            if e.ok == 0:
                continue
            if wp.dot(ng, e.l) <= 0.0:
                continue
            f = blinn_phong(n, e.l, v, kd, ks, p_exp)
            if wp.max(f) <= 0.0:
                continue
            rays += 1
            T = shadow(scene, origin, e.y, 2.0 * spawn_offset(e.mag), time, own_rect)
            if wp.max(T) <= 0.0:
                continue
            acc += mul_sat(mul_sat(T, f), wp.vec3(e.inv_pdf / wp.pi))
        L = mul_sat(scene.alights[j].le, acc) / float(ns)
        return wp.vec4(L[0], L[1], L[2], float(rays))

    @wp.func
    def area_lights_direct(scene: SceneData, params: RenderParams, pkey: wp.uint32, sample: int, key: wp.uint32,
                           p: wp.vec3, origin: wp.vec3, ng: wp.vec3, n: wp.vec3, v: wp.vec3, kd: wp.vec3, ks: wp.vec3,
                           p_exp: float, time: float, map_n: int) -> wp.vec4:
        """Direct light from the area lights: ``samples`` stratified shadow rays per light (rgb,
        shadow rays used in w). ``pkey`` is the pixel's ``pixel_key``; ``ng``/``n`` are the
        geometric/shading normals turned towards the viewer, ``v`` the direction to it; ``map_n``
        the pixel's count for "auto" lights (``map_samples``)."""
        L = wp.vec3(0.0, 0.0, 0.0)
        rays = int(0)
        for j in range(scene.n_alights):
            a = one_area_light(scene, params, j, pkey, sample, key, p, origin, ng, n, v, kd, ks, p_exp, time, map_n)
            L += wp.vec3(a[0], a[1], a[2])
            rays += int(a[3])
        return wp.vec4(L[0], L[1], L[2], float(rays))

    @wp.func(inline=True)
    def area_lights_packet(scene: SceneData, params: RenderParams, sp: ShadePacket, lanes: int,
                           live: int, skip: PacketI, face: PacketI) -> LightPacket:
        """``area_lights_direct`` for the shading points of a camera packet (lanes 0 to ``lanes``
        - 1 whose bit is set in ``live``; their path key is the camera ray's, ROOT_KEY), each
        lane's sum the same as alone, bit for bit: a rectangle's set-up and draws for all lanes
        at once (``shapes.rect_setup_packet``, ``rect_draw_packet``; with Sobol and a
        power-of-two ``samples``, the lanes' s-th draws in one quarter of the light:
        ``sampling.sobol_split_index``), then the lanes' shadow rays together; other emitters,
        and lanes a rectangle is drawn for by solid angle, one lane at a time. ``skip[k]`` = i + 1
        where lane k's point is on a face of mesh instance i with escape horizons, ``face[k]``
        that face and side (its shadow rays above them pass that instance:
        ``trace.occluded_packet``), else 0."""
        out = LightPacket()
        glossy = sp.glossy
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
        fr = PacketF()
        fg = PacketF()
        fb = PacketF()
        sx = PacketF()
        sy = PacketF()
        sz = PacketF()
        st = PacketF()
        nl = PacketF()
        hl = PacketF()
        nh = PacketF()
        for j in range(scene.n_alights):
            todo = live
            while todo != 0:
                # the lanes with one count of shadow rays together (with a split map, an "auto" light's
                # count is the lane's pixel's: the lanes of the first lane's count, then the others')
                ns = scene.alights[j].samples
                group = todo
                if ns == 0:
                    first = int(0)
                    while (todo >> first) & 1 == 0:
                        first += 1
                    ns = light_count(scene, j, lane_i(sp.ns, first))
                    group = int(0)
                    for k in range(lanes):
                        if (todo >> k) & 1 != 0 and light_count(scene, j, lane_i(sp.ns, k)) == ns:
                            group = group | (1 << k)
                todo = todo & ~group
                dim = hash2(wp.uint32(ROOT_KEY), wp.uint32(LIGHT_DIM_BASE + j))
                scalar = group
                if scene.alights[j].kind == KIND_RECT:
                    rec = scene.rects[scene.alights[j].shape]
                    area = wp.length(wp.cross(rec.e1, rec.e2))
                    square = int(0)
                    if is_rectangle_edges(rec.e1, rec.e2):
                        square = 1
                    stop = 2.0 * spawn_offset(max_abs(rec.c) + max_abs(rec.e1) + max_abs(rec.e2))
                    # the lanes' set-up once (the cosine warp's knots), then their ns draws from it
                    knots = RectKnots()
                    ready = rect_setup_packet(rec.c, rec.e1, rec.e2, rec.n, params.light_sampling, square, group, sp.px,
                                              sp.py, sp.pz, sp.nx, sp.ny, sp.nz, knots)
                    scalar = ready >> 8
                    drawn = group & ~scalar
                    for k in range(PACKET):
                        ar[k] = 0.0
                        ag[k] = 0.0
                        ab[k] = 0.0
                    split = is_split_order(params.sampler, ns)
                    # (with sobol_packets switched off, warprt.fast, each lane draws its points alone)
                    together = (scene.fast_off & FAST_SOBOL_PACKETS) == 0
                    draws = SplitDraws()
                    if split and together:  # lane k's s-th point in the light's quadrant s % 4 (sobol_split_index)
                        sobol_split_setup(sp.key, sp.sample, ns, dim, draws)
                    for s in range(ns):
                        if split and together:
                            sobol_split_draw(draws, ns, s, ux, uy)
                        elif params.sampler == SAMPLER_SOBOL and together:
                            idx = PacketI()
                            for k in range(lanes):
                                idx[k] = sp.sample[k] * ns + s
                            sobol_packet(sp.key, idx, dim, ux, uy)  # the 8 lanes' points at once
                        else:
                            for k in range(lanes):
                                if (group >> k) & 1 != 0:
                                    u = light_sample_2d(params.sampler, sp.key[k], lane_i(sp.sample, k), ns, s, params.spp,
                                                        dim)
                                    ux[k] = u[0]
                                    uy[k] = u[1]
                        m = rect_draw_packet(rec.c, rec.e1, rec.e2, rec.n, area, params.light_sampling, ready & 255, knots,
                                             sp.px, sp.py, sp.pz, ux, uy, y0, y1, y2, l0, l1, l2, ip)
                        go = int(0)  # the lanes whose sample lights them if nothing is in the way
                        # blinn_phong for the lanes: its geometry at once, then each lane's colour (all
                        # lanes at once for Lambertian materials)
                        m = lobe_packet(m & 255, l0, l1, l2, sp.gx, sp.gy, sp.gz, sp.nx, sp.ny, sp.nz, sp.vx, sp.vy, sp.vz,
                                        nl, hl, nh)
                        if glossy == 0:
                            go = diffuse_lanes(m, sp.kdr, sp.kdg, sp.kdb, nl, fr, fg, fb, out.rays)
                        else:
                            for k in range(lanes):
                                if (m >> k) & 1 == 0:
                                    continue
                                f = lobe_colour(sp, k, nl[k], hl[k], nh[k])
                                if wp.max(f) <= 0.0:
                                    continue
                                lane_addi(out.rays, k, 1)
                                fr[k] = f[0]
                                fg[k] = f[1]
                                fb[k] = f[2]
                                go = go | (1 << k)
                        if go == 0:
                            continue
                        # the shadow rays of the lanes together (``shadow``'s set-up, then
                        # ``occluded_packet``; without secondary rays nothing is transparent)
                        test = shadow_rays_packet(go, sp.ox, sp.oy, sp.oz, y0, y1, y2, stop, sx, sy, sz, st)
                        shut = occluded_packet(scene, lanes, test, sp.ox, sp.oy, sp.oz, sx, sy, sz, st, sp.time, skip,
                                               face, scene.alights[j].shape, -1)
                        # each lit lane's mul_sat(mul_sat(1, f), ip / π), the 8 at once
                        area_sums(go & ~shut, ip, fr, fg, fb, ar, ag, ab)
                    for k in range(lanes):
                        if (drawn >> k) & 1 != 0:
                            L = mul_sat(scene.alights[j].le, wp.vec3(lane(ar, k), lane(ag, k), lane(ab, k))) / float(ns)
                            lane_add(out.r, k, L[0])
                            lane_add(out.g, k, L[1])
                            lane_add(out.b, k, L[2])
                for k in range(lanes):
                    if (scalar >> k) & 1 != 0:
                        q = one_area_light(scene, params, j, sp.key[k], lane_i(sp.sample, k), wp.uint32(ROOT_KEY),
                                           wp.vec3(lane(sp.px, k), lane(sp.py, k), lane(sp.pz, k)),
                                           wp.vec3(lane(sp.ox, k), lane(sp.oy, k), lane(sp.oz, k)),
                                           wp.vec3(lane(sp.gx, k), lane(sp.gy, k), lane(sp.gz, k)),
                                           wp.vec3(lane(sp.nx, k), lane(sp.ny, k), lane(sp.nz, k)),
                                           wp.vec3(lane(sp.vx, k), lane(sp.vy, k), lane(sp.vz, k)),
                                           wp.vec3(lane(sp.kdr, k), lane(sp.kdg, k), lane(sp.kdb, k)),
                                           wp.vec3(lane(sp.ksr, k), lane(sp.ksg, k), lane(sp.ksb, k)), lane(sp.p_exp, k),
                                           lane(sp.time, k), lane_i(sp.ns, k))
                        lane_add(out.r, k, q[0])
                        lane_add(out.g, k, q[1])
                        lane_add(out.b, k, q[2])
                        lane_addi(out.rays, k, int(q[3]))
        return out

    @wp.func
    def point_lights_packet(scene: SceneData, sp: ShadePacket, lanes: int, live: int, skip: PacketI,
                            face: PacketI) -> LightPacket:
        """``point_lights_direct`` for the shading points of a camera packet (lanes 0 to ``lanes`` - 1
        whose bit is set in ``live``), each lane's sum the same as alone, bit for bit: per light,
        the geometry for all lanes at once (``point_light_packet``), each lane's colour, then the
        lanes' shadow rays together (``occluded_packet``; a kernel without secondary rays has no
        transparent materials); ``skip`` and ``face`` as for ``area_lights_packet``."""
        out = LightPacket()
        glossy = sp.glossy
        dist = PacketF()
        nl = PacketF()
        hl = PacketF()
        nh = PacketF()
        sx = PacketF()
        sy = PacketF()
        sz = PacketF()
        st = PacketF()
        fr = PacketF()
        fg = PacketF()
        fb = PacketF()
        for i in range(scene.n_plights):
            pos = scene.plights[i].pos
            directional = int(0)
            if scene.plights[i].inv_sq == FALLOFF_DIRECTIONAL:
                directional = 1
            m = point_light_packet(pos, directional, spawn_offset(max_abs(pos)), live, sp.px, sp.py, sp.pz, sp.ox,
                                   sp.oy, sp.oz, sp.gx, sp.gy, sp.gz, sp.nx, sp.ny, sp.nz, sp.vx, sp.vy, sp.vz, dist,
                                   nl, hl, nh, sx, sy, sz, st)
            go = int(0)
            if glossy == 0:  # (Lambertian lanes' colours at once, as for the area lights)
                go = diffuse_lanes(m & 255, sp.kdr, sp.kdg, sp.kdb, nl, fr, fg, fb, out.rays)
            else:
                for k in range(PACKET):
                    if (m >> k) & 1 == 0:
                        continue
                    f = lobe_colour(sp, k, nl[k], hl[k], nh[k])
                    if wp.max(f) <= 0.0:
                        continue
                    out.rays[k] += 1
                    fr[k] = f[0]
                    fg[k] = f[1]
                    fb[k] = f[2]
                    go = go | (1 << k)
            if go == 0:
                continue
            blocked = occluded_packet(scene, lanes, go & (m >> 16), sp.ox, sp.oy, sp.oz, sx, sy, sz, st, sp.time, skip,
                                      face, -1, i)
            lit = go & ~blocked
            # each lit lane's mul_sat(1, mul_sat(I, f)), the 8 at once
            inv_sq = int(0)
            if scene.plights[i].inv_sq == 1:
                inv_sq = 1
            point_sums(lit, scene.plights[i].intensity, inv_sq, dist, fr, fg, fb, out.r, out.g, out.b)
        return out

    @wp.func(inline=True)
    def point_lights_direct(scene: SceneData, p: wp.vec3, origin: wp.vec3, kd: wp.vec3, ks: wp.vec3, p_exp: float,
                            ng: wp.vec3, n: wp.vec3, v: wp.vec3, time: float) -> wp.vec4:
        """Light reaching the viewer from the point lights (rgb, shadow rays used in w) at a
        point of diffuse kd and specular ks, p_exp."""
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
                T = transmittance(scene, origin, d_sh, t_sh, time, -1)
            if wp.max(T) <= 0.0:
                continue
            I = scene.plights[i].intensity
            if scene.plights[i].inv_sq == 1:
                I = I / (dist * dist)
            L += mul_sat(T, mul_sat(I, f))
        return wp.vec4(L[0], L[1], L[2], float(rays))

    return SimpleNamespace(point_lights_direct=point_lights_direct, area_lights_direct=area_lights_direct,
                           area_lights_packet=area_lights_packet, point_lights_packet=point_lights_packet)
