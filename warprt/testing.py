"""Image checks for pytest suites (warprt's own and its users').

* :func:`assert_images_close` compares two images by relative MSE and/or per-pixel tolerance;
  on failure it says by how much, where, and writes a difference image (PNG heat map plus an EXR
  with ``actual``, ``expected`` and ``diff`` layers) whose path is in the message.
* The pytest plugin (registered through the ``pytest11`` entry point, so installing warprt is
  enough) provides the ``warprt_reference`` fixture: ``warprt_reference(image)`` compares with
  ``references/<test name>.exr`` next to the test file, and writes that file when it is missing
  or when ``WARPRT_UPDATE_REFERENCES=1`` (the test then fails once, asking for a re-run, so a new
  reference is never taken silently on CI).

Difference images go to ``WARPRT_DIFF_DIR`` when set, else to a temporary folder.
"""

from __future__ import annotations

import os
import re
import tempfile
from pathlib import Path

import numpy as np

__all__ = ["assert_images_close", "relative_mse", "ImageMismatch"]


class ImageMismatch(AssertionError):
    """Two images differ beyond tolerance; ``diff_path`` is the written difference image."""

    def __init__(self, message: str, diff_path: str | None):
        super().__init__(message)
        self.diff_path = diff_path


def relative_mse(actual, expected, eps: float = 1e-12) -> float:
    """mean((actual - expected)^2) / mean(expected^2): 0 for equal images, scale free."""
    a = np.asarray(actual, dtype=np.float64)
    b = np.asarray(expected, dtype=np.float64)
    return float(np.mean((a - b) ** 2) / (np.mean(b ** 2) + eps))


def _diff_dir() -> Path:
    d = os.environ.get("WARPRT_DIFF_DIR")
    path = Path(d) if d else Path(tempfile.gettempdir()) / "warprt-diffs"
    path.mkdir(parents=True, exist_ok=True)
    return path


def _write_diff(actual: np.ndarray, expected: np.ndarray, name: str) -> str:
    from .image import linear_to_srgb8, write_exr

    diff = np.abs(actual - expected)
    heat = diff.max(axis=-1) if diff.ndim == 3 else diff
    scale = float(heat.max()) or 1.0
    stem = re.sub(r"[^A-Za-z0-9_.-]+", "_", name) or "image"
    folder = _diff_dir()
    png = folder / f"{stem}-diff.png"
    exr = folder / f"{stem}-diff.exr"
    from PIL import Image

    rgb = np.stack([heat / scale, np.zeros_like(heat), 1.0 - heat / scale], axis=-1)
    side = np.concatenate([linear_to_srgb8(_rgb(actual)), linear_to_srgb8(_rgb(expected)), linear_to_srgb8(rgb)], axis=1)
    Image.fromarray(side, mode="RGB").save(png)
    layers = {}
    for label, img in (("actual", actual), ("expected", expected), ("diff", diff)):
        img = _rgb(img)
        for k, c in enumerate("RGB"):
            layers[f"{label}.{c}"] = img[..., k]
    layers["RGB"] = _rgb(diff)
    write_exr(str(exr), layers)
    return str(png)


def _rgb(img: np.ndarray) -> np.ndarray:
    img = np.asarray(img, dtype=np.float32)
    if img.ndim == 2:
        return np.repeat(img[..., None], 3, axis=-1)
    return img[..., :3] if img.shape[-1] >= 3 else np.repeat(img[..., :1], 3, axis=-1)


def assert_images_close(actual, expected, *, rel_mse: float | None = None, atol: float | None = None,
                        rtol: float = 0.0, max_bad_fraction: float = 0.0, name: str = "image") -> None:
    """Fail (ImageMismatch) unless ``actual`` matches ``expected``.

    Criteria, each checked when given: ``rel_mse`` bounds :func:`relative_mse`; ``atol``/``rtol``
    bound every pixel's error |a - e| <= atol + rtol·|e|, allowing a fraction ``max_bad_fraction``
    of pixels to exceed it. With neither, the images must be equal. NaN anywhere fails.
    """
    a = np.asarray(actual, dtype=np.float32)
    e = np.asarray(expected, dtype=np.float32)
    if a.shape != e.shape:
        raise ImageMismatch(f"{name}: shape {a.shape} differs from expected {e.shape}", None)
    problems = []
    if np.isnan(a).any() or np.isnan(e).any():
        problems.append(f"NaN in {'actual' if np.isnan(a).any() else 'expected'} "
                        f"({int(np.isnan(a).sum() + np.isnan(e).sum())} values)")
    if rel_mse is None and atol is None and not rtol:
        atol = 0.0
    if rel_mse is not None:
        value = relative_mse(a, e)
        if not value <= rel_mse:
            problems.append(f"relative MSE {value:.3g} > {rel_mse:.3g}")
    if atol is not None or rtol:
        tol = (atol or 0.0) + rtol * np.abs(e)
        err = np.abs(a - e)
        bad = err > tol
        frac = float(bad.mean())
        if frac > max_bad_fraction:
            worst = np.unravel_index(int(np.argmax(err - tol)), err.shape)
            problems.append(f"{int(bad.sum())} of {bad.size} values ({frac:.2%}) beyond |a - e| <= "
                            f"{atol or 0.0:g} + {rtol:g}|e|; worst at {tuple(int(i) for i in worst)}: "
                            f"actual {float(a[worst]):.6g}, expected {float(e[worst]):.6g}")
    if problems:
        path = _write_diff(a, e, name)
        raise ImageMismatch(f"{name}: " + "; ".join(problems) + f" (difference image: {path})", path)


# --- pytest plugin -------------------------------------------------------------------------------

try:
    import pytest
except ImportError:  # warprt works without pytest; the fixture needs it
    pytest = None

if pytest is not None:

    @pytest.fixture
    def warprt_reference(request):
        """Compare an image with this test's stored reference (see the module docstring)."""
        folder = Path(request.node.fspath).parent / "references"
        test = re.sub(r"[^A-Za-z0-9_.-]+", "_", request.node.name)

        def check(image, name: str | None = None, rel_mse: float = 1e-4, **tolerances):
            from .image import read_exr, save_image

            path = folder / f"{test}{'-' + name if name else ''}.exr"
            update = os.environ.get("WARPRT_UPDATE_REFERENCES") == "1"
            if update or not path.exists():
                folder.mkdir(parents=True, exist_ok=True)
                save_image(np.asarray(image), str(path))
                pytest.fail(f"reference {path.name} written; check it and run the test again", pytrace=False)
            expected, _ = read_exr(str(path))
            assert_images_close(image, expected, rel_mse=rel_mse, name=path.stem, **tolerances)

        return check
