"""``python -m warprt.compile FEATURES PACKETS DEVICE``: one render kernel compiled into Warp's
kernel cache by a process of its own, at low priority: what a process that ends while a render
kernel compiles in the background starts (``warprt.kernels._hand_over_compiles``), so that the
next run finds the kernel in the cache."""

from __future__ import annotations

import os
import sys

from . import _warp  # noqa: F401  (Warp initialised with warprt's settings)
from .integrator import kernels_for
from .kernels import BACKGROUND_NICE, load
from .records import Features


def main(argv: list[str]) -> int:
    """The render kernel of feature key ``argv[0]`` (``Features.key``, e.g. ``meshes+area_lights``),
    packets ``argv[1]`` (0 or 1), for device ``argv[2]``, compiled into Warp's kernel cache
    (``WARP_CACHE_PATH``: the starting process's), at low priority."""
    if hasattr(os, "nice"):
        os.nice(BACKGROUND_NICE)
    key, packets, device = argv[0], bool(int(argv[1])), argv[2]
    features = Features(**{name: True for name in key.split("+") if name != "basic"})
    load(kernels_for(features, packets).render, device)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
