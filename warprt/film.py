"""The film: per-pixel accumulation buffers, sample sanitising, and the image they hold.

Each pixel accumulates the sum of its samples' radiance (float32 linear RGB), the sum of their
squared luminance (for the variance estimate behind ``target_error``), the rays traced and the
rays dropped by a full ray stack. The image is the sum over the sample count, as numpy (host) or
as a (H, W, 3) ``wp.array`` left on the device. The film also holds the counter from which a CPU
pass's launches claim blocks of rows (``claim_block``).
"""

from __future__ import annotations

import functools
import math
from types import SimpleNamespace

import numpy as np
import warp as wp

from ._warp import build_once
from .accel import PacketF

NO_LIMIT = (1 << 31) - 1  # FilmData.limit of a pixel without a sample cap


@wp.struct
class FilmData:
    accum: wp.array(dtype=wp.vec3)  # Σ radiance
    accum_sq: wp.array(dtype=float)  # Σ luminance²
    rays: wp.array(dtype=int)  # rays traced
    overflow: wp.array(dtype=int)  # rays dropped because the pixel's ray stack was full
    limit: wp.array(dtype=int)  # samples this pixel takes at most (adaptive sampling; else NO_LIMIT)
    claims: wp.array(dtype=int)  # [0]: the blocks of rows a CPU pass has handed out (claim_block)


# counter[0], then one more, atomically: Warp's own atomic_add is a plain read and write in CPU
# code (a CPU launch runs on one thread), and the pool's threads claim blocks from one counter
_CLAIM_BLOCK = r"""
#if defined(__CUDA_ARCH__)
return atomicAdd(counter.data, 1);
#else
return __atomic_fetch_add(counter.data, 1, __ATOMIC_RELAXED);
#endif
"""


@wp.func_native(_CLAIM_BLOCK)
def claim_block(counter: wp.array(dtype=int)) -> int:
    """The next block of a pass to render (see above)."""
    ...


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


# A shaded camera packet's 8 samples as the film takes them, at once (clang vectors; lane by lane
# on CUDA): the lanes in ``lit`` (a bit mask) first add their area lights to the rest,
# mul_sat(1, local + area) (``shading.mul_sat``); then every lane is ``sanitize``d, and its
# luminance squared (``luminance``, each product and sum rounded once, as Warp's C++ has them)
# comes out with it. Each lane's values are the scalar functions', bit for bit; the pixel's sums
# still add them lane by lane, in order.
_PACKET_SAMPLES = r"""
#if defined(__clang__) && !defined(__CUDA_ARCH__)
typedef float v8 __attribute__((ext_vector_type(8)));
typedef int i8 __attribute__((ext_vector_type(8)));
v8 R, G, B, AR, AG, AB;
__builtin_memcpy(&R, &r, 32); __builtin_memcpy(&G, &g, 32); __builtin_memcpy(&B, &b, 32);
__builtin_memcpy(&AR, &ar, 32); __builtin_memcpy(&AG, &ag, 32); __builtin_memcpy(&AB, &ab, 32);
const i8 on = ((i8){1, 2, 4, 8, 16, 32, 64, 128} & lit) != 0;
const v8 zero = 0.0f, big = 3.4028234663852886e38f, cl = clamp;
auto lit_sum = [&](v8 l, v8 a) {
    const v8 x = l + a;
    const v8 x1 = 1.0f * x;
    const v8 m = x > 0.0f ? (x1 <= big ? x1 : big) : zero;  // mul_sat(1, x): min(1·x, FLT_MAX)
    return zero + m;
};
auto clean = [&](v8 x) {  // clamp(x, 0, clamp) (a NaN gives fmax's 0, as sanitize's test does)
    const v8 hi = zero >= x ? zero : (x == x ? x : zero);  // fmax(0, x)
    return hi <= cl ? hi : (cl == cl ? cl : hi);  // fmin(., clamp)
};
const v8 Rs = clean(on ? lit_sum(R, AR) : R), Gs = clean(on ? lit_sum(G, AG) : G), Bs = clean(on ? lit_sum(B, AB) : B);
const v8 t1 = (float)0.2126 * Rs;
const v8 t2 = (float)0.7152 * Gs;
const v8 t3 = t1 + t2;
const v8 t4 = (float)0.0722 * Bs;
const v8 y = t3 + t4;
const v8 y2 = y * y;
__builtin_memcpy(&out_r, &Rs, 32); __builtin_memcpy(&out_g, &Gs, 32); __builtin_memcpy(&out_b, &Bs, 32);
__builtin_memcpy(&out_y2, &y2, 32);
#else
for (int l = 0; l < 8; ++l) {
    float c[3] = {r[l], g[l], b[l]};
    const float a[3] = {ar[l], ag[l], ab[l]};
    for (int k = 0; k < 3; ++k) {
        if ((lit >> l) & 1) {
            const float x = c[k] + a[k];
            const float x1 = 1.0f * x;
            const float m = x > 0.0f ? (x1 <= 3.4028234663852886e38f ? x1 : 3.4028234663852886e38f) : 0.0f;
            c[k] = 0.0f + m;
        }
        const float x = c[k];
        const float hi = 0.0f >= x ? 0.0f : (x == x ? x : 0.0f);
        c[k] = hi <= clamp ? hi : (clamp == clamp ? clamp : hi);
    }
    const float t1 = (float)0.2126 * c[0];
    const float t2 = (float)0.7152 * c[1];
    const float t3 = t1 + t2;
    const float t4 = (float)0.0722 * c[2];
    const float y = t3 + t4;
    out_r[l] = c[0]; out_g[l] = c[1]; out_b[l] = c[2]; out_y2[l] = y * y;
}
#endif
"""


@wp.func_native(_PACKET_SAMPLES)
def packet_samples(r: PacketF, g: PacketF, b: PacketF, ar: PacketF, ag: PacketF, ab: PacketF, lit: int, clamp: float,
                   out_r: wp.ref[PacketF], out_g: wp.ref[PacketF], out_b: wp.ref[PacketF], out_y2: wp.ref[PacketF]):
    """A shaded packet's samples as the film adds them (see above)."""
    ...


@build_once
def _image_kernels():
    """The film's two image kernels, defined together so that the Warp module ``warprt_film``
    always holds the same two (whichever is used first)."""

    @wp.kernel(module="warprt_film", enable_backward=False)
    def image_kernel(accum: wp.array(dtype=wp.vec3), inv_spp: float, width: int, out: wp.array3d(dtype=float)):
        i = wp.tid()
        c = accum[i] * inv_spp
        y = i / width
        x = i - y * width
        out[y, x, 0] = c[0]
        out[y, x, 1] = c[1]
        out[y, x, 2] = c[2]

    @wp.kernel(module="warprt_film", enable_backward=False)
    def counted_image_kernel(accum: wp.array(dtype=wp.vec3), limit: wp.array(dtype=int), spp: int, width: int,
                             out: wp.array3d(dtype=float)):
        i = wp.tid()
        c = accum[i] * (1.0 / float(wp.min(limit[i], spp)))
        y = i / width
        x = i - y * width
        out[y, x, 0] = c[0]
        out[y, x, 1] = c[1]
        out[y, x, 2] = c[2]

    return SimpleNamespace(plain=image_kernel, counted=counted_image_kernel)


class Film:
    """Accumulation buffers for a width × height image on one device."""

    def __init__(self, width: int, height: int, device, zeroed: bool = True):
        """``zeroed=False`` leaves the sums unset: for a film whose first pass covers every pixel
        (the render kernel's first pass starts each pixel's sums rather than adding to them)."""
        self.width, self.height, self.device = width, height, device
        n = width * height
        alloc = wp.zeros if zeroed else wp.empty
        self.data = FilmData()
        self.data.accum = alloc(n, dtype=wp.vec3, device=device)
        self.data.accum_sq = alloc(n, dtype=float, device=device)
        self.data.rays = alloc(n, dtype=int, device=device)
        self.data.overflow = alloc(n, dtype=int, device=device)
        self.data.limit = wp.full(n, NO_LIMIT, dtype=int, device=device)
        self.data.claims = wp.zeros(1, dtype=int, device=device)
        # (on the CPU a numpy view of the counter, for reset_claims)
        self._claims = self.data.claims.numpy() if self.data.claims.device.is_cpu else None
        # (and of the sample caps, which adaptive renders set and clear: Warp's assign and fill_
        # took 0.1-0.2 ms each)
        self._limit = self.data.limit.numpy() if self.data.limit.device.is_cpu else None
        self.counts: np.ndarray | None = None  # per-pixel sample counts (adaptive sampling)

    def reset_claims(self) -> None:
        """No block of rows handed out yet (before each CPU pass whose launches claim them)."""
        if self._claims is not None:
            self._claims[0] = 0
        else:
            self.data.claims.zero_()

    def clear_counts(self) -> None:
        """No per-pixel sample cap any more (a reused film after an adaptive render)."""
        if self.counts is not None:
            if self._limit is not None:
                self._limit.fill(NO_LIMIT)
            else:
                self.data.limit.fill_(NO_LIMIT)
            self.counts = None

    def set_counts(self, counts: np.ndarray) -> None:
        """Let pixel i take at most counts[i] samples (adaptive sampling; counts >= 1)."""
        self.counts = np.ascontiguousarray(counts, dtype=np.int32).reshape(-1)
        if self._limit is not None:
            self._limit[:] = self.counts
        else:
            self.data.limit.assign(self.counts)

    def image(self, spp: int) -> np.ndarray:
        """The mean of the samples, (H, W, 3) float32 on the host (each pixel over its own count
        when ``set_counts`` was used, with ``spp`` samples run)."""
        accum = self.data.accum.numpy()
        if self.counts is None:
            return (accum * np.float32(1.0 / spp)).reshape(self.height, self.width, 3)
        inv = np.float32(1.0) / np.minimum(self.counts, spp).astype(np.float32)  # as the device kernel
        # (each pixel's reciprocal repeated per channel: broadcasting it over the 3 channels took 5x)
        return (accum.reshape(-1) * np.repeat(inv, 3)).reshape(self.height, self.width, 3)

    def device_image(self, spp: int) -> "wp.array":
        """The mean of the samples as a (H, W, 3) float32 ``wp.array`` on the film's device (the
        same values as :meth:`image`)."""
        out = wp.zeros((self.height, self.width, 3), dtype=float, device=self.device)
        if self.counts is None:
            wp.launch(_image_kernels().plain, dim=self.width * self.height, device=self.device,
                      inputs=[self.data.accum, 1.0 / float(spp), self.width, out])
        else:
            wp.launch(_image_kernels().counted, dim=self.width * self.height, device=self.device,
                      inputs=[self.data.accum, self.data.limit, int(spp), self.width, out])
        return out

    def rays(self) -> int:
        return int(self.data.rays.numpy().sum(dtype=np.int64))

    def overflows(self) -> int:
        return int(self.data.overflow.numpy().sum(dtype=np.int64))

    def luminance_stats(self, spp: int) -> tuple[np.ndarray, np.ndarray]:
        """Per pixel, from ``spp`` samples each: the mean luminance and the (unbiased) sample
        variance of the luminance, float64."""
        n = spp
        rgb = self.data.accum.numpy().astype(np.float64) / n
        y = 0.2126 * rgb[:, 0] + 0.7152 * rgb[:, 1] + 0.0722 * rgb[:, 2]
        var = np.maximum(self.data.accum_sq.numpy().astype(np.float64) / n - y * y, 0.0) * n / max(n - 1, 1)
        return y, var

    def relative_error(self, spp: int) -> float:
        """RMS over pixels of the standard error of each pixel's mean luminance, over the mean
        luminance (from ``spp`` samples per pixel)."""
        y, var = self.luminance_stats(spp)
        mean = float(y.mean())
        return math.sqrt(float(var.mean()) / spp) / mean if mean > 0 else 0.0


ADAPTIVE_MIN_SHARE = 2  # adaptive sampling gives every pixel at least spp / 2 samples (and at least 1)
ADAPTIVE_MAX_FACTOR = 8  # and no pixel more than 8 × spp (each extra pass costs every pixel a little)
# the pixels whose pilot decides a pixel's count: the other checkerboard colour in its 5 × 5 window
ADAPTIVE_NEIGHBOURS = tuple((a, b) for a in range(-2, 3) for b in range(-2, 3) if (a + b) % 2)
ADAPTIVE_NEAR_WEIGHT = 12.0  # the 4 edge neighbours' weight in the mean variance (the 8 others: 1)
# and in the spread of a one-sample pilot's values (12 there gives a slightly larger error)
ADAPTIVE_NEAR_WEIGHT_1 = 6.0
# with a pilot of 2 samples or more, the share of a pixel's squared deviation taken from the contrast
# across it (the squared differences of its left and right, and of its upper and lower neighbours'
# mean luminances, added and over 4: the variance of a pixel that an edge between them halves),
# the rest from that mean variance. The mean variance alone spreads an edge's noise over the
# pixels on either side of it, which takes the samples the edge's own pixels need: with this
# share the error at 4 to 16 spp is lower on hard edges, penumbrae and defocused edges, most at
# the lowest spp, and about the same where the noise is spread evenly (a bumpy mesh)
ADAPTIVE_CONTRAST = 0.125
# and a thin line's: the square of the left and right neighbours' sum less the upper and lower
# ones' over 16 (the contrast of a one-pixel line between them, over 4), at this share: with it
# (and the near weight of 12) lines a pixel wide, which the contrast across a pixel misses, get
# their samples, and scenes without such lines keep their error within a few percent
ADAPTIVE_RIDGE = 0.25
_KEEP = 1.0 - ADAPTIVE_CONTRAST  # (the float32 factors of _deviations and _contrast)
_CONTRAST4 = ADAPTIVE_CONTRAST / 4.0
_RIDGE16 = ADAPTIVE_RIDGE / 16.0
ROUND_BUCKETS = 4096  # _round_keeping_sum's histogram (a few parts per bucket at 65k pixels)


def adaptive_counts(film: Film, n0: int, spp: int) -> np.ndarray:
    """Per-pixel sample counts averaging ``spp``, from a film holding the first ``n0`` samples of
    every pixel (the pilot, which each count includes).

    A pixel's count comes from other pixels' pilot samples only, never its own: the pixels are
    coloured as a checkerboard, and a pixel's deviation (of luminance) is estimated from the
    ADAPTIVE_NEIGHBOURS pixels of the other colour around it (those of its 5 × 5 window), the 4
    edge neighbours weighing ADAPTIVE_NEAR_WEIGHT (ADAPTIVE_NEAR_WEIGHT_1 with a pilot of one
    sample) and the 8 farther ones 1: the root of their weighted mean variance, ADAPTIVE_CONTRAST
    of its square taken instead from the contrast across the pixel (its left and right, and its
    upper and lower neighbours' mean luminances: an edge between them runs through it), and
    ADAPTIVE_RIDGE of a thin line's contrast added (left and right against above and below: a
    line between them runs along it); or with a pilot of one sample (2 spp), the weighted spread
    of their values about their weighted mean (noise and image detail alike: both call for
    samples). So the count is independent of the pixel's own samples, and the mean of all of
    them, pilot included, stays unbiased: no sample is thrown away. Twelve pixels' pilots also see
    an edge or a penumbra that a pixel's few samples may miss; the weights, the contrast and the
    ridge keep an edge's or a thin line's samples on the pixels it runs through. Within each
    colour the budget is shared in proportion to those deviations (Neyman allocation: the summed
    variance Σ σ²/N of the pixel means is least for a given total), with every pixel at least
    max(n0, spp / ADAPTIVE_MIN_SHARE) and at most ADAPTIVE_MAX_FACTOR × spp (what a capped pixel
    would take beyond is shared among the others, ``_capped_shares``); the normaliser of a
    colour is itself a function of the other colour's samples. Computed with numpy on the host (a
    CUDA film's sums copied there), each float32 and float64 operation in a fixed order, so that
    a film gives the same counts on every device and machine."""
    n_min = max(1, n0, spp // ADAPTIVE_MIN_SHARE)
    h, w = film.height, film.width
    _, colours = _adaptive_layout(h, w, _near_weight(n0))
    # (radiance near float32's largest overflows the squares: such a colour's total is not finite
    # and it keeps the uniform count, below, without numpy's warnings reaching the user)
    with np.errstate(over="ignore", invalid="ignore"):
        nb = _deviations(film, n0)
    counts = np.full(h * w, spp, dtype=np.int32)
    for mine in colours:
        dev = nb[mine].astype(np.float64)  # the shares in float64: the budget must add up exactly
        total = _sum_in_order(dev)
        if total > 0.0 and math.isfinite(total):
            counts[mine] = _round_keeping_sum(_capped_shares(dev, total, n_min, spp))
    return counts


def _capped_shares(dev: np.ndarray, total: float, n_min: int, spp: int) -> np.ndarray:
    """Each pixel's n_min plus its share of the colour's budget (spp − n_min) × M, in proportion
    to ``dev`` (summing to ``total`` > 0), float64. A share above ADAPTIVE_MAX_FACTOR × spp is
    held there and what it would have taken beyond is shared out again, in the same proportion,
    among the pixels under the cap (repeated while one passes it): the budget is spent whole,
    whatever a few very bright pixels (a light in view) ask for. With no pixel at the cap the
    shares are n_min + budget × dev / total."""
    cap = float(ADAPTIVE_MAX_FACTOR * spp)
    budget = float(spp - n_min) * dev.size
    left = budget
    capped = np.zeros(dev.size, dtype=bool)
    while True:
        share = n_min + left * dev / total
        over = share > cap
        over &= ~capped
        if not over.any():
            break
        capped |= over
        total = _sum_in_order(dev[~capped])
        left = budget - (cap - n_min) * int(np.count_nonzero(capped))
        if not total > 0.0 or not left > 0.0:  # (every pixel left has no deviation, or no budget)
            share = np.full(dev.size, float(n_min))
            break
    share[capped] = cap
    return np.minimum(share, cap)


_LUMA = np.array([0.2126, 0.7152, 0.0722], dtype=np.float32)


def _deviations(film: Film, n0: int) -> np.ndarray:
    """Each pixel's deviation for ``adaptive_counts`` from a film holding ``n0`` samples of every
    pixel, float32, with numpy: the root of the weighted mean variance of its ADAPTIVE_NEIGHBOURS
    with the contrast and the ridge across it (``_contrast``), or with one sample a pixel, the
    weighted spread of their values about their weighted mean."""
    h, w = film.height, film.width
    near = _near_weight(n0)
    weights = _adaptive_layout(h, w, near)[0]
    acc = film.data.accum.numpy()
    y = acc[:, 0] * _LUMA[0]  # (each product and sum rounded once, in this order: a matrix product's
    y += acc[:, 1] * _LUMA[1]  # BLAS may fuse or reorder them, machine by machine)
    y += acc[:, 2] * _LUMA[2]
    y *= np.float32(1.0 / n0)
    if n0 >= 2:
        var = film.data.accum_sq.numpy() * np.float32(1.0 / n0)
        var -= y * y
        np.maximum(var, np.float32(0.0), out=var)
        var *= np.float32(n0 / max(n0 - 1, 1))
        d = _neighbour_sum(var, h, w, near) / weights
        d *= np.float32(_KEEP)
        d += _contrast(y, h, w)
        return np.sqrt(d)
    mean = _neighbour_sum(y, h, w, near) / weights
    return np.sqrt(np.maximum(_neighbour_sum(y * y, h, w, near) / weights - mean * mean, 0.0))


def _contrast(y: np.ndarray, h: int, w: int) -> np.ndarray:
    """ADAPTIVE_CONTRAST / 4 × ((right − left)² + (below − above)²) + ADAPTIVE_RIDGE / 16 ×
    (left + right − above − below)² of each pixel's neighbours' mean luminances y (float32, flat):
    an axis's difference 0 where the pixel has a neighbour missing on it, the ridge where it has
    any missing."""
    Y = y.reshape(h, w)
    dh = np.zeros((h, w), dtype=np.float32)
    dv = np.zeros((h, w), dtype=np.float32)
    rg = np.zeros((h, w), dtype=np.float32)
    dh[:, 1:-1] = Y[:, 2:] - Y[:, :-2]
    dv[1:-1, :] = Y[2:, :] - Y[:-2, :]
    rg[1:-1, 1:-1] = Y[1:-1, :-2] + Y[1:-1, 2:]
    rg[1:-1, 1:-1] -= Y[:-2, 1:-1]
    rg[1:-1, 1:-1] -= Y[2:, 1:-1]
    t = dh * dh
    t += dv * dv
    t *= np.float32(_CONTRAST4)
    q = rg * rg
    q *= np.float32(_RIDGE16)
    t += q
    return t.reshape(-1)


def _sum_in_order(x: np.ndarray) -> float:
    """Σ x added first to last: a sum whose order is fixed by the array alone (numpy's own sum adds
    in pairs, in blocks that depend on its build's unrolling and vector width), so that a colour's
    total, its shares and their rounding are the same wherever numpy runs."""
    return float(np.cumsum(x)[-1]) if x.size else 0.0


def _round_keeping_sum(x: np.ndarray) -> np.ndarray:
    """Integers within 1 of x (>= 0) whose sum is round(Σ x): the floors, plus one for the largest
    fractional parts (ties to the lower index), so that a small budget keeps its mean."""
    base = np.floor(x)
    extra = int(round(_sum_in_order(x) - _sum_in_order(base)))
    if extra > 0:
        # the extra largest fractional parts in linear time: a histogram of the parts in
        # ROUND_BUCKETS buckets finds the bucket the extra-th falls in; every part in a higher
        # bucket is larger than all in it, and that bucket's few are ordered exactly (largest
        # first, then the lower index). x - floor(x) is exact, and a bucket is monotone in it.
        f = x - base
        q = (f * float(ROUND_BUCKETS - 1)).astype(np.int32)
        from_top = np.cumsum(np.bincount(q, minlength=ROUND_BUCKETS)[::-1])
        b = ROUND_BUCKETS - 1 - int(np.searchsorted(from_top, extra))
        above = q > b
        in_b = np.flatnonzero(q == b)
        rest = extra - int(np.count_nonzero(above))
        base += above  # (a mask's in-place add: 20x the time of adding the booleans)
        base[in_b[np.lexsort((in_b, -f[in_b]))[:rest]]] += 1.0
    return base.astype(np.int32)


def _near_weight(n0: int) -> float:
    """The 4 edge neighbours' weight for a pilot of n0 samples a pixel (the 8 others weigh 1)."""
    return ADAPTIVE_NEAR_WEIGHT if n0 >= 2 else ADAPTIVE_NEAR_WEIGHT_1


def _neighbour_sum(v: np.ndarray, h: int, w: int, near_w: float) -> np.ndarray:
    """Σ over ADAPTIVE_NEIGHBOURS of weight × v, the 4 edge neighbours weighing ``near_w`` (flat
    per-pixel values; 0 outside the image)."""
    pad = np.pad(v.reshape(h, w), 2)
    near = np.zeros((h, w), dtype=v.dtype)
    far = np.zeros((h, w), dtype=v.dtype)
    for a, b in ADAPTIVE_NEIGHBOURS:
        if abs(a) + abs(b) == 1:
            near += pad[2 + a:2 + a + h, 2 + b:2 + b + w]
        else:
            far += pad[2 + a:2 + a + h, 2 + b:2 + b + w]
    return (near_w * near + far).reshape(-1)


@functools.lru_cache(maxsize=8)
def _adaptive_layout(h: int, w: int, near_w: float) -> tuple[np.ndarray, tuple[np.ndarray, np.ndarray]]:
    """For an h × w film: each pixel's summed neighbour weights, the 4 edge neighbours weighing
    ``near_w`` (fewer neighbours at the border; at least 1, so that a pixel with none gets
    deviation 0) and the flat indices of the two checkerboard colours."""
    weights = np.maximum(_neighbour_sum(np.ones(h * w, dtype=np.float32), h, w, near_w), np.float32(1.0))
    colour = (np.add.outer(np.arange(h), np.arange(w)) & 1).reshape(-1)
    return weights, (np.flatnonzero(colour == 0), np.flatnonzero(colour == 1))
