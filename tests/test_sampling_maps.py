"""The cone and disk maps (``sampling.square_to_cone``, ``sampling.square_to_disk``: sphere
lights and the thin lens) at the device level, against closed forms of their moments:

* cone of 1 - cos θmax = a, uniform in solid angle: 1 - cos θ is uniform on [0, a], so
  E[1 - cos θ] = a/2 and E[(1 - cos θ)²] = a²/3; the azimuth is uniform;
* unit disk, uniform by area: E[r²] = 1/2, E[r⁴] = 1/3, E[x] = E[y] = 0, r <= 1.

Tolerances: 4 standard errors of the sample mean (from the samples' own spread) plus float32
rounding of one sample (a mean is never further off than its worst sample).

The disk map's sine and cosine are float32 polynomials (``sampling.quarter_sin``,
``quarter_cos``): those against float64 in ulps, and the map point by point against the
concentric map in float64, each within a margin over its measured error.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import warp as wp

from warprt.sampling import quarter_cos, quarter_sin, square_to_cone, square_to_disk

N = 1 << 18
EPS = 2.0 ** -22


@wp.kernel(enable_backward=False)
def maps_kernel(u: wp.array(dtype=wp.vec2), a: float, cone: wp.array(dtype=wp.vec3), disk: wp.array(dtype=wp.vec2)):
    i = wp.tid()
    cone[i] = square_to_cone(u[i], a)
    disk[i] = square_to_disk(u[i])


def draw(a: float, seed: int = 0):
    u = np.random.default_rng(seed).random((N, 2), dtype=np.float32)
    cone = wp.zeros(N, dtype=wp.vec3, device="cpu")
    disk = wp.zeros(N, dtype=wp.vec2, device="cpu")
    wp.launch(maps_kernel, dim=N, device="cpu", inputs=[wp.array(u, dtype=wp.vec2, device="cpu"), float(a)],
              outputs=[cone, disk])
    return cone.numpy().astype(np.float64), disk.numpy().astype(np.float64)


def assert_mean(x, expected, scale, what):
    se = float(x.std(ddof=1)) / math.sqrt(len(x))
    err = abs(float(x.mean()) - expected)
    assert err <= 4.0 * se + EPS * scale, (what, float(x.mean()), expected, err / max(se, 1e-300))


@pytest.mark.parametrize("a", [1e-4, 0.05, 0.6, 1.0, 2.0], ids=lambda a: f"1-cos={a:g}")
def test_cone_is_uniform_in_solid_angle(a):
    cone, _ = draw(a)
    one_minus = 1.0 - cone[:, 2]
    assert (one_minus >= -EPS).all() and (one_minus <= a * (1 + 1e-6) + EPS).all()
    np.testing.assert_allclose(np.linalg.norm(cone, axis=1), 1.0, atol=4 * EPS)
    assert_mean(one_minus, a / 2, a, "E[1 - cos]")
    assert_mean(one_minus ** 2, a * a / 3, a * a, "E[(1 - cos)^2]")
    phi = np.arctan2(cone[:, 1], cone[:, 0])
    for k in (1, 2):
        assert_mean(np.cos(k * phi), 0.0, 1.0, f"E[cos {k}phi]")
        assert_mean(np.sin(k * phi), 0.0, 1.0, f"E[sin {k}phi]")


def test_disk_is_uniform_by_area():
    _, disk = draw(0.5)
    r2 = np.sum(disk ** 2, axis=1)
    assert (r2 <= 1.0 + 4 * EPS).all()
    assert_mean(r2, 0.5, 1.0, "E[r^2]")
    assert_mean(r2 ** 2, 1.0 / 3.0, 1.0, "E[r^4]")
    assert_mean(disk[:, 0], 0.0, 1.0, "E[x]")
    assert_mean(disk[:, 1], 0.0, 1.0, "E[y]")
    # equal mass in the 8 octants of the concentric map
    octant = ((np.arctan2(disk[:, 1], disk[:, 0]) + math.pi) / (math.pi / 4)).astype(int) % 8
    counts = np.bincount(octant, minlength=8)
    assert np.abs(counts - N / 8).max() < 5 * math.sqrt(N / 8 * 7 / 8)


@wp.kernel(enable_backward=False)
def quarter_kernel(x: wp.array(dtype=float), s: wp.array(dtype=float), c: wp.array(dtype=float)):
    i = wp.tid()
    s[i] = quarter_sin(x[i])
    c[i] = quarter_cos(x[i])


def _ulps(got: np.ndarray, want: np.ndarray) -> np.ndarray:
    """|got - want| in units of the float32 spacing at |want|."""
    return np.abs(got - want) / np.spacing(np.abs(want).astype(np.float32)).astype(np.float64)


def test_quarter_sin_and_cos_hold_float32_accuracy():
    """``quarter_sin`` and ``quarter_cos`` (the concentric map's polynomials) against float64 sin
    and cos over [-π/4, π/4], its ends, zero and tiny arguments: within 1.5 ulp of the float64
    value (measured: 0.76 ulp for sin, 1.10 for cos; a correctly rounded result is within 0.5)."""
    x = np.concatenate([np.linspace(-math.pi / 4, math.pi / 4, 1 << 20, dtype=np.float32),
                        np.float32(math.pi) / np.float32(4) * np.float32([1, -1]),
                        np.float32([0, 1e-30, -1e-30, 1e-6, 2e-3])])
    s = wp.zeros(len(x), dtype=float, device="cpu")
    c = wp.zeros(len(x), dtype=float, device="cpu")
    wp.launch(quarter_kernel, dim=len(x), device="cpu", inputs=[wp.array(x, dtype=float, device="cpu"), s, c])
    xs = x.astype(np.float64)
    assert _ulps(s.numpy().astype(np.float64), np.sin(xs)).max() <= 1.5
    assert _ulps(c.numpy().astype(np.float64), np.cos(xs)).max() <= 1.5


def test_disk_is_the_concentric_map():
    """``square_to_disk`` against the concentric map (Shirley-Chiu) in float64, from its own
    float32 a = 2u − 1, b = 2v − 1: radius max(|a|, |b|), angle π/4·b/a or π/2 − π/4·a/b, within
    1.5e-7 absolute (measured 1.03e-7: a few float32 roundings of 6e-8 at radius 1), over random
    points, the square's edges and corners, its diagonals and centre."""
    rng = np.random.default_rng(5)
    t = np.linspace(0, 1, 257, dtype=np.float32)
    u = np.concatenate([rng.random((1 << 16, 2), dtype=np.float32),
                        np.stack([t, np.zeros_like(t)], 1), np.stack([t, np.ones_like(t)], 1),
                        np.stack([np.zeros_like(t), t], 1), np.stack([t, t], 1), np.stack([t, 1 - t], 1),
                        np.float32([[0.5, 0.5]])]).astype(np.float32)
    disk = wp.zeros(len(u), dtype=wp.vec2, device="cpu")
    cone = wp.zeros(len(u), dtype=wp.vec3, device="cpu")
    wp.launch(maps_kernel, dim=len(u), device="cpu", inputs=[wp.array(u, dtype=wp.vec2, device="cpu"), 0.5],
              outputs=[cone, disk])
    a = (np.float32(2) * u[:, 0] - np.float32(1)).astype(np.float64)
    b = (np.float32(2) * u[:, 1] - np.float32(1)).astype(np.float64)
    wide = np.abs(a) > np.abs(b)
    with np.errstate(divide="ignore", invalid="ignore"):
        r = np.where(wide, a, b)
        phi = np.where(wide, math.pi / 4 * b / a, math.pi / 2 - math.pi / 4 * a / b)
    want = np.stack([r * np.cos(phi), r * np.sin(phi)], 1)
    want[(a == 0) & (b == 0)] = 0.0
    assert np.abs(disk.numpy().astype(np.float64) - want).max() <= 1.5e-7
