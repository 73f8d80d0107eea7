"""Moiré: regular supersampling aliases a fine periodic pattern into low-frequency error.

Failure mode: thin stripes receding in perspective have, towards the horizon, a frequency above
any fixed sampling rate. A regular n×n grid of samples per pixel (``sampler="regular"``, the
naive supersampler: the same stratum centres in every pixel) samples them at one fixed rate, so
the excess frequency folds back into a smooth false pattern (moiré) that more samples on the
same kind of grid only move towards the horizon: its error hardly falls with spp. Jittered
stratified samples and Owen-scrambled Sobol points (warprt's ``stratified`` and its default
``sobol``) turn the same error into fine noise that falls with spp. Every render is uniform
(``adaptive=False``): each pixel takes the spp of its sampler's pattern.

Measured against a converged reference (Sobol, 1024 spp) at equal spp = 4, 16, 64 (2×2, 4×4,
8×8 grids for ``regular``); stratified and Sobol errors are RMS over 4 seeds. Moiré is error
that survives a low-pass filter, so the main measure is the RMS of the 4×4-block means of the
error image (the block error); white noise keeps 1/√16 = 0.25 of its RMS through that filter.

Measured on this scene (block error at 4 / 16 / 64 spp; log-log slope; low-pass share):

    regular     0.080 / 0.071 / 0.052   slope -0.16   share 0.49 / 0.73 / 0.68
    stratified  0.035 / 0.014 / 0.007   slope -0.58   share 0.25 / 0.25 / 0.28
    sobol       0.029 / 0.009 / 0.003   slope -0.85   share 0.25 / 0.25 / 0.22

(other seeds: stratified slopes -0.56 ... -0.65, Sobol -0.83 ... -0.85, shares at most 0.30;
``regular`` does not depend on the seed). Every render uses ``_util``'s all-features kernel, as
the original test in tests/test_distribution.py did. About 4 s on 2 CPU cores.
"""

from __future__ import annotations

import numpy as np
import pytest

import warprt

from ._util import render

SPPS = (4, 16, 64)  # n×n grids for the regular sampler
SEEDS = range(1, 5)  # stratified / sobol; the reference uses another seed
REFERENCE_SPP, REFERENCE_SEED = 1024, 99
SIZE, BLOCK = 32, 4

# bounds (measured values in the module docstring)
MOIRE_FACTOR = 2.0  # regular's block error exceeds stratified's and Sobol's by this at every spp
MOIRE_FACTOR_AT_64 = 5.0  # ... and by this at 64 spp (measured 7.4 and 16)
REGULAR_SLOPE_MIN = -0.3  # regular's block error falls more slowly than spp^-0.3 (measured -0.16)
STRATIFIED_SLOPE_MAX = -0.45  # stratified falls at least as spp^-0.45 (measured -0.56 ... -0.65)
SOBOL_SLOPE_MAX = -0.65  # Sobol at least as spp^-0.65 (measured -0.83 ... -0.85)
SLOPE_GAP = 0.3  # and both at least this much steeper than regular
REGULAR_SHARE_MIN = 0.45  # regular's error is mostly low-frequency (block RMS / RMS, measured >= 0.49)
NOISE_SHARE_MAX = 0.35  # stratified / Sobol error is noise-like: white noise gives 0.25 (measured <= 0.30)


def stripes_scene() -> warprt.Scene:
    """60 thin white stripes (0.12 wide, every 0.5) on a black floor, seen receding to the horizon;
    ambient-only shading, so a pixel's exact value is the stripe coverage of its footprint."""
    stripes = tuple(warprt.Rectangle(corner=(-20, 0, -0.5 - k * 0.5), edge1=(0, 0, 0.12), edge2=(40, 0, 0),
                                     material="white") for k in range(60))
    return warprt.Scene(camera=warprt.Camera(eye=(0, 1.0, 1.0), look_at=(0, 0, -4), fov=50, width=SIZE, height=SIZE),
                        shapes=stripes, materials={"white": warprt.Material(kd=0.0, ka=1.0)}, ambient=1.0)


def _slope(errors) -> float:
    return float(np.polyfit(np.log(SPPS), np.log(errors), 1)[0])


@pytest.fixture(scope="module")
def errors():
    """{sampler: (block errors, RMS errors)}, one entry per spp in SPPS."""
    scene = stripes_scene()
    reference = render(scene.with_settings(sampler="sobol"), REFERENCE_SPP, seed=REFERENCE_SEED,
                       adaptive=False).image[..., 0]
    n = SIZE // BLOCK

    def mse(img):
        d = img[..., 0].astype(np.float64) - reference
        return float(np.mean(d.reshape(n, BLOCK, n, BLOCK).mean(axis=(1, 3)) ** 2)), float(np.mean(d ** 2))

    out = {}
    for sampler in ("regular", "stratified", "sobol"):
        seeds = [0] if sampler == "regular" else SEEDS  # regular: the same samples for every seed
        s = scene.with_settings(sampler=sampler)
        per_spp = [np.mean([mse(render(s, spp, seed=seed, adaptive=False).image) for seed in seeds], axis=0)
                   for spp in SPPS]
        out[sampler] = (np.sqrt([b for b, _ in per_spp]), np.sqrt([r for _, r in per_spp]))
    return out


def test_regular_sampling_shows_moire_where_stratified_does_not(errors):
    """At equal spp, the regular grid's low-frequency error is several times that of stratified
    and Sobol samples (moved here from tests/test_distribution.py, where it compared 4 spp)."""
    regular = errors["regular"][0]
    for ours in ("stratified", "sobol"):
        e = errors[ours][0]
        assert (regular > MOIRE_FACTOR * e).all(), (ours, regular, e)
        assert regular[-1] > MOIRE_FACTOR_AT_64 * e[-1], (ours, regular, e)


def test_regular_error_does_not_fall_with_spp_like_stratified_and_sobol(errors):
    """The moiré is structured aliasing: a finer regular grid only shifts it, so its error
    barely falls from 4 to 64 spp, while jittered and Sobol samples converge."""
    slopes = {s: _slope(errors[s][0]) for s in errors}
    assert slopes["regular"] > REGULAR_SLOPE_MIN, slopes
    assert slopes["stratified"] < STRATIFIED_SLOPE_MAX, slopes
    assert slopes["sobol"] < SOBOL_SLOPE_MAX, slopes
    assert max(slopes["stratified"], slopes["sobol"]) < slopes["regular"] - SLOPE_GAP, slopes
    # and over the whole range: 16x the samples leave regular with most of its error
    regular = errors["regular"][0]
    assert regular[-1] > 0.5 * regular[0], regular
    for ours in ("stratified", "sobol"):
        assert errors[ours][0][-1] < 0.3 * errors[ours][0][0], (ours, errors[ours][0])


def test_regular_error_is_low_frequency_and_ours_is_noise(errors):
    """Share of the error that survives 4x4 block averaging: white noise keeps 1/4 of its RMS;
    the regular grid's moiré keeps about half or more."""
    for sampler, (block, rms) in errors.items():
        share = block / rms
        if sampler == "regular":
            assert (share > REGULAR_SHARE_MIN).all(), (sampler, share)
        else:
            assert (share < NOISE_SHARE_MAX).all(), (sampler, share)
