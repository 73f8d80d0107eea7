"""Random numbers, pixel samplers and sampling maps (Warp device functions).

Replayable randomness: every sample value is a pure function of (seed, pixel, sample index,
dimension). Nothing depends on the thread id, the tile or the pass, so an image is bit-identical
for any tiling, worker count or pass split.

A *dimension* is a 32-bit key naming one 2D sample of a camera sample: the film position, the
lens position, the time, a light sample at some bounce, a glossy direction... Keys are hashed,
so they need not be contiguous.

Samplers (``RenderSettings.sampler``):

* ``regular``: the n_x × n_y stratum centres, identical in every pixel (aliases, on purpose);
* ``independent``: uniform random numbers;
* ``stratified``: one jittered sample in each of the n_x × n_y strata, visited in a per-pixel
  random order in every dimension (padding), so lens and light samples are stratified and
  decorrelated from the film position; ``sample_1d`` (the shutter time) stratifies [0, 1) into
  spp intervals;
* ``sobol``: Owen-scrambled Sobol (0,2)-sequence points, shuffled and scrambled per pixel and
  dimension (Burley 2020, "Practical hash-based Owen scrambling"); every power-of-two prefix of
  a pixel's samples is a (0, m, 2)-net in every 2D dimension.

Sampling maps come with their densities: ``square_to_disk`` (concentric), ``square_to_cone``
(uniform in a cone), ``square_to_cos_power`` (Phong lobe cos^n about +z).
"""

from __future__ import annotations

import warp as wp

from .scene.description import SAMPLERS

SAMPLER_IDS = {name: i for i, name in enumerate(SAMPLERS)}  # RenderParams.sampler
SAMPLER_REGULAR = SAMPLER_IDS["regular"]
SAMPLER_INDEPENDENT = SAMPLER_IDS["independent"]
SAMPLER_STRATIFIED = SAMPLER_IDS["stratified"]
SAMPLER_SOBOL = SAMPLER_IDS["sobol"]

INV_2_24 = 1.0 / 16777216.0

# 32-bit constants at or above 2^31, typed (a bare literal would be emitted as int32)
_C80000000 = wp.constant(wp.uint32(0x80000000))
_C846CA68B = wp.constant(wp.uint32(0x846CA68B))
_C8D22F6E6 = wp.constant(wp.uint32(0x8D22F6E6))
_C9E3779B9 = wp.constant(wp.uint32(0x9E3779B9))
_CA511E9B3 = wp.constant(wp.uint32(0xA511E9B3))
_CB82F1E52 = wp.constant(wp.uint32(0xB82F1E52))
_CC7AFE638 = wp.constant(wp.uint32(0xC7AFE638))


# --- hashing --------------------------------------------------------------------------------


@wp.func
def hash_u32(x: wp.uint32) -> wp.uint32:
    """A 32-bit integer finaliser with low bias (xorshift-multiply; Wellons' "lowbias32")."""
    x = x ^ (x >> wp.uint32(16))
    x = x * wp.uint32(0x7FEB352D)
    x = x ^ (x >> wp.uint32(15))
    x = x * _C846CA68B
    x = x ^ (x >> wp.uint32(16))
    return x


@wp.func
def hash2(a: wp.uint32, b: wp.uint32) -> wp.uint32:
    """Hash of an ordered pair (a is typically a running hash, b a new key)."""
    return hash_u32(a ^ (hash_u32(b) + _C9E3779B9 + (a << wp.uint32(6)) + (a >> wp.uint32(2))))


@wp.func
def u32_to_unit(x: wp.uint32) -> float:
    """Map 32 random bits to a float in [0, 1) (24 bits, so 1.0 is never returned)."""
    return float(x >> wp.uint32(8)) * INV_2_24


@wp.func
def pixel_key(seed: wp.uint32, pixel: int) -> wp.uint32:
    return hash2(hash_u32(seed ^ _CA511E9B3), wp.uint32(pixel))


# --- bit tricks -------------------------------------------------------------------------------


@wp.func
def reverse_bits(x: wp.uint32) -> wp.uint32:
    x = ((x >> wp.uint32(1)) & wp.uint32(0x55555555)) | ((x & wp.uint32(0x55555555)) << wp.uint32(1))
    x = ((x >> wp.uint32(2)) & wp.uint32(0x33333333)) | ((x & wp.uint32(0x33333333)) << wp.uint32(2))
    x = ((x >> wp.uint32(4)) & wp.uint32(0x0F0F0F0F)) | ((x & wp.uint32(0x0F0F0F0F)) << wp.uint32(4))
    x = ((x >> wp.uint32(8)) & wp.uint32(0x00FF00FF)) | ((x & wp.uint32(0x00FF00FF)) << wp.uint32(8))
    return (x >> wp.uint32(16)) | (x << wp.uint32(16))


@wp.func
def owen_scramble(x: wp.uint32, seed: wp.uint32) -> wp.uint32:
    """Nested uniform (Owen) scrambling of the bits of x, approximated by a hash whose every step
    only carries information from less to more significant bits of the reversed word."""
    x = reverse_bits(x)
    x = x + seed
    x = x ^ (x * wp.uint32(0x6C50B47C))
    x = x ^ (x * _CB82F1E52)
    x = x ^ (x * _CC7AFE638)
    x = x ^ (x * _C8D22F6E6)
    return reverse_bits(x)


@wp.func
def sobol_dim1(index: wp.uint32) -> wp.uint32:
    """Second dimension of the Sobol sequence (the first is the bit-reversed index)."""
    r = wp.uint32(0)
    v = _C80000000
    i = index
    while i != wp.uint32(0):
        if (i & wp.uint32(1)) != wp.uint32(0):
            r = r ^ v
        i = i >> wp.uint32(1)
        v = v ^ (v >> wp.uint32(1))
    return r


@wp.func
def permute(i: int, n: int, key: wp.uint32) -> int:
    """Element i of a pseudo-random permutation of [0, n) chosen by key (cycle walking over a
    bijection of the smallest power-of-two range that holds n)."""
    if n <= 1:
        return 0
    mask = wp.uint32(n - 1)
    mask = mask | (mask >> wp.uint32(1))
    mask = mask | (mask >> wp.uint32(2))
    mask = mask | (mask >> wp.uint32(4))
    mask = mask | (mask >> wp.uint32(8))
    mask = mask | (mask >> wp.uint32(16))
    bits = int(0)
    m = mask
    while m != wp.uint32(0):
        bits += 1
        m = m >> wp.uint32(1)
    shift = wp.uint32(wp.max(1, bits / 2))
    k1 = hash2(key, wp.uint32(1))
    k2 = hash2(key, wp.uint32(2))
    k3 = hash2(key, wp.uint32(3))
    x = wp.uint32(i)
    while True:
        # each step is a bijection of [0, mask]
        x = (x + k1) & mask
        x = (x * (k2 | wp.uint32(1))) & mask
        x = x ^ (x >> shift)
        x = (x + k3) & mask
        x = (x * wp.uint32(0x2C1B3C6D)) & mask
        x = x ^ (x >> shift)
        if int(x) < n:
            break
    return int(x)


# --- samplers -------------------------------------------------------------------------------


@wp.func
def grid_shape_x(n: int) -> int:
    """Columns of the most nearly square grid nx × ny = n (nx >= ny)."""
    ny = int(wp.floor(wp.sqrt(float(n)) + 1.0e-3))
    while ny > 1 and n % ny != 0:
        ny -= 1
    return n / ny


@wp.func
def sample_2d(sampler: int, seed: wp.uint32, pixel: int, index: int, spp: int, dim: wp.uint32) -> wp.vec2:
    """The 2D sample of dimension ``dim`` for sample ``index`` of ``pixel`` (spp samples planned)."""
    pkey = pixel_key(seed, pixel)
    key = hash2(pkey, dim)
    if sampler == SAMPLER_INDEPENDENT:
        h = hash2(key, wp.uint32(index))
        return wp.vec2(u32_to_unit(h), u32_to_unit(hash_u32(h ^ wp.uint32(0x68E31DA4))))
    if sampler == SAMPLER_SOBOL:  # Owen-scrambled, shuffled Sobol
        i = owen_scramble(wp.uint32(index), hash2(key, wp.uint32(0x5B0)))
        x = owen_scramble(reverse_bits(i), hash2(key, wp.uint32(0x5B1)))
        y = owen_scramble(sobol_dim1(i), hash2(key, wp.uint32(0x5B2)))
        return wp.vec2(u32_to_unit(x), u32_to_unit(y))
    # regular and stratified: an nx × ny grid of strata, one sample each
    n = wp.max(spp, 1)
    nx = grid_shape_x(n)
    ny = n / nx
    rnd = index / n  # samples beyond spp start a new round of strata
    s = index - rnd * n
    if sampler == SAMPLER_REGULAR:
        if dim != wp.uint32(0):
            s = permute(s, n, hash2(hash_u32(dim), wp.uint32(rnd)))  # same order in every pixel
        return wp.vec2((float(s % nx) + 0.5) / float(nx), (float(s / nx) + 0.5) / float(ny))
    s = permute(s, n, hash2(key, wp.uint32(rnd)))
    h = hash2(hash2(key, wp.uint32(0x7A3)), wp.uint32(index))
    jx = u32_to_unit(h)
    jy = u32_to_unit(hash_u32(h ^ wp.uint32(0x68E31DA4)))
    return wp.vec2((float(s % nx) + jx) / float(nx), (float(s / nx) + jy) / float(ny))


@wp.func
def sample_1d(sampler: int, seed: wp.uint32, pixel: int, index: int, spp: int, dim: wp.uint32) -> float:
    """The 1D sample of dimension ``dim`` for sample ``index`` of ``pixel`` (spp samples planned).

    ``regular``: the centres of spp equal strata of [0, 1), in the same shuffled order in every
    pixel; ``stratified``: one jittered sample in each of the spp strata, strata shuffled per pixel
    (a 2D grid would fill only nx of the spp strata along one axis); ``independent`` and
    ``sobol``: the first coordinate of ``sample_2d`` (Sobol's first dimension, scrambled van der
    Corput, is already stratified at every power-of-two prefix)."""
    if sampler == SAMPLER_INDEPENDENT or sampler == SAMPLER_SOBOL:
        return sample_2d(sampler, seed, pixel, index, spp, dim)[0]
    key = hash2(pixel_key(seed, pixel), dim)
    n = wp.max(spp, 1)
    rnd = index / n  # samples beyond spp start a new round of strata
    s = index - rnd * n
    if sampler == SAMPLER_REGULAR:
        s = permute(s, n, hash2(hash_u32(dim), wp.uint32(rnd)))  # same order in every pixel
        return (float(s) + 0.5) / float(n)
    s = permute(s, n, hash2(hash2(key, wp.uint32(0x1D)), wp.uint32(rnd)))
    j = u32_to_unit(hash2(hash2(key, wp.uint32(0x7A4)), wp.uint32(index)))
    return (float(s) + j) / float(n)


# --- sampling maps -------------------------------------------------------------------------------


@wp.func
def square_to_disk(u: wp.vec2) -> wp.vec2:
    """Concentric map (Shirley-Chiu) of [0,1)^2 onto the unit disk; density 1/π."""
    a = 2.0 * u[0] - 1.0
    b = 2.0 * u[1] - 1.0
    if a == 0.0 and b == 0.0:
        return wp.vec2(0.0, 0.0)
    r = float(0.0)
    phi = float(0.0)
    if wp.abs(a) > wp.abs(b):
        r = a
        phi = (wp.pi / 4.0) * (b / a)
    else:
        r = b
        phi = (wp.pi / 2.0) - (wp.pi / 4.0) * (a / b)
    return wp.vec2(r * wp.cos(phi), r * wp.sin(phi))


@wp.func
def square_to_cone(u: wp.vec2, one_minus_cos_max: float) -> wp.vec3:
    """Uniform direction in the cone of half-angle θmax about +z, given 1 - cos θmax (passed as is,
    so tiny cones keep their precision); density 1/(2π(1 - cos θmax))."""
    a = u[0] * one_minus_cos_max  # 1 - cos θ
    cos_t = 1.0 - a
    sin_t = wp.sqrt(wp.max(0.0, a * (2.0 - a)))
    phi = 2.0 * wp.pi * u[1]
    return wp.vec3(sin_t * wp.cos(phi), sin_t * wp.sin(phi), cos_t)


@wp.func
def square_to_cos_power(u: wp.vec2, n: float) -> wp.vec3:
    """Direction about +z with density (n+1)/(2π)·cos^n θ (the normalised Phong lobe)."""
    cos_t = wp.pow(wp.max(1.0 - u[0], 1.0e-30), 1.0 / (n + 1.0))
    sin_t = wp.sqrt(wp.max(0.0, 1.0 - cos_t * cos_t))
    phi = 2.0 * wp.pi * u[1]
    return wp.vec3(sin_t * wp.cos(phi), sin_t * wp.sin(phi), cos_t)


@wp.func
def frame_from_z(z: wp.vec3, local: wp.vec3) -> wp.vec3:
    """Rotate a direction given about +z into the frame whose z axis is the unit vector z
    (branchless orthonormal basis of Duff et al. 2017)."""
    sign = wp.where(z[2] >= 0.0, 1.0, -1.0)
    a = -1.0 / (sign + z[2])
    b = z[0] * z[1] * a
    t = wp.vec3(1.0 + sign * z[0] * z[0] * a, sign * b, -sign * z[0])
    s = wp.vec3(b, sign + z[1] * z[1] * a, -z[1])
    return local[0] * t + local[1] * s + local[2] * z

