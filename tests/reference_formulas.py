"""Closed forms shared by the tests (float64 NumPy, written independently of warprt's code)."""

from __future__ import annotations

import numpy as np


def fresnel_exact(cos_i, eta_i, eta_t):
    """Unpolarised dielectric reflectance for light arriving at cos_i from the eta_i side; 1 under
    total internal reflection."""
    cos_i = np.clip(cos_i, 0.0, 1.0)
    sin_t = eta_i / eta_t * np.sqrt(np.maximum(0.0, 1.0 - cos_i ** 2))
    cos_t = np.sqrt(np.maximum(0.0, 1.0 - sin_t ** 2))
    with np.errstate(invalid="ignore", divide="ignore"):
        rs = (eta_i * cos_i - eta_t * cos_t) / (eta_i * cos_i + eta_t * cos_t)
        rp = (eta_t * cos_i - eta_i * cos_t) / (eta_t * cos_i + eta_i * cos_t)
    return np.where(sin_t >= 1.0, 1.0, 0.5 * (rs ** 2 + rp ** 2))


def fresnel_schlick(cos_i, eta_i, eta_t):
    """Schlick's approximation r0 + (1 - r0)(1 - c)^5; from the denser side c is the transmitted
    angle's cosine, and total internal reflection gives 1."""
    r0 = ((eta_i - eta_t) / (eta_i + eta_t)) ** 2
    c = np.clip(cos_i, 0.0, 1.0)
    sin_t2 = (eta_i / eta_t) ** 2 * (1.0 - c * c)
    c = np.where(eta_i > eta_t, np.sqrt(np.maximum(0.0, 1.0 - sin_t2)), c)
    return np.where(sin_t2 >= 1.0, 1.0, r0 + (1.0 - r0) * (1.0 - c) ** 5)
