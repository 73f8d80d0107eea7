"""Shared helpers for the stability tests (not a test module).

Every render here uses the all-features kernel, so the whole package compiles one render-kernel
variant (plus the query module) however many scenes it renders.
"""

from __future__ import annotations

import numpy as np

import warprt
from warprt import Features

FULL = Features.full()
SPAWN_REL = 2.0 ** -17  # documented spawn offset: |coords| * 2^-17 along the geometric normal


def render(scene: warprt.Scene, spp: int = 1, seed: int = 0, **kw) -> warprt.RenderResult:
    return warprt.Renderer(scene, device="cpu", features=FULL).render(spp=spp, seed=seed, progress=False, **kw)


def image(scene: warprt.Scene, spp: int = 1, seed: int = 0, **kw) -> np.ndarray:
    return render(scene, spp, seed, **kw).image


def unit(a) -> np.ndarray:
    a = np.asarray(a, np.float64)
    return a / np.linalg.norm(a, axis=-1, keepdims=True)


def max_abs(a) -> np.ndarray:
    return np.abs(np.asarray(a, np.float64)).max(axis=-1)


def pixel_hits(scene: warprt.Scene):
    """Camera rays through the pixel centres (what ``sampler="regular"`` at 1 spp renders) and
    their nearest hits, row-major; origins/directions as float64 copies of the float32 rays."""
    o, d = warprt.camera_rays(scene)
    h = warprt.trace_rays(scene, o, d)
    return o.astype(np.float64), d.astype(np.float64), h
