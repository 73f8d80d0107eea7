"""Splitting: how many shadow rays an area light with ``samples = "auto"`` takes per camera sample.

A pixel's estimate has two kinds of noise: where its camera samples land (the pixel footprint,
the lens, the time) and where on the lights their shadow rays go. With n camera samples of N
light samples each, a stratifying sampler (``sobol``, ``stratified``, ``regular``) makes the
error of a pixel's mean fall as a power RATE ≈ 1.5 of its samples, for both parts: the camera
samples are a stratified set of n, and the light samples a stratified run of n·N. So

    error ≈ n^-RATE (E_cam + E_light · N^-RATE)        for a cost of  n (C_cam + N C_light),

and at a given cost (n = T / (C_cam + N C_light)) the error is proportional to

    (1 + N C_light / C_cam)^RATE (E_cam + E_light · N^-RATE),

which the renderer evaluates for N = 1, 2, 4, ..., MAX_SAMPLES and takes the least of (N a power
of two: a camera sample's light samples are then a stratified run of the sampler's sequence).
With the ``independent`` sampler RATE is 1, and the least is the classical
N = sqrt(E_light / E_cam · C_cam / C_light).

E_cam and E_light are measured, not modelled, by a pilot: every ``PILOT_ROW_STEP``-th row at
``PILOT_SPP`` camera samples, rendered with 1 and with ``PROBE`` light samples per camera sample,
each twice with two fixed seeds. The squared difference of a pixel's two means, halved, is the
error of one mean (the seeds' scrambles are independent); summed over the pixels it is what the
image's mean squared error adds up: E(1) = E_cam + E_light and E(PROBE) = E_cam + E_light ·
PROBE^-RATE. The ``regular`` sampler's points move with no seed: its two renders agree, there
is no error to split, and N is 1. (Splitting the per-sample variances instead, as for
independent samples, would overstate E_light / E_cam: the camera's variance inside a pixel is
what stratification removes best, and such a split chooses 8 and 16 shadow rays where 2 to 4
reach a given error soonest.)

The cost ratio is a constant, not a timing, so the same scene always gets the same N and the
same seed the same image: one more light sample (the light draw and its shadow ray) costs about
a third of a camera sample (camera ray, hit, shading, film). The constant is the median, over
mesh scenes with area lights, of the ratio fitted to a render's time against N at a fixed spp
(lower where shadow rays cross a deep tree). With several "auto" lights each takes N, and a unit
of N costs one light sample per such light.

The choice is made once per renderer (the split is the scene's, not the render's) and is
independent of the seed, spp and workers.
"""

from __future__ import annotations

import numpy as np

PILOT_SPP = 4  # camera samples per pixel of the pilot
PILOT_ROW_STEP = 8  # the pilot renders every 8th row (at least 16 rows: smaller steps on small images)
PROBE = 8  # light samples per camera sample in the pilot's second pair of renders
MAX_SAMPLES = 16  # the most shadow rays per camera sample "auto" gives
COST_RATIO = 3.1  # cost of a camera sample / cost of one light sample (measured, see above)
PILOT_SEEDS = (0x5EED5, 0x5EED6)  # the pilot's fixed seeds: the choice does not depend on the render's
RATE = 1.5  # a stratifying sampler's error of a mean falls as (samples)^-RATE (1 for independent)


def pilot_rows(height: int) -> tuple[int, int]:
    """(first row, step) of the rows the pilot renders."""
    step = max(1, min(PILOT_ROW_STEP, height // 16))
    return step // 2, step


def pixel_error(mean_a: np.ndarray, mean_b: np.ndarray) -> float:
    """The error (variance) of one pixel mean summed over pixels, from two independent renders'
    means of the same pixels: Var(a - b) = 2 Var(a)."""
    d = np.asarray(mean_a, dtype=np.float64) - np.asarray(mean_b, dtype=np.float64)
    return float(np.sum(d * d)) / 2.0


def error_split(e_one: float, e_probe: float, probe: int = PROBE, rate: float = RATE) -> tuple[float, float]:
    """(E_cam, E_light) from the errors with 1 and ``probe`` light samples per camera sample
    (the same camera samples); negative estimates clipped to 0."""
    e_light = max(e_one - e_probe, 0.0) / (1.0 - probe ** -rate)
    e_cam = max(e_one - e_light, 0.0)
    return e_cam, e_light


def best_samples(e_cam: float, e_light: float, n_lights: int = 1, cost_ratio: float = COST_RATIO,
                 rate: float = RATE) -> int:
    """The power of two N in [1, MAX_SAMPLES] whose error at a given cost,
    (1 + N · n_lights / cost_ratio)^rate (e_cam + e_light N^-rate), is least (the smaller N on a
    tie); a light sample costs ``n_lights`` light samples (one per "auto" light)."""
    if not (e_light > 0.0):
        return 1
    if not (e_cam > 0.0):
        return MAX_SAMPLES
    rho = max(n_lights, 1) / cost_ratio
    best, best_cost = 1, float("inf")
    n = 1
    while n <= MAX_SAMPLES:
        cost = (1.0 + n * rho) ** rate * (e_cam + e_light * n ** -rate)
        if cost < best_cost:
            best, best_cost = n, cost
        n *= 2
    return best


# The split map: a count per MAP_TILE × MAP_TILE block of the image instead of one for the whole
# image. Where a block's noise is mostly its light samples' (a penumbra) more shadow rays pay;
# where it is its camera samples' (edges, a mesh's facets) or where there is little noise at all
# (a plain lit floor) fewer do. Minimising the whole image's error at a given cost, with block i
# at N_i, sum_i E_i(N_i) · (sum_i C_i(N_i))^RATE with E_i(N) = E_cam,i + E_light,i · N^-RATE and
# C_i(N) = pixels_i · (COST_RATIO + N · n_lights), picks every block's N_i by one multiplier λ
# (N_i minimises E_i(N) + λ C_i(N): a Lagrangian relaxation); the best λ over a sweep is kept, and
# the map only where it beats the best single count in the same model.
MAP_TILE = 16


def tile_errors(mean_a: np.ndarray, mean_b: np.ndarray, rows: np.ndarray, width: int, height: int,
                tile: int = MAP_TILE) -> np.ndarray:
    """``pixel_error`` per tile × tile block (rows of blocks), from two renders' means of the
    pilot ``rows`` (each a full row of ``width`` pixels, in ``rows``' order), each block's sum
    scaled from its pilot rows to all of its rows."""
    d = (np.asarray(mean_a, np.float64) - np.asarray(mean_b, np.float64)).reshape(len(rows), width)
    ty, tx = -(-height // tile), -(-width // tile)
    e = np.zeros((ty, tx))
    seen = np.zeros(ty)
    cols = np.arange(width) // tile
    for r, row in zip(rows, d):
        np.add.at(e[r // tile], cols, row * row / 2.0)
        seen[r // tile] += 1
    heights = np.minimum(tile, height - np.arange(ty) * tile)
    return e * (heights / np.maximum(seen, 1))[:, None]


def light_map(e_one: np.ndarray, e_probe: np.ndarray, width: int, height: int, n_lights: int = 1,
              tile: int = MAP_TILE, probe: int = PROBE, cost_ratio: float = COST_RATIO,
              rate: float = RATE, one: int | None = None) -> np.ndarray | None:
    """Each block's shadow rays per camera sample (rows of blocks, powers of two up to
    MAX_SAMPLES) from the blocks' errors with 1 and ``probe`` light samples (``tile_errors``), as
    described above; None where the one count for the whole image, ``one`` (the renderer's;
    default ``best_samples`` of the blocks' sums), does as well (the model's cost within 1%)."""
    e_one = np.asarray(e_one, np.float64)
    e_probe = np.asarray(e_probe, np.float64)
    e_light = np.maximum(e_one - e_probe, 0.0) / (1.0 - probe ** -rate)
    e_cam = np.maximum(e_one - e_light, 0.0)
    ty, tx = e_one.shape
    pixels = np.outer(np.minimum(tile, height - np.arange(ty) * tile), np.minimum(tile, width - np.arange(tx) * tile))
    counts = 2 ** np.arange(int(np.log2(MAX_SAMPLES)) + 1)
    rho = max(n_lights, 1)
    err = e_cam[None] + e_light[None] * counts[:, None, None] ** -rate  # (N, ty, tx)
    cost = pixels[None] * (cost_ratio + counts[:, None, None] * rho)

    def objective(pick: np.ndarray) -> float:
        e = np.take_along_axis(err, pick[None], 0).sum()
        c = np.take_along_axis(cost, pick[None], 0).sum()
        return float(e * c ** rate)

    if one is None:
        one = best_samples(float(e_cam.sum()), float(e_light.sum()), n_lights, cost_ratio, rate)
    best_pick = np.full((ty, tx), int(np.log2(one)))
    best = uniform = objective(best_pick)
    # λ from the blocks' own break points (where two neighbouring counts cost a block the same)
    de = err[:-1] - err[1:]
    dc = cost[1:] - cost[:-1]
    breaks = de[de > 0] / dc[de > 0]
    if breaks.size:
        for lam in np.geomspace(breaks.min(), breaks.max(), 256):
            pick = np.argmin(err + lam * cost, axis=0)
            v = objective(pick)
            if v < best:
                best, best_pick = v, pick
    if not best < 0.99 * uniform:
        return None
    return counts[best_pick].astype(np.int32)
