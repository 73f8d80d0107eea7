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
is no error to split, and N is 1. (An earlier pilot split the per-sample variances instead, as
for independent samples: the camera's variance inside a pixel is what stratification removes
best, so it overstated E_light / E_cam and chose 8 and 16 shadow rays where 2 to 4 reach a given
error soonest: docs/benchmarks.md, levers.)

The cost ratio is a constant, not a timing, so the same scene always gets the same N and the
same seed the same image: one more light sample (the light draw and its shadow ray) costs about
a third of a camera sample (camera ray, hit, shading, film) on the peer benchmark's mesh scenes
(2 workers, wall ms at 8 spp for N = 1, 2, 4, 8, a line fitted through them: 40, 50, 69, 109 on
the penumbrae, C_cam / C_light = 3.1; 52, 62, 83, 127 through the thin lens, 3.8; 67, 90, 133,
222 on the 328k-triangle mesh, 2.1, whose shadow rays cross a deep tree; the median is taken).
Measured again once the shadow rays had become cheaper (at first: 2.2 on the penumbrae, 2.1 on
the mesh): with 3.1 the thin lens takes 4 shadow rays instead of 2, its error × time 0.72–0.84×
at 2–16 spp (docs/benchmarks.md, levers). With several "auto" lights each takes N, and a unit of
N costs one light sample per such light.

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
