"""The scenes/ files rendered small: the images a layout change must leave bit-identical.

``python -m tests.scene_images --save`` writes them to tests/data/scene_images.npz (run it only
when the physics or the defaults change on purpose, and say so in the commit); ``test_layout.py`` compares.
"""

from __future__ import annotations

import dataclasses
import pathlib
import sys

import numpy as np

ROOT = pathlib.Path(__file__).resolve().parents[1]
DATA = ROOT / "tests" / "data" / "scene_images.npz"
WIDTH, SPP = 48, 2


def render_all(device: str = "cpu", packets: bool | None = None) -> dict[str, np.ndarray]:
    """The saved images are CPU renders (camera rays in packets, the CPU's default); CUDA's agree
    to rounding (its sin, exp and the like round differently), not bit for bit."""
    import warprt

    out = {}
    for path in sorted((ROOT / "scenes").glob("*.toml")):
        scene = warprt.load_scene(str(path))
        cam = scene.camera
        small = dataclasses.replace(cam, width=WIDTH, height=max(1, round(WIDTH * cam.height / cam.width)))
        # the all-features kernel, which most tests compile anyway (a specialised kernel gives the
        # same image bit for bit: tests/test_features.py), instead of one variant per scene file
        out[path.stem] = warprt.Renderer(scene.replace(camera=small), features=warprt.Features.full(),
                                         device=device, packets=packets).render(
            spp=SPP, seed=7, progress=False).image
    return out


if __name__ == "__main__":
    if "--save" in sys.argv:
        DATA.parent.mkdir(parents=True, exist_ok=True)
        np.savez_compressed(DATA, **render_all())
        print(f"wrote {DATA.relative_to(ROOT)}")
