"""The glossy / frosted lobe (``sampling.square_to_cos_power`` and ``integrator.lobe``, which turns
it about an axis with ``frame_from_z``), checked at the device level against closed forms.

The lobe's documented density is p_n(ω) = (n+1)/(2π)·cosⁿθ about its axis, so:

* E[1 - cos θ] = 1/(n+2) and E[1 - cos² θ] = 2/(n+3) (the moments E[cos θ] = (n+1)/(n+2) and
  E[cos² θ] = (n+1)/(n+3), written as distances from 1 so that they keep their precision at
  large n, where cos θ is within 1e-4 of 1);
* the density is normalised and is the one drawn: ∫ p_{2n+1} dω = 1 estimated as the mean of
  p_{2n+1}(ω)/p_n(ω) over the lobe's own draws (per-sample variance exactly 1/3 for every n);
* the azimuth about the axis is uniform: E[cos kφ] = E[sin kφ] = 0 and equal counts in 16 sectors.

Tolerances: 4 standard errors of the sample mean, from the samples' own spread, plus a bound on
the per-sample float32 error of cos θ (COS_ERROR, from its measured error against the same map
in float64; a mean cannot be off by more than its worst sample). Every device call goes through the one kernel
below: one Warp module, compiled once.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import warp as wp

from warprt.integrator import lobe
from warprt.sampling import square_to_cos_power

N = 1 << 18
EXPONENTS = [0.0, 1.0, 10.0, 1.0e4]
# float32 rounding of cos θ, measured over these draws against float64 at the same u: within 4e-8
# for the map about +z (under one ulp of 1, 6e-8) and 1.4e-7 once turned about an axis
# (frame_from_z adds a few roundings); bounds of 2 and 4 ulps of 1. |d| - 1 reaches 1.8e-7.
COS_ERROR = {"local": 2.0 ** -23, "world": 2.0 ** -22}
AXES = {"tilted": (0.3, -0.5, 0.8), "nearly -z": (0.02, 0.05, -1.0)}  # both branches of frame_from_z


@wp.kernel(enable_backward=False)
def lobe_kernel(u: wp.array(dtype=wp.vec2), axis: wp.vec3, n: float,
                local: wp.array(dtype=wp.vec3), world: wp.array(dtype=wp.vec3)):
    i = wp.tid()
    local[i] = square_to_cos_power(u[i], n)
    world[i] = lobe(u[i], axis, n)


def draw(n: float, axis, device="cpu", seed=0):
    """(u, local, world, unit axis): N uniform points (float32, as the samplers give), the lobe
    directions about +z and about ``axis``, as float64."""
    u = np.random.default_rng(seed).random((N, 2), dtype=np.float32)
    a = np.asarray(axis, np.float64)
    a /= np.linalg.norm(a)
    local = wp.zeros(N, dtype=wp.vec3, device=device)
    world = wp.zeros(N, dtype=wp.vec3, device=device)
    wp.launch(lobe_kernel, dim=N, device=device,
              inputs=[wp.array(u, dtype=wp.vec2, device=device), wp.vec3(*a.astype(np.float32)), float(n)],
              outputs=[local, world])
    return u.astype(np.float64), local.numpy().astype(np.float64), world.numpy().astype(np.float64), a


def basis(a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Any float64 orthonormal pair perpendicular to the unit vector a (not the device's)."""
    t = np.cross(a, [1.0, 0.0, 0.0] if abs(a[0]) < 0.9 else [0.0, 1.0, 0.0])
    t /= np.linalg.norm(t)
    return t, np.cross(a, t)


def assert_mean(x: np.ndarray, expected: float, per_sample_error: float, what: str):
    """mean(x) = expected within 4 standard errors plus the worst per-sample rounding error."""
    se = float(x.std(ddof=1)) / math.sqrt(len(x))
    err = abs(float(x.mean()) - expected)
    assert err <= 4.0 * se + per_sample_error, (what, float(x.mean()), expected, err / se)


@pytest.mark.parametrize("n", EXPONENTS, ids=lambda n: f"n={n:g}")
@pytest.mark.parametrize("axis", list(AXES.values()), ids=list(AXES))
def test_lobe_moments_and_normalisation_match_closed_forms(n, axis):
    u, local, world, a = draw(n, axis)
    # float64 inverse CDF of the same u: cos θ = (1 - u0)^(1/(n+1))
    cos_ref = np.maximum(1.0 - u[:, 0], 1e-30) ** (1.0 / (n + 1.0))
    for frame, d in (("local", local), ("world", world)):
        c = d[:, 2] if frame == "local" else d @ a
        np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0, atol=2.0 ** -22)  # unit directions
        # the inverse CDF sample by sample: only float32 rounding apart from float64
        assert float(np.abs(c - cos_ref).max()) <= COS_ERROR[frame], frame
        # the moments, each allowed its 4 standard errors plus the worst rounding of its samples
        # (a bound fixed in advance, not the observed deviation, which a wrong map would inflate)
        e = COS_ERROR[frame]
        assert_mean(1.0 - c, 1.0 / (n + 2.0), e, f"{frame}: E[1 - cos]")
        assert_mean((1.0 - c) * (1.0 + c), 2.0 / (n + 3.0), 2.0 * e, f"{frame}: E[1 - cos²]")
        # ∫ p_m dω = 1 for m = 2n+1, estimated with the lobe's own draws: mean of p_m / p_n =
        # 2·cos^(n+1) θ, whose slope in cos θ is at most 2(n+1)
        m = 2.0 * n + 1.0
        ratio = (m + 1.0) / (n + 1.0) * np.maximum(c, 0.0) ** (m - n)
        assert_mean(ratio, 1.0, 2.0 * (n + 1.0) * e, f"{frame}: normalisation")


@pytest.mark.parametrize("n", EXPONENTS, ids=lambda n: f"n={n:g}")
def test_lobe_azimuth_is_uniform_about_its_axis(n):
    _, local, world, a = draw(n, AXES["tilted"], seed=1)
    t, s = basis(a)
    for frame, d, (e1, e2) in (("local", local, (np.array([1.0, 0, 0]), np.array([0, 1.0, 0]))),
                               ("world", world, (t, s))):
        x, y = d @ e1, d @ e2
        ok = np.hypot(x, y) > 0  # u0 = 0 gives the axis itself: no azimuth
        phi = np.arctan2(y[ok], x[ok])
        for k in (1, 2):  # each has variance 1/2 per sample under a uniform azimuth
            for f in (np.cos(k * phi), np.sin(k * phi)):
                assert abs(float(f.mean())) <= 4.0 * math.sqrt(0.5 / len(phi)), (frame, k, float(f.mean()))
        counts = np.histogram(phi, bins=16, range=(-math.pi, math.pi))[0]
        p = 1.0 / 16
        sigma = math.sqrt(len(phi) * p * (1 - p))
        assert np.abs(counts - len(phi) * p).max() <= 4.0 * sigma, (frame, counts)
