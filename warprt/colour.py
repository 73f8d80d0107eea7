"""Colour encodings: warprt's linear RGB and the sRGB display encoding, in one place.

warprt shades in linear RGB (Rec. 709 / sRGB primaries, the radiance values a render returns).
Displays, PNG and JPEG files, Newton's shape colours and glTF textures speak *sRGB-encoded* values
in [0, 1]. The two curves of IEC 61966-2-1 convert between them:

* :func:`linear_to_srgb`: the sRGB encoding (the "OETF"): 12.92·x up to x = 0.0031308, then
  1.055·x^(1/2.4) − 0.055. A linear image is **clipped to [0, 1] first** (values above 1 show as
  white, NaN as black): what ``plt.imshow(warprt.linear_to_srgb(image))`` needs to show a render
  as a PNG viewer would.
* :func:`srgb_to_linear`: its inverse (the decoding of an sRGB colour or texel): c / 12.92 up to
  c = 0.04045, then ((c + 0.055) / 1.055)^2.4, also on values clipped to [0, 1].

The **view transform** of warprt's 8-bit and 16-bit outputs (PNG, JPEG, notebook display,
``--exposure`` on the command line) is :func:`view`: the image times 2^exposure (exposure in
stops), then :func:`linear_to_srgb` — Blender's "Standard" view: no tone curve, so radiance
above 1 (after exposure) clips. :func:`quantize` rounds the encoded values to 8 or 16 bits.
EXR files keep the linear values themselves (no exposure, no curve).
"""

from __future__ import annotations

import numpy as np

# IEC 61966-2-1: the linear segment's slope and end (encoded: 12.92 × 0.0031308 = 0.04045 to four
# places), the power segment's exponent and offset
SRGB_SLOPE = 12.92
SRGB_LINEAR_END = 0.0031308  # linear value where the power segment starts
SRGB_ENCODED_END = 0.04045  # the same point, encoded
SRGB_GAMMA = 2.4
SRGB_SCALE = 1.055
SRGB_OFFSET = 0.055


def _unit(x, dtype) -> np.ndarray:
    """x as an array of ``dtype`` in [0, 1]: NaN and -inf become 0, +inf 1."""
    a = np.asarray(x, dtype=dtype)
    return np.clip(np.nan_to_num(a, nan=0.0, posinf=1.0, neginf=0.0), 0.0, 1.0)


def linear_to_srgb(x) -> np.ndarray:
    """Linear RGB (any shape) to sRGB-encoded values in [0, 1], clipped first (see the module
    docstring). Float32 in, float32 out; float64 (or Python numbers) in, float64 out."""
    dtype = np.float32 if np.asarray(x).dtype == np.float32 else np.float64
    a = _unit(x, dtype)
    with np.errstate(invalid="ignore"):
        s = np.where(a <= SRGB_LINEAR_END, SRGB_SLOPE * a,
                     SRGB_SCALE * np.power(a, 1.0 / SRGB_GAMMA) - SRGB_OFFSET)
    return s.astype(dtype, copy=False)[()]  # ([()]: a number for a number)


def srgb_to_linear(c) -> np.ndarray:
    """sRGB-encoded values (any shape, clipped to [0, 1]) to linear RGB: the inverse of
    :func:`linear_to_srgb`. Float32 in, float32 out; float64 (or Python numbers) in, float64 out."""
    dtype = np.float32 if np.asarray(c).dtype == np.float32 else np.float64
    a = _unit(c, dtype)
    lin = np.where(a <= SRGB_ENCODED_END, a / SRGB_SLOPE, np.power((a + SRGB_OFFSET) / SRGB_SCALE, SRGB_GAMMA))
    return lin.astype(dtype, copy=False)[()]


def check_exposure(exposure) -> float:
    """``exposure`` (stops) as a finite float, else a RenderError naming it."""
    from .errors import RenderError

    if isinstance(exposure, bool) or not isinstance(exposure, (int, float, np.integer, np.floating)) \
            or not np.isfinite(exposure):
        raise RenderError(f"exposure must be a finite number of stops, got {exposure!r:.60}")
    return float(exposure)


def view(image, exposure: float = 0.0, dtype=np.float32) -> np.ndarray:
    """The view transform of warprt's display outputs: ``image`` × 2^exposure, then
    :func:`linear_to_srgb` (clipped to [0, 1]); in [0, 1], same shape, computed in ``dtype``
    (float32; float64 for 16-bit outputs, whose levels are finer than float32's curve)."""
    a = np.asarray(image, dtype=dtype)
    if exposure:
        a = a * dtype(2.0 ** exposure)
    return linear_to_srgb(a)


def quantize(encoded: np.ndarray, bits: int) -> np.ndarray:
    """Encoded values in [0, 1] rounded to the nearest of 2^bits levels: uint8 (bits 8) or uint16
    (bits 16)."""
    top = (1 << bits) - 1
    dtype = np.uint8 if bits == 8 else np.uint16
    return np.clip(np.round(np.asarray(encoded, dtype=np.float64 if bits == 16 else np.float32) * top),
                   0, top).astype(dtype)


__all__ = ["linear_to_srgb", "srgb_to_linear", "view", "quantize"]
