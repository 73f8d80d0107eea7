"""Splitting: how many shadow rays an area light with ``samples = "auto"`` takes per camera sample.

A pixel's estimate has two kinds of noise: where its camera samples land (the pixel footprint,
the lens, the time) and where on the lights their shadow rays go. With N light samples per
camera sample and n camera samples, the variance of a pixel's mean is

    (V_cam + V_light / N) / n            for a cost of  n (C_cam + N C_light),

and the N that minimises variance × cost is sqrt((V_light / V_cam) · (C_cam / C_light)) (set the
derivative of (V_cam + V_light / N)(C_cam + N C_light) in N to zero).
The renderer measures V_light and V_cam with a pilot: every ``PILOT_ROW_STEP``-th row at
``PILOT_SPP`` camera samples, rendered once with 1 and once with ``PROBE`` light samples per
camera sample, the same camera samples in both (one seed). Per pixel the sample variance of the
luminance is V_cam + V_light in the first and V_cam + V_light / PROBE in the second, which gives
both parts summed over the pixels (the sum is what the image's mean squared error adds up).

The cost ratio is a constant, not a timing, so the same scene always gets the same N and the
same seed the same image: a camera sample (camera ray, hit, shading, film) cost about as much as
one more light sample (the light draw and its shadow ray) on the peer benchmark's mesh scenes
(1 worker, CPU s at 8 spp for N = 1, 2, 4, 8: 0.28, 0.42, 0.70, 1.24 s on the penumbrae; 0.60,
0.89, 1.46, 2.56 s on the 328k-triangle mesh: C_cam / C_light = 1.0 and 1.1). With several
"auto" lights each takes N, and a unit of N costs one light sample per such light.

N is rounded to a power of two (the light samples of a camera sample are then a stratified run of
the sampler's sequence) and kept within [1, MAX_SAMPLES]. The choice is made once per renderer
(the split is the scene's, not the render's) and is independent of the seed, spp and workers.
"""

from __future__ import annotations

import math

import numpy as np

PILOT_SPP = 4  # camera samples per pixel of the pilot
PILOT_ROW_STEP = 8  # the pilot renders every 8th row (at least 16 rows: smaller steps on small images)
PROBE = 8  # light samples per camera sample in the pilot's second render
MAX_SAMPLES = 16  # the most shadow rays per camera sample "auto" gives
COST_RATIO = 1.0  # cost of a camera sample / cost of one light sample (measured, see above)
PILOT_SEED = 0x5EED5  # the pilot's fixed seed: the choice does not depend on the render's


def pilot_rows(height: int) -> tuple[int, int]:
    """(first row, step) of the rows the pilot renders."""
    step = max(1, min(PILOT_ROW_STEP, height // 16))
    return step // 2, step


def variance_split(var_one: np.ndarray, var_probe: np.ndarray, probe: int = PROBE) -> tuple[float, float]:
    """(V_cam, V_light) summed over pixels, from per-pixel sample variances with 1 and ``probe``
    light samples per camera sample (the same camera samples); negative estimates clipped to 0."""
    one = float(np.sum(var_one, dtype=np.float64))
    many = float(np.sum(var_probe, dtype=np.float64))
    v_light = max(one - many, 0.0) * probe / (probe - 1)
    v_cam = max(one - v_light, 0.0)
    return v_cam, v_light


def best_samples(v_cam: float, v_light: float, n_lights: int = 1, cost_ratio: float = COST_RATIO) -> int:
    """The power of two nearest (in log) to sqrt(V_light / V_cam · C_cam / C_light), in
    [1, MAX_SAMPLES]; C_light is ``n_lights`` light samples (one per "auto" light)."""
    if not (v_light > 0.0):
        return 1
    if not (v_cam > 0.0):
        return MAX_SAMPLES
    n = math.sqrt(v_light / v_cam * cost_ratio / max(n_lights, 1))
    if n <= 1.0:
        return 1
    return int(min(MAX_SAMPLES, 2 ** round(math.log2(n))))
