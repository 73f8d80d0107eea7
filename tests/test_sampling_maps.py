"""The cone and disk maps (``sampling.square_to_cone``, ``sampling.square_to_disk``: sphere
lights and the thin lens) at the device level, against closed forms of their moments:

* cone of 1 - cos θmax = a, uniform in solid angle: 1 - cos θ is uniform on [0, a], so
  E[1 - cos θ] = a/2 and E[(1 - cos θ)²] = a²/3; the azimuth is uniform;
* unit disk, uniform by area: E[r²] = 1/2, E[r⁴] = 1/3, E[x] = E[y] = 0, r <= 1.

Tolerances: 4 standard errors of the sample mean (from the samples' own spread) plus float32
rounding of one sample (a mean is never further off than its worst sample).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import warp as wp

from warprt.sampling import square_to_cone, square_to_disk

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
