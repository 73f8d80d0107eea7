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
(uniform in a cone), ``square_to_cos_power`` (Phong lobe cos^n about +z),
``square_to_spherical_rect`` (a rectangle uniformly in the solid angle it subtends, density 1/Ω;
see the section at the end of this module).
"""

from __future__ import annotations

import warp as wp

from .accel import PacketF, PacketI, PacketU
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
    """Second dimension of the Sobol sequence (the first is the bit-reversed index).

    Its generator matrix is Pascal's triangle mod 2, so by Lucas' theorem the point is the index
    run through the prefix-xor ``y ^= (y >> b) & mask`` for b = 1, 2, 4, 8, 16, bit-reversed:
    five branch-free steps instead of a loop over the (scrambled, so unpredictable) index bits."""
    y = index
    y = y ^ ((y >> wp.uint32(1)) & wp.uint32(0x55555555))
    y = y ^ ((y >> wp.uint32(2)) & wp.uint32(0x33333333))
    y = y ^ ((y >> wp.uint32(4)) & wp.uint32(0x0F0F0F0F))
    y = y ^ ((y >> wp.uint32(8)) & wp.uint32(0x00FF00FF))
    y = y ^ ((y >> wp.uint32(16)) & wp.uint32(0x0000FFFF))
    return reverse_bits(y)


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
    return sample_2d_keyed(sampler, pixel_key(seed, pixel), index, spp, dim)


@wp.func
def sobol_point(key: wp.uint32, i: wp.uint32) -> wp.vec2:
    """Point i of the Sobol (0,2)-sequence, both coordinates Owen-scrambled by the dimension's
    ``key`` (``sample_2d_keyed``'s Sobol branch after its index shuffle)."""
    x = owen_scramble(reverse_bits(i), hash2(key, wp.uint32(0x5B1)))
    y = owen_scramble(sobol_dim1(i), hash2(key, wp.uint32(0x5B2)))
    return wp.vec2(u32_to_unit(x), u32_to_unit(y))


@wp.func
def parity(x: wp.uint32) -> wp.uint32:
    """The xor of x's 32 bits."""
    p = x ^ (x >> wp.uint32(16))
    p = p ^ (p >> wp.uint32(8))
    p = p ^ (p >> wp.uint32(4))
    p = p ^ (p >> wp.uint32(2))
    p = p ^ (p >> wp.uint32(1))
    return p & wp.uint32(1)


@wp.func
def sobol_split_index(key: wp.uint32, sample: int, ns: int, k: int) -> wp.uint32:
    """The shuffled Sobol index of light sample k of camera sample ``sample`` (``ns`` a power of
    two, at least 2), drawn in quadrant order.

    ``sample_2d_keyed`` would draw it at ``owen_scramble(sample * ns + k)``. That shuffle is a
    nested scramble: its output's bits from m = log2(ns) up depend only on the input's bits from m
    up, so the ns draws of one camera sample are the aligned block ``base`` + [0, ns) whatever k,
    and which of them comes k-th is free. Here the k-th is the block's point in the light square's
    quadrant k % 4 (the x half for ns = 2): the first digit of x is the index's bit 0 flipped by
    x's scramble, of y the index's parity flipped by y's (Sobol's second dimension starts with the
    xor of all the index's bits). A camera packet's lanes then send their k-th shadow rays towards
    one quadrant of the light, whichever pixel or sample they are (``lights.area_lights_packet``),
    and each camera sample's sum is over the same ns points as with the plain order."""
    m = wp.uint32(ns - 1)
    base = owen_scramble(wp.uint32(sample * ns), hash2(key, wp.uint32(0x5B0))) & ~m
    kk = wp.uint32(k)
    b0 = (kk ^ hash2(key, wp.uint32(0x5B1))) & wp.uint32(1)
    low = b0 | (kk & ~wp.uint32(3))
    if ns >= 4:
        qy = (kk >> wp.uint32(1)) & wp.uint32(1)
        b1 = (qy ^ hash2(key, wp.uint32(0x5B2)) ^ parity(base | low)) & wp.uint32(1)
        low = low | (b1 << wp.uint32(1))
    return base | low


@wp.func
def is_split_order(sampler: int, ns: int) -> bool:
    """Whether light samples are drawn in quadrant order (``sobol_split_index``)."""
    return sampler == SAMPLER_SOBOL and ns >= 2 and (ns & (ns - 1)) == 0


@wp.func
def light_sample_2d(sampler: int, pkey: wp.uint32, sample: int, ns: int, k: int, spp: int, dim: wp.uint32) -> wp.vec2:
    """Light sample k of the ``ns`` per camera sample ``sample``: ``sample_2d_keyed`` at index
    ``sample * ns + k``, the Sobol draws of a power-of-two ns in quadrant order
    (``sobol_split_index``)."""
    if is_split_order(sampler, ns):
        key = hash2(pkey, dim)
        return sobol_point(key, sobol_split_index(key, sample, ns, k))
    return sample_2d_keyed(sampler, pkey, sample * ns + k, spp * ns, dim)


@wp.func
def sample_2d_keyed(sampler: int, pkey: wp.uint32, index: int, spp: int, dim: wp.uint32) -> wp.vec2:
    """``sample_2d`` for the pixel whose ``pixel_key(seed, pixel)`` is ``pkey`` (a kernel computes
    it once per pixel rather than once per sample and dimension)."""
    key = hash2(pkey, dim)
    if sampler == SAMPLER_INDEPENDENT:
        h = hash2(key, wp.uint32(index))
        return wp.vec2(u32_to_unit(h), u32_to_unit(hash_u32(h ^ wp.uint32(0x68E31DA4))))
    if sampler == SAMPLER_SOBOL:  # Owen-scrambled, shuffled Sobol
        return sobol_point(key, owen_scramble(wp.uint32(index), hash2(key, wp.uint32(0x5B0))))
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
    return sample_1d_keyed(sampler, pixel_key(seed, pixel), index, spp, dim)


@wp.func
def sample_1d_keyed(sampler: int, pkey: wp.uint32, index: int, spp: int, dim: wp.uint32) -> float:
    """``sample_1d`` for the pixel whose ``pixel_key(seed, pixel)`` is ``pkey``."""
    if sampler == SAMPLER_INDEPENDENT or sampler == SAMPLER_SOBOL:
        return sample_2d_keyed(sampler, pkey, index, spp, dim)[0]
    key = hash2(pkey, dim)
    n = wp.max(spp, 1)
    rnd = index / n  # samples beyond spp start a new round of strata
    s = index - rnd * n
    if sampler == SAMPLER_REGULAR:
        s = permute(s, n, hash2(hash_u32(dim), wp.uint32(rnd)))  # same order in every pixel
        return (float(s) + 0.5) / float(n)
    s = permute(s, n, hash2(hash2(key, wp.uint32(0x1D)), wp.uint32(rnd)))
    j = u32_to_unit(hash2(hash2(key, wp.uint32(0x7A4)), wp.uint32(index)))
    return (float(s) + j) / float(n)



# ``sample_2d_keyed``'s Sobol points for the 8 lanes of a packet at once (each lane its pixel key
# and sample index, one dimension key): the same integer hashes and scrambles as clang vectors
# on the CPU, so every lane's point is the scalar one bit for bit; lane by lane elsewhere.
_SOBOL_FUNCTIONS = r"""
// the scalar functions' operations, for one lane (unsigned) or for 8 (clang vectors)
auto hash_u32 = [](auto x) {
    x = x ^ (x >> 16u); x = x * 0x7FEB352Du; x = x ^ (x >> 15u); x = x * 0x846CA68Bu; x = x ^ (x >> 16u);
    return x;
};
auto hash2 = [&](auto a, unsigned b) { return hash_u32(a ^ (((hash_u32(b) + 0x9E3779B9u) + (a << 6u)) + (a >> 2u))); };
auto reverse_bits = [](auto x) {
    x = ((x >> 1u) & 0x55555555u) | ((x & 0x55555555u) << 1u);
    x = ((x >> 2u) & 0x33333333u) | ((x & 0x33333333u) << 2u);
    x = ((x >> 4u) & 0x0F0F0F0Fu) | ((x & 0x0F0F0F0Fu) << 4u);
    x = ((x >> 8u) & 0x00FF00FFu) | ((x & 0x00FF00FFu) << 8u);
    return (x >> 16u) | (x << 16u);
};
auto owen = [&](auto x, auto seed) {
    x = reverse_bits(x);
    x = x + seed;
    x = x ^ (x * 0x6C50B47Cu); x = x ^ (x * 0xB82F1E52u); x = x ^ (x * 0xC7AFE638u); x = x ^ (x * 0x8D22F6E6u);
    return reverse_bits(x);
};
// sobol_point: point i's coordinates, scrambled with the dimension's seeds for x (sx) and y (sy)
auto scramble = [&](auto i, auto sx, auto sy, auto& x, auto& y) {
    x = owen(reverse_bits(i), sx);
    auto z = i;
    z = z ^ ((z >> 1u) & 0x55555555u); z = z ^ ((z >> 2u) & 0x33333333u); z = z ^ ((z >> 4u) & 0x0F0F0F0Fu);
    z = z ^ ((z >> 8u) & 0x00FF00FFu); z = z ^ ((z >> 16u) & 0x0000FFFFu);
    y = owen(reverse_bits(z), sy);
};
"""
# the 8 lanes' points as floats (``u32_to_unit``) from their scrambled integers X, Y: @VECTORS@
# makes them as clang vectors on the CPU, @LANE@ lane l's elsewhere
_SOBOL_OUT = r"""
#if defined(__clang__) && !defined(__CUDA_ARCH__)
typedef unsigned int u8v __attribute__((ext_vector_type(8)));
typedef float v8 __attribute__((ext_vector_type(8)));
u8v X, Y;
@VECTORS@
const v8 fx = __builtin_convertvector(X >> 8u, v8) * 5.9604644775390625e-08f;
const v8 fy = __builtin_convertvector(Y >> 8u, v8) * 5.9604644775390625e-08f;
__builtin_memcpy(&out_x, &fx, 32);
__builtin_memcpy(&out_y, &fy, 32);
#else
for (int l = 0; l < 8; ++l) {
    unsigned X, Y;
    @LANE@
    out_x[l] = (float)(X >> 8u) * 5.9604644775390625e-08f;
    out_y[l] = (float)(Y >> 8u) * 5.9604644775390625e-08f;
}
#endif
"""
_SOBOL_PACKET = _SOBOL_FUNCTIONS + r"""
// sample_2d_keyed's Sobol branch: the shuffled index, then both coordinates scrambled
auto point = [&](auto K, auto I, auto& x, auto& y) {
    const auto key = hash2(K, dim);
    scramble(owen(I, hash2(key, 0x5B0u)), hash2(key, 0x5B1u), hash2(key, 0x5B2u), x, y);
};
""" + _SOBOL_OUT.replace("@VECTORS@", """u8v K, I;
__builtin_memcpy(&K, &keys, 32);
__builtin_memcpy(&I, &index, 32);
point(K, I, X, Y);""").replace("@LANE@", "point((unsigned)keys[l], (unsigned)index[l], X, Y);")
# sobol_split_index for a packet's lanes in two steps: once per light (``sobol_split_setup``) the
# seeds of x and y and the camera sample's block, ``base``, in a ``SplitDraws`` (rows 0 to 2, a
# column per lane); then for each draw k (``sobol_split_draw``) its low bits and the point
SplitDraws = wp.types.matrix(shape=(3, 8), dtype=wp.uint32)
_SOBOL_SPLIT_SETUP = _SOBOL_FUNCTIONS + r"""
auto setup = [&](auto K, auto I, auto& sx, auto& sy, auto& base) {
    const auto key = hash2(K, dim);
    sx = hash2(key, 0x5B1u);
    sy = hash2(key, 0x5B2u);
    base = owen(I * (unsigned)ns, hash2(key, 0x5B0u)) & ~(unsigned)(ns - 1);
};
#if defined(__clang__) && !defined(__CUDA_ARCH__)
typedef unsigned int u8v __attribute__((ext_vector_type(8)));
u8v K, I, SX, SY, B;
__builtin_memcpy(&K, &keys, 32);
__builtin_memcpy(&I, &sample, 32);
setup(K, I, SX, SY, B);
__builtin_memcpy(&out.data[0][0], &SX, 32);
__builtin_memcpy(&out.data[1][0], &SY, 32);
__builtin_memcpy(&out.data[2][0], &B, 32);
#else
for (int l = 0; l < 8; ++l) {
    unsigned sx, sy, base;
    setup((unsigned)keys[l], (unsigned)sample[l], sx, sy, base);
    out.data[0][l] = sx; out.data[1][l] = sy; out.data[2][l] = base;
}
#endif
"""
_SOBOL_SPLIT_DRAW = _SOBOL_FUNCTIONS + r"""
const unsigned kk = (unsigned)k;
auto parity = [](auto x) {
    x = x ^ (x >> 16u); x = x ^ (x >> 8u); x = x ^ (x >> 4u); x = x ^ (x >> 2u); x = x ^ (x >> 1u);
    return x & 1u;
};
auto draw = [&](auto sx, auto sy, auto base, auto& x, auto& y) {
    auto low = ((kk ^ sx) & 1u) | (kk & ~3u);
    if (ns >= 4) low = low | ((((((kk >> 1u) & 1u) ^ sy) ^ parity(base | low)) & 1u) << 1u);
    scramble(base | low, sx, sy, x, y);
};
""" + _SOBOL_OUT.replace("@VECTORS@", """u8v SX, SY, B;
__builtin_memcpy(&SX, &state.data[0][0], 32);
__builtin_memcpy(&SY, &state.data[1][0], 32);
__builtin_memcpy(&B, &state.data[2][0], 32);
draw(SX, SY, B, X, Y);""").replace("@LANE@", "draw(state.data[0][l], state.data[1][l], state.data[2][l], X, Y);")


@wp.func_native(_SOBOL_PACKET)
def sobol_packet(keys: PacketU, index: PacketI, dim: wp.uint32, out_x: wp.ref[PacketF], out_y: wp.ref[PacketF]):
    """``sample_2d_keyed(SAMPLER_SOBOL, keys[l], index[l], spp, dim)`` for the 8 lanes l."""
    ...


@wp.func_native(_SOBOL_SPLIT_SETUP)
def sobol_split_setup(keys: PacketU, sample: PacketI, ns: int, dim: wp.uint32, out: wp.ref[SplitDraws]):
    """The 8 lanes' part of ``sobol_split_index`` shared by the ns draws of camera sample
    ``sample[l]`` of the pixel keyed ``keys[l]`` in dimension ``dim`` (ns a power of two of at
    least 2: ``is_split_order``), for ``sobol_split_draw``."""
    ...


@wp.func_native(_SOBOL_SPLIT_DRAW)
def sobol_split_draw(state: SplitDraws, ns: int, k: int, out_x: wp.ref[PacketF], out_y: wp.ref[PacketF]):
    """``light_sample_2d(SAMPLER_SOBOL, keys[l], sample[l], ns, k, spp, dim)`` for the 8 lanes l,
    from ``sobol_split_setup``'s ``state`` for those keys, samples, ns and dimension."""
    ...


# --- sampling maps -------------------------------------------------------------------------------


# sin and cos on [-π/4, π/4] as polynomials (Cephes' sinf and cosf coefficients rounded to
# float32; within 1.1 ulp of the float64 values there, tests/test_sampling_maps.py), for the
# concentric map: written out operation by operation, so that a thin-lens camera packet
# (``camera.lens_packet``) computes its 8 lanes' disk points with the same float32 operations as
# clang vectors (libm's sinf and cosf can only be called lane by lane; ``camera_packet_rays`` in
# ``warprt.fast``).
QSIN3 = -0.16666655242443085
QSIN5 = 0.008332161232829094
QSIN7 = -0.00019515295571181923
QCOS4 = 0.04166664555668831
QCOS6 = -0.0013887316454201937
QCOS8 = 2.44331567955669e-05


@wp.func
def quarter_sin(x: float) -> float:
    """sin(x) for |x| <= π/4 (the polynomial above, Horner's order)."""
    x2 = x * x
    p = x2 * QSIN7
    p = p + QSIN5
    p = p * x2
    p = p + QSIN3
    p = p * x2
    p = p * x
    return x + p


@wp.func
def quarter_cos(x: float) -> float:
    """cos(x) for |x| <= π/4 (the polynomial above, Horner's order)."""
    x2 = x * x
    p = x2 * QCOS8
    p = p + QCOS6
    p = p * x2
    p = p + QCOS4
    p = p * x2
    p = p - 0.5
    p = p * x2
    return 1.0 + p


@wp.func
def square_to_disk(u: wp.vec2) -> wp.vec2:
    """Concentric map (Shirley-Chiu) of [0,1)^2 onto the unit disk; density 1/π. The angle is
    π/4·(b/a) where |a| > |b|, else π/2 − π/4·(a/b), whose cosine and sine are the sine and cosine
    of π/4·(a/b): both within [-π/4, π/4], where ``quarter_sin`` and ``quarter_cos`` hold."""
    a = 2.0 * u[0] - 1.0
    b = 2.0 * u[1] - 1.0
    if a == 0.0 and b == 0.0:
        return wp.vec2(0.0, 0.0)
    if wp.abs(a) > wp.abs(b):
        x = (wp.pi / 4.0) * (b / a)
        return wp.vec2(a * quarter_cos(x), a * quarter_sin(x))
    x = (wp.pi / 4.0) * (a / b)
    return wp.vec2(b * quarter_sin(x), b * quarter_cos(x))


@wp.func
def sample_linear(u: float, a: float, b: float) -> float:
    """x in [0, 1] with density 2((1 - x)·a + x·b)/(a + b) (a, b >= 0, a + b > 0): the root of
    the quadratic CDF (2a·x + (b - a)·x²)/(a + b) = u in the form that does not cancel when a ≈ b."""
    x = u * (a + b) / (a + wp.sqrt((1.0 - u) * a * a + u * b * b))
    if not (x >= 0.0):
        return 0.0  # u = a = 0
    return wp.min(x, 1.0)


@wp.func
def sample_two_linear(u: float, a: float, b: float, c: float) -> float:
    """x in [0, 1] with a density in proportion to the piecewise-linear function through a, b, c at
    x = 0, ½, 1 (all >= 0, not all 0): the half by its mass, then ``sample_linear`` in it.
    Monotone in u."""
    m0 = a + b
    m1 = b + c
    t = u * (m0 + m1)
    if t < m0:
        return 0.5 * sample_linear(wp.min(t / m0, 1.0), a, b)
    return 0.5 + 0.5 * sample_linear(wp.clamp((t - m0) / m1, 0.0, 1.0), b, c)


@wp.func
def grid_lerp(w: wp.mat33, i: int, y: float) -> float:
    """Column i of the knot grid (w[i, j]: x = i/2, y = j/2) interpolated at y."""
    if y < 0.5:
        t = 2.0 * y
        return (1.0 - t) * w[i, 0] + t * w[i, 1]
    t = 2.0 * y - 1.0
    return (1.0 - t) * w[i, 1] + t * w[i, 2]


@wp.struct
class GridWarp:
    """The set-up of ``square_to_grid_bilinear`` for one knot grid: the knots, the masses of the
    three rows (y = 0, ½, 1) that give y's marginal, and the whole mass (the density's norm). One
    shading point draws all its samples of a light from one set-up."""

    w: wp.mat33
    g0: float
    g1: float
    g2: float
    total: float


@wp.func
def grid_warp_setup(w: wp.mat33) -> GridWarp:
    """``GridWarp`` for the 3 × 3 knot values w[i, j] at (x, y) = (i/2, j/2) (all >= 0, not all 0)."""
    g = GridWarp()
    g.w = w
    g.g0 = w[0, 0] + 2.0 * w[1, 0] + w[2, 0]
    g.g1 = w[0, 1] + 2.0 * w[1, 1] + w[2, 1]
    g.g2 = w[0, 2] + 2.0 * w[1, 2] + w[2, 2]
    total = float(0.0)  # g0 + 2·g1 + g2, summed by columns as the density always has been
    for i in range(3):
        total += (w[i, 0] + 2.0 * w[i, 1] + w[i, 2]) * wp.where(i == 1, 2.0, 1.0)
    g.total = total
    return g


@wp.func(inline=True)
def grid_pdf_at(x: float, a: float, b: float, c: float, total: float) -> float:
    """The warp's density at x on the row whose knots (x = 0, ½, 1) are a, b, c."""
    f = float(0.0)
    if x < 0.5:
        f = a + (b - a) * (2.0 * x)
    else:
        f = b + (c - b) * (2.0 * x - 1.0)
    return 16.0 * f / total


@wp.func
def grid_warp_sample(g: GridWarp, u: wp.vec2) -> wp.vec3:
    """(x, y, density) of ``square_to_grid_bilinear`` from a set-up: the density comes from the
    row the draw of x interpolated anyway."""
    y = sample_two_linear(u[1], g.g0, g.g1, g.g2)
    a = grid_lerp(g.w, 0, y)
    b = grid_lerp(g.w, 1, y)
    c = grid_lerp(g.w, 2, y)
    x = sample_two_linear(u[0], a, b, c)
    return wp.vec3(x, y, grid_pdf_at(x, a, b, c, g.total))


@wp.func
def square_to_grid_bilinear(u: wp.vec2, w: wp.mat33) -> wp.vec2:
    """A point of the unit square with density in proportion to the bilinear interpolation of the
    3 × 3 knot values w[i, j] at (x, y) = (i/2, j/2) (all >= 0, not all 0): y from its marginal
    (piecewise linear: the trapezoid rule along x is exact), then x given y. The map is monotone
    in each coordinate, so stratified and low-discrepancy points stay so. Density:
    ``grid_bilinear_pdf``; many draws from one grid: ``grid_warp_setup`` and ``grid_warp_sample``."""
    q = grid_warp_sample(grid_warp_setup(w), u)
    return wp.vec2(q[0], q[1])


@wp.func
def grid_bilinear_pdf(q: wp.vec2, w: wp.mat33) -> float:
    """Density of ``square_to_grid_bilinear`` at q (with respect to area on the unit square)."""
    return grid_pdf_at(q[0], grid_lerp(w, 0, q[1]), grid_lerp(w, 1, q[1]), grid_lerp(w, 2, q[1]),
                       grid_warp_setup(w).total)


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


# --- spherical rectangles: solid-angle sampling of rectangle lights --------------------------------
#
# Ureña, Fajardo and King 2013, "An Area-Preserving Parametrization for Spherical Rectangles".
# Conventions: a rectangle is ``corner + a*e1 + b*e2`` with (a, b) in [0, 1]^2 and e1 ⟂ e2 (check
# with ``is_rectangle`` / ``is_rectangle_edges``; a sheared parallelogram must be area-sampled).
# Its one-sidedness does not matter here: the solid angle is sampled from either side.
#
# Local frame at the shading point p: x along e1, y along e2, the rectangle in the plane z = -h
# (h = distance from p to the rectangle's plane), spanning x in [x0, x0 + w], y in [y0, y0 + v].
# All lengths are divided by |corner - p| + |e1| + |e2| first (the map is scale-invariant), so no
# square or cube overflows however near or far p is.
#
# The sample is drawn in two steps, each the inverse of a cumulative solid angle:
#   u0 = S(x) / Ω, S(x) = solid angle of the sub-rectangle [x0, x] × [y0, y1]
#   u1 = (sinφ(y) - sinφ(y0)) / (sinφ(y1) - sinφ(y0)), sinφ(y) = y / sqrt(x² + h² + y²)
# (the second is the solid-angle density along the line at x, integrated in y).
#
# x: the paper's closed form (written here as C(x) = asin(b0 s) + asin(b1 s), s = x/sqrt(x² + h²),
# C(x) - C(x0) = S(x)) gives the first guess. It measures angles against π, so alone it is off by
# about 1e-7·π/Ω in u (1e-3 at Ω = 1e-4 sr) and fails at grazing angles, where x = h·tan(...) is
# ill-conditioned. Safeguarded Newton steps on S(x) = u0·Ω then bring x to float32 round-off
# (one step in ordinary configurations, a few at grazing angles; at most SPHRECT_NEWTON_MAX).
# S itself is evaluated without cancellation: the rectangle is cut by the lines x = 0 and y = 0
# through the foot of p and each piece, reflected into x, y >= 0, is measured with Van Oosterom
# and Strackee's triangle formula, whose terms are then all non-negative.
# y: sinφ is linear in u1; 1 ± sinφ are carried as sums of non-negative terms, and one Newton
# step on the difference of sines in conjugate form removes the rest of the round-off.
#
# Accuracy (float32, measured against a float64 inverse over random configurations): Ω to a few
# 1e-7 relative and u to ~1e-6, except where the float32 inputs themselves do not determine the
# answer: h below ~1e-5 of the coordinates' magnitude (Ω's relative error grows like 1e-7·|p|/h)
# and samples packed within a few ulps of the foot of p.
#
# Below SPHRECT_MIN_SOLID_ANGLE (and for p in the rectangle's plane, a zero-area rectangle or any
# non-finite intermediate) ``square_to_spherical_rect`` reports Ω = 0: the caller falls back to
# area sampling, which is as good there (a tiny solid angle is nearly uniform in area).

SPHRECT_MIN_SOLID_ANGLE = 1.0e-6  # sr
SPHRECT_MIN_HEIGHT = 1.0e-12  # p nearer its plane than this, relative to |corner - p| + |e1| + |e2|, is in it
SPHRECT_NEWTON_MAX = 10  # Newton/bisection steps on x at most (1 or 2 in ordinary configurations)
RECT_COS_TOL = 1.0e-5  # |cos| of the angle between e1 and e2 still treated as a right angle


def is_rectangle(e1, e2, tol: float = RECT_COS_TOL) -> bool:
    """True when the parallelogram spanned by e1 and e2 is a rectangle that spherical-rectangle
    sampling may take as exact: both edges non-zero and |e1·e2| <= tol·|e1||e2| (host helper,
    float64; the density error of treating a near-rectangle as a rectangle is O(tol))."""
    import numpy as np

    a = np.asarray(e1, dtype=np.float64)
    b = np.asarray(e2, dtype=np.float64)
    la = float(np.linalg.norm(a))
    lb = float(np.linalg.norm(b))
    return la > 0.0 and lb > 0.0 and abs(float(np.dot(a, b))) <= tol * la * lb


@wp.func
def is_rectangle_edges(e1: wp.vec3, e2: wp.vec3) -> bool:
    """Device twin of ``is_rectangle``: non-zero edges, |e1·e2| <= RECT_COS_TOL·|e1||e2|."""
    l1 = wp.length(e1)
    l2 = wp.length(e2)
    return l1 > 0.0 and l2 > 0.0 and wp.abs(wp.dot(e1, e2)) <= RECT_COS_TOL * l1 * l2


@wp.func
def sin_diff(ya: float, yb: float, d2: float) -> float:
    """ya/sqrt(d2 + ya²) - yb/sqrt(d2 + yb²) without cancellation (conjugate form when ya and yb
    have the same sign)."""
    ra = wp.sqrt(d2 + ya * ya)
    rb = wp.sqrt(d2 + yb * yb)
    if ya * yb > 0.0:
        return d2 * (ya - yb) * (ya + yb) / (ra * rb * (ya * rb + yb * ra))
    return ya / ra - yb / rb


@wp.func
def tri_half_angle(ax: float, ay: float, bx: float, by: float, cx: float, cy: float, h: float,
                   ra: float, rb: float, rc: float) -> wp.vec2:
    """(cos, sin)·k, k > 0, of half the solid angle of the triangle abc in the plane z = -h seen
    from the origin (Van Oosterom-Strackee: tan(Ω/2) = |a·(b×c)| / (abc + (a·b)c + (a·c)b +
    (b·c)a)); ra, rb, rc are the vertices' distances. Scaled to cos + sin = 1 (no underflow)."""
    h2 = h * h
    num = h * wp.abs((bx - ax) * (cy - ay) - (by - ay) * (cx - ax))
    den = ra * rb * rc + (ax * bx + ay * by + h2) * rc + (ax * cx + ay * cy + h2) * rb + (bx * cx + by * cy + h2) * ra
    t = wp.abs(den) + num
    if t > 0.0:
        return wp.vec2(den / t, num / t)
    return wp.vec2(1.0, 0.0)


@wp.func
def cmul(a: wp.vec2, b: wp.vec2) -> wp.vec2:
    return wp.vec2(a[0] * b[0] - a[1] * b[1], a[0] * b[1] + a[1] * b[0])


@wp.func
def quad_half_angle(a0: float, a1: float, b0: float, b1: float, h: float) -> wp.vec2:
    """Half the solid angle of [a0, a1] × [b0, b1] (0 <= a0 <= a1, 0 <= b0 <= b1) in the plane
    z = -h, as a complex number (two triangles). In this quadrant every dot product between
    vertices is at least h², so every term of the formula is non-negative: no cancellation."""
    h2 = h * h
    r00 = wp.sqrt(a0 * a0 + b0 * b0 + h2)
    r10 = wp.sqrt(a1 * a1 + b0 * b0 + h2)
    r11 = wp.sqrt(a1 * a1 + b1 * b1 + h2)
    r01 = wp.sqrt(a0 * a0 + b1 * b1 + h2)
    t1 = tri_half_angle(a0, b0, a1, b0, a1, b1, h, r00, r10, r11)
    t2 = tri_half_angle(a0, b0, a1, b1, a0, b1, h, r00, r11, r01)
    return cmul(t1, t2)


@wp.func
def fold_interval(a0: float, a1: float) -> wp.vec3:
    """[a0, a1] folded onto a >= 0 by the reflection a -> -a: the piece (lo, hi) it covers there,
    and the upper end of the second piece [0, b1] when 0 cuts the interval (-1 when it does not)."""
    if a0 >= 0.0:
        return wp.vec3(a0, a1, -1.0)
    if a1 <= 0.0:
        return wp.vec3(-a1, -a0, -1.0)
    return wp.vec3(0.0, -a0, a1)


@wp.func
def rect_solid_angle_local(x0: float, y0: float, w: float, v: float, h: float) -> float:
    """Solid angle of [x0, x0 + w] × [y0, y0 + v] in the plane z = -h seen from the origin (h > 0).

    The rectangle is cut along x = 0 and y = 0 where they cross it, and each piece is reflected
    into the quadrant x, y >= 0 (``quad_half_angle``, exact to round-off there). The pieces' half
    angles are added as arguments of a product of complex numbers, one atan2 at the end
    (Ω/2 < π; a result pushed just below -π by round-off is put back)."""
    x1 = x0 + w
    y1 = y0 + v
    # pieces along x: [xa0, xa1] and, when x = 0 cuts the rectangle, [0, xb1]; the same along y
    fx = fold_interval(x0, x1)
    xa0 = fx[0]
    xa1 = fx[1]
    xb1 = fx[2]
    fy = fold_interval(y0, y1)
    ya0 = fy[0]
    ya1 = fy[1]
    yb1 = fy[2]
    z = quad_half_angle(xa0, xa1, ya0, ya1, h)
    if xb1 >= 0.0:
        z = cmul(z, quad_half_angle(0.0, xb1, ya0, ya1, h))
    if yb1 >= 0.0:
        z = cmul(z, quad_half_angle(xa0, xa1, 0.0, yb1, h))
        if xb1 >= 0.0:
            z = cmul(z, quad_half_angle(0.0, xb1, 0.0, yb1, h))
    half = wp.atan2(z[1], z[0])
    if half < 0.0:
        half += 2.0 * wp.pi
    return 2.0 * half


@wp.struct
class SphRect:
    """A rectangle in p's local frame (lengths scaled by 1/scale), with its solid angle."""

    x0: float
    y0: float
    w: float
    v: float
    h: float
    omega: float  # 0 when degenerate


@wp.func
def sphrect_setup(p: wp.vec3, corner: wp.vec3, e1: wp.vec3, e2: wp.vec3) -> SphRect:
    r = SphRect()
    l1 = wp.length(e1)
    l2 = wp.length(e2)
    d = corner - p
    scale = wp.length(d) + l1 + l2
    r.omega = 0.0
    if l1 <= 0.0 or l2 <= 0.0 or not (scale < 3.0e38):
        return r
    ex = e1 / l1
    ey = e2 / l2
    ez = wp.cross(ex, ey)
    lz = wp.length(ez)
    if lz <= 0.0:
        return r
    inv = 1.0 / scale
    r.x0 = wp.dot(d, ex) * inv
    r.y0 = wp.dot(d, ey) * inv
    r.h = wp.abs(wp.dot(d, ez)) / lz * inv
    r.w = l1 * inv
    r.v = l2 * inv
    if r.h > SPHRECT_MIN_HEIGHT and r.w > 0.0 and r.v > 0.0:
        om = rect_solid_angle_local(r.x0, r.y0, r.w, r.v, r.h)
        if wp.isfinite(om):
            r.omega = wp.min(om, 2.0 * wp.pi)
    return r


@wp.func
def spherical_rect_solid_angle(p: wp.vec3, corner: wp.vec3, e1: wp.vec3, e2: wp.vec3) -> float:
    """Solid angle (sr) of the rectangle corner + [0,1]·e1 + [0,1]·e2 seen from p, from either side;
    0 for p in its plane or a zero-area rectangle. Accurate to float32 round-off relative to Ω
    (no threshold applied here)."""
    return sphrect_setup(p, corner, e1, e2).omega


@wp.func
def sphrect_x_cdf(r: SphRect, dx: float) -> float:
    """S(x0 + dx): solid angle of the part of the rectangle with x in [x0, x0 + dx]."""
    return rect_solid_angle_local(r.x0, r.y0, dx, r.v, r.h)


@wp.func
def sphrect_x_guess(r: SphRect, u0: float) -> float:
    """The paper's closed-form dx in [0, w] for S(x0 + dx) = u0·Ω (see the section comment for
    its accuracy); ``sphrect_sample_x`` refines it."""
    x0 = r.x0
    y0 = r.y0
    y1 = y0 + r.v
    h = r.h
    h2 = h * h
    # C(x) = asin(b0 s) + asin(b1 s), s = x/sqrt(x² + h²), is S(x) up to a constant. Solving
    # C(x) = T = C(x0) + u0·Ω gives s = sin T / sqrt(b0² + b1² + 2 b0 b1 cos T) (b0 + b1 > 0);
    # the denominator is taken as a sum of two non-negative terms. sin T and cos T come from the
    # angle-sum formulas (sin and cos of each asin are algebraic): two trigonometric calls.
    b0 = wp.clamp(-y0 / wp.sqrt(y0 * y0 + h2), -1.0, 1.0)
    b1 = wp.clamp(y1 / wp.sqrt(y1 * y1 + h2), -1.0, 1.0)
    s0 = x0 / wp.sqrt(x0 * x0 + h2)
    sa = b0 * s0
    sb = b1 * s0
    ca = wp.sqrt(wp.max(0.0, 1.0 - sa * sa))
    cb = wp.sqrt(wp.max(0.0, 1.0 - sb * sb))
    sc = sa * cb + ca * sb  # sin C(x0)
    cc = ca * cb - sa * sb  # cos C(x0)
    phi = u0 * r.omega
    sp = wp.sin(phi)
    cp = wp.cos(phi)
    sin_t = sc * cp + cc * sp
    # 1 - cos T and 1 + cos T without cancellation: 1 ∓ cos(C + φ) = (1 ∓ cos C) ± cos C (1 - cos φ)
    # ± sin C sin φ, with 1 ∓ cos C = sin² C / (1 ± cos C) on the side where that is accurate
    omc_p = 2.0 * wp.sin(0.5 * phi) * wp.sin(0.5 * phi)  # 1 - cos φ
    den = float(0.0)
    if b0 * b1 < 0.0:
        omc_c = wp.where(cc > 0.0, sc * sc / (1.0 + cc), 1.0 - cc)
        omc_t = omc_c + cc * omc_p + sc * sp  # 1 - cos T
        bsum = sin_diff(y1, y0, h2)
        den = bsum * bsum - 2.0 * b0 * b1 * wp.max(omc_t, 0.0)
    else:
        opc_c = wp.where(cc < 0.0, sc * sc / (1.0 - cc), 1.0 + cc)
        opc_t = opc_c - cc * omc_p - sc * sp  # 1 + cos T
        den = (b0 - b1) * (b0 - b1) + 2.0 * b0 * b1 * wp.max(opc_t, 0.0)
    s = wp.clamp(sin_t / wp.sqrt(wp.max(den, 1.0e-30)), -1.0, 1.0)
    dx = wp.clamp(h * s / wp.sqrt(wp.max((1.0 - s) * (1.0 + s), 1.0e-30)) - x0, 0.0, r.w)
    if not wp.isfinite(dx):
        dx = u0 * r.w
    return dx


@wp.func
def sphrect_sample_x(r: SphRect, u0: float) -> float:
    """dx in [0, w] with S(x0 + dx) = u0·Ω: ``sphrect_x_guess``, then Newton steps in the angle
    θ = atan(x/H), H² = h² + (distance from y = 0 to [y0, y1])², in which S is smooth whether the
    foot of p lies in the rectangle's y range (dS/dθ = sinφ(y1) - sinφ(y0) in (0, 2]) or beside it
    (dS/dx nearly constant for |x| < H, decaying beyond)."""
    x0 = r.x0
    y0 = r.y0
    y1 = y0 + r.v
    h = r.h
    h2 = h * h
    dx = sphrect_x_guess(r, u0)
    # Newton in θ, safeguarded by bisection on the bracket [lo, hi] of dx; the residual is
    # accurate (see rect_solid_angle_local). The step is taken on x directly, without forming θ:
    # x' = H·tan(θ + dθ) = x + tan(dθ)·(x² + H²)/(H - x·tan(dθ)).
    y_near = wp.max(0.0, wp.max(y0, -y1))
    big_h2 = h2 + y_near * y_near
    big_h = wp.sqrt(big_h2)
    target = u0 * r.omega
    lo = float(0.0)
    hi = r.w
    it = int(0)
    while it < SPHRECT_NEWTON_MAX:
        it += 1
        res = rect_solid_angle_local(x0, y0, dx, r.v, h) - target
        if res == 0.0:
            break
        if res < 0.0:
            lo = dx
        else:
            hi = dx
        x = x0 + dx
        d2 = x * x + h2
        dth = -res * d2 * big_h / (h * (x * x + big_h2) * sin_diff(y1, y0, d2))  # -res / (dS/dθ)
        nxt = 0.5 * (lo + hi)
        newton = False
        if wp.abs(dth) < 1.5:
            tn = dth * (1.0 + dth * dth * (1.0 / 3.0))  # tan, to 2e-9 relative below 0.01
            if wp.abs(dth) > 0.01:
                tn = wp.tan(dth)
            q = big_h - x * tn
            if q > 0.0:
                cand = dx + tn * (x * x + big_h2) / q
                if cand >= lo and cand <= hi:
                    nxt = cand
                    newton = True
        dx = nxt
        if newton and wp.abs(res) <= 1.0e-5 * r.omega:
            break  # converged: the step just taken leaves an error of order res²
    return dx


@wp.func
def sphrect_sample_y(r: SphRect, dx: float, u1: float) -> float:
    """dy in [0, v] on the line x = x0 + dx, uniform in solid angle: sinφ(y) = y/sqrt(d² + y²),
    d² = x² + h², is linear in u1. 1 ± sinφ are carried as sums of non-negative terms (no
    cancellation near the ends of the range), then y = d·sinφ / sqrt((1 + sinφ)(1 - sinφ))."""
    x = r.x0 + dx
    d2 = x * x + r.h * r.h
    y0 = r.y0
    y1 = y0 + r.v
    r0 = wp.sqrt(d2 + y0 * y0)
    r1 = wp.sqrt(d2 + y1 * y1)
    g0 = float(0.0)  # 1 + sinφ(y0)
    if y0 < 0.0:
        g0 = d2 / (r0 * (r0 - y0))
    else:
        g0 = 1.0 + y0 / r0
    g1 = float(0.0)  # 1 - sinφ(y1)
    if y1 > 0.0:
        g1 = d2 / (r1 * (r1 + y1))
    else:
        g1 = 1.0 - y1 / r1
    total = sin_diff(y1, y0, d2)
    a = g0 + u1 * total  # 1 + sinφ
    b = g1 + (1.0 - u1) * total  # 1 - sinφ
    sv = float(0.0)  # sinφ, taken from its most accurate form
    if a < 0.5:
        sv = a - 1.0
    elif b < 0.5:
        sv = 1.0 - b
    else:
        sv = y0 / r0 + u1 * total
    y = wp.sqrt(d2) * sv / wp.sqrt(a * b)
    dy = wp.clamp(y - y0, 0.0, r.v)
    if not wp.isfinite(dy):
        dy = u1 * r.v
    # one Newton step on sinφ(y) - sinφ(y0) = u1·total, the difference in conjugate form
    y = y0 + dy
    ry = wp.sqrt(d2 + y * y)
    dy = wp.clamp(dy - (sin_diff(y, y0, d2) - u1 * total) * ry * ry * ry / d2, 0.0, r.v)
    return dy


@wp.func
def sphrect_sample(r: SphRect, corner: wp.vec3, e1: wp.vec3, e2: wp.vec3, u: wp.vec2) -> wp.vec4:
    """``square_to_spherical_rect`` from its set-up ``sphrect_setup(p, corner, e1, e2)`` (many
    draws from one shading point share it)."""
    area_y = corner + u[0] * e1 + u[1] * e2
    if not (r.omega >= SPHRECT_MIN_SOLID_ANGLE):
        return wp.vec4(area_y[0], area_y[1], area_y[2], 0.0)
    dx = sphrect_sample_x(r, u[0])
    dy = sphrect_sample_y(r, dx, u[1])
    a = wp.clamp(dx / r.w, 0.0, 1.0)
    b = wp.clamp(dy / r.v, 0.0, 1.0)
    if not (wp.isfinite(a) and wp.isfinite(b)):
        return wp.vec4(area_y[0], area_y[1], area_y[2], 0.0)
    y = corner + a * e1 + b * e2
    return wp.vec4(y[0], y[1], y[2], r.omega)


@wp.func
def square_to_spherical_rect(p: wp.vec3, corner: wp.vec3, e1: wp.vec3, e2: wp.vec3, u: wp.vec2) -> wp.vec4:
    """A point on the rectangle corner + a·e1 + b·e2 (a, b in [0, 1], e1 ⟂ e2) whose direction from
    p is uniform in the solid angle the rectangle subtends; returns (y, Ω), so the density of the
    direction is 1/Ω. Either side of the rectangle is sampled.

    Returns Ω = 0 (w component) when Ω < SPHRECT_MIN_SOLID_ANGLE, p lies in the rectangle's
    plane, the rectangle has zero area or the computation fails; xyz is then the area sample
    corner + u0·e1 + u1·e2, for the caller's area-sampling fallback. The point always lies on the
    rectangle (a and b are clamped to [0, 1])."""
    return sphrect_sample(sphrect_setup(p, corner, e1, e2), corner, e1, e2, u)


@wp.func
def spherical_rect_to_square(p: wp.vec3, corner: wp.vec3, e1: wp.vec3, e2: wp.vec3, y: wp.vec3) -> wp.vec2:
    """Inverse of ``square_to_spherical_rect``: the (u0, u1) that maps to the point y of the
    rectangle (y is projected onto it and clamped). Where the forward map reports Ω = 0 it
    inverts the area map instead: ((y - corner)·e1/|e1|², (y - corner)·e2/|e2|²)."""
    q = y - corner
    l11 = wp.dot(e1, e1)
    l22 = wp.dot(e2, e2)
    a = float(0.0)
    b = float(0.0)
    if l11 > 0.0:
        a = wp.clamp(wp.dot(q, e1) / l11, 0.0, 1.0)
    if l22 > 0.0:
        b = wp.clamp(wp.dot(q, e2) / l22, 0.0, 1.0)
    r = sphrect_setup(p, corner, e1, e2)
    if not (r.omega >= SPHRECT_MIN_SOLID_ANGLE):
        return wp.vec2(a, b)
    dx = a * r.w
    x = r.x0 + dx
    dd2 = x * x + r.h * r.h
    u0 = sphrect_x_cdf(r, dx) / r.omega
    yv = r.y0 + b * r.v
    u1 = sin_diff(yv, r.y0, dd2) / sin_diff(r.y0 + r.v, r.y0, dd2)
    return wp.vec2(wp.clamp(u0, 0.0, 1.0), wp.clamp(u1, 0.0, 1.0))
