"""The film: per-pixel accumulation buffers, sample sanitising, and the image they hold.

Each pixel accumulates the sum of its samples' radiance (float32 linear RGB), the sum of their
squared luminance (for the variance estimate behind ``target_error``), the rays traced and the
rays dropped by a full ray stack. The image is the sum over the sample count, as numpy (host) or
as a (H, W, 3) ``wp.array`` left on the device.
"""

from __future__ import annotations

import math

import numpy as np
import warp as wp

from ._warp import build_once


@wp.struct
class FilmData:
    accum: wp.array(dtype=wp.vec3)  # Σ radiance
    accum_sq: wp.array(dtype=float)  # Σ luminance²
    rays: wp.array(dtype=int)  # rays traced
    overflow: wp.array(dtype=int)  # rays dropped because the pixel's ray stack was full


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


@build_once
def _image_kernel():
    @wp.kernel(module="warprt_film", enable_backward=False)
    def image_kernel(accum: wp.array(dtype=wp.vec3), inv_spp: float, width: int, out: wp.array3d(dtype=float)):
        i = wp.tid()
        c = accum[i] * inv_spp
        y = i / width
        x = i - y * width
        out[y, x, 0] = c[0]
        out[y, x, 1] = c[1]
        out[y, x, 2] = c[2]

    return image_kernel


class Film:
    """Accumulation buffers for a width × height image on one device."""

    def __init__(self, width: int, height: int, device):
        self.width, self.height, self.device = width, height, device
        n = width * height
        self.data = FilmData()
        self.data.accum = wp.zeros(n, dtype=wp.vec3, device=device)
        self.data.accum_sq = wp.zeros(n, dtype=float, device=device)
        self.data.rays = wp.zeros(n, dtype=int, device=device)
        self.data.overflow = wp.zeros(n, dtype=int, device=device)

    def image(self, spp: int) -> np.ndarray:
        """The mean of the samples, (H, W, 3) float32 on the host."""
        return (self.data.accum.numpy() * np.float32(1.0 / spp)).reshape(self.height, self.width, 3)

    def device_image(self, spp: int) -> "wp.array":
        """The mean of the samples as a (H, W, 3) float32 ``wp.array`` on the film's device (the
        same values as :meth:`image`)."""
        out = wp.zeros((self.height, self.width, 3), dtype=float, device=self.device)
        wp.launch(_image_kernel(), dim=self.width * self.height, device=self.device,
                  inputs=[self.data.accum, 1.0 / float(spp), self.width, out])
        return out

    def rays(self) -> int:
        return int(self.data.rays.numpy().sum(dtype=np.int64))

    def overflows(self) -> int:
        return int(self.data.overflow.numpy().sum(dtype=np.int64))

    def relative_error(self, spp: int) -> float:
        """RMS over pixels of the standard error of each pixel's mean luminance, over the mean
        luminance (from ``spp`` samples per pixel)."""
        n = spp
        rgb = self.data.accum.numpy().astype(np.float64) / n
        y = 0.2126 * rgb[:, 0] + 0.7152 * rgb[:, 1] + 0.0722 * rgb[:, 2]
        var = np.maximum(self.data.accum_sq.numpy().astype(np.float64) / n - y * y, 0.0) * n / max(n - 1, 1)
        mean = float(y.mean())
        return math.sqrt(float(var.mean()) / n) / mean if mean > 0 else 0.0
