"""Regenerate the images of the effects documentation (docs/effects/) and the README.

Every image is rendered on the CPU from a scene file in scenes/ (reduced in size where noted;
the radiometry comparison from a small scene built below) with seed 0, so a rerun on the same
machine writes the same pixels. Single renders go straight
to PNG through ``warprt.save_image``; comparisons render each panel the same way, then Pillow
crops, zooms (nearest neighbour, so pixels stay visible), labels and puts the panels side by side.

    python examples/make_doc_images.py                          # every image into docs/images/
    python examples/make_doc_images.py out/img --only glossy soft_shadows_samples
    python examples/make_doc_images.py out/quick --scale 0.2 --max-spp 2   # a quick look, seconds
    python examples/make_doc_images.py --list

``--scale`` and ``--max-spp`` are for trying the script (and for the test suite): every image,
crop and panel shrinks by the scale and no render takes more samples per pixel than the limit.
The images in docs/images/ are made with neither.

The first run compiles one render kernel per feature set the scenes use (a few seconds each on a
cold cache, see WARP_CACHE_PATH). On the 2-core development machine the whole set takes about
45 s with the kernels cached and 70 s with an empty cache, and comes to about 0.5 MB.
"""

from __future__ import annotations

import argparse
import dataclasses
import tempfile
import time
from pathlib import Path
from typing import Callable

import numpy as np
from PIL import Image, ImageDraw, ImageFont

import warprt

ROOT = Path(__file__).resolve().parents[1]
SCENES = ROOT / "scenes"
DEFAULT_OUT = ROOT / "docs" / "images"
SEED = 0

LABEL_H = 22  # height of the caption bar under each panel
GAP = 4  # pixels between panels

# Set by --scale and --max-spp (1 and no limit for the documentation's images).
SCALE = 1.0
MAX_SPP: int | None = None


# --- helpers -----------------------------------------------------------------------------------


def scaled(pixels: int) -> int:
    """A size or coordinate in pixels at the --scale in force (at least 1)."""
    return max(1, round(pixels * SCALE))


def load(name: str, width: int | None = None, height: int | None = None) -> warprt.Scene:
    """A scene file at the given size (default: the file's), times --scale."""
    scene = warprt.load_scene(SCENES / f"{name}.toml")
    width = scene.camera.width if width is None else width
    height = scene.camera.height if height is None else height
    return scene.with_camera(width=scaled(width), height=scaled(height))


def render(scene: warprt.Scene, spp: int | None = None) -> np.ndarray:
    """Render on the CPU with the scene's own (specialised) kernel, at ``spp`` (default: the
    scene's) capped by --max-spp; returns linear RGB."""
    spp = scene.render.spp if spp is None else spp
    if MAX_SPP is not None:
        spp = min(spp, MAX_SPP)
    result = warprt.Renderer(scene, device="cpu").render(spp=spp, seed=SEED, progress=False)
    return result.image


def with_light(scene: warprt.Scene, **changes) -> warprt.Scene:
    """Change a field (e.g. ``samples``) of every area light."""
    lights = tuple(dataclasses.replace(l, **changes) if not isinstance(l, warprt.PointLight) else l
                   for l in scene.lights)
    return scene.replace(lights=lights)


class Panels:
    """Renders saved through save_image into a temporary folder, read back with Pillow."""

    def __init__(self, tmp: Path):
        self.tmp = tmp
        self.count = 0

    def __call__(self, image: np.ndarray, label: str, crop: tuple[int, int, int, int] | None = None,
                 zoom: int = 1) -> tuple[Image.Image, str]:
        self.count += 1
        path = self.tmp / f"panel{self.count}.png"
        warprt.save_image(image, str(path))  # the same sRGB conversion as every other doc image
        with Image.open(path) as im:
            im = im.convert("RGB")
            if crop is not None:
                im = im.crop(tuple(scaled(c) for c in crop))  # (left, top, right, bottom) in pixels
            if zoom != 1:
                im = im.resize((im.width * zoom, im.height * zoom), Image.NEAREST)
            return im.copy(), label


def side_by_side(panels: list[tuple[Image.Image, str]], path: Path, columns: int | None = None) -> None:
    """Panels in rows of ``columns`` (default: one row), each with its caption underneath, on a
    dark background."""
    font = ImageFont.load_default(size=14)
    columns = columns or len(panels)
    rows = [panels[i:i + columns] for i in range(0, len(panels), columns)]
    cell_w = max(p.width for p, _ in panels)
    cell_h = max(p.height for p, _ in panels) + LABEL_H
    sheet = Image.new("RGB", (cell_w * columns + GAP * (columns - 1), cell_h * len(rows) + GAP * (len(rows) - 1)),
                      (32, 32, 32))
    draw = ImageDraw.Draw(sheet)
    for r, row in enumerate(rows):
        for c, (im, label) in enumerate(row):
            x, y = c * (cell_w + GAP), r * (cell_h + GAP)
            sheet.paste(im, (x, y))
            tw = draw.textlength(label, font=font)
            draw.text((x + (im.width - tw) / 2, y + im.height + 3), label, fill=(235, 235, 235), font=font)
    sheet.save(path, optimize=True)


# --- the images ----------------------------------------------------------------------------------
# Each function writes one PNG into `out` (a Path) and may use `panels` for comparisons.


def showcase(out: Path, panels: Panels) -> None:
    """scenes/showcase.toml reduced to 320x180 (the file's 32 spp, Sobol)."""
    warprt.save_image(render(load("showcase", 320, 180)), str(out / "showcase.png"))


def antialiasing(out: Path, panels: Panels) -> None:
    """The stripes scene with the stratified sampler at the file's 64 spp (the file itself uses
    the regular sampler to show moire)."""
    scene = load("antialiasing").with_settings(sampler="stratified")
    warprt.save_image(render(scene, 64), str(out / "antialiasing.png"))


def antialiasing_samplers(out: Path, panels: Panels) -> None:
    """A region left of the centre, from above the horizon down the floor, zoomed 2x: one sample
    at the pixel centre, the four samplers at 4 spp, and a converged reference."""
    base = load("antialiasing")  # 320x240
    crop, zoom = (10, 70, 130, 160), 2
    row = [panels(render(base.with_settings(sampler="regular"), 1), "1 spp (pixel centre)", crop, zoom)]
    for sampler in ("regular", "independent", "stratified", "sobol"):
        row.append(panels(render(base.with_settings(sampler=sampler), 4), f"{sampler}, 4 spp", crop, zoom))
    row.append(panels(render(base.with_settings(sampler="sobol"), 1024), "reference (1024 spp)", crop, zoom))
    side_by_side(row, out / "antialiasing_samplers.png", columns=3)


def glossy(out: Path, panels: Panels) -> None:
    """scenes/glossy.toml at its size and 128 spp."""
    warprt.save_image(render(load("glossy")), str(out / "glossy.png"))


def soft_shadows(out: Path, panels: Panels) -> None:
    """scenes/soft_shadows.toml at its size, 32 spp, 2 light samples."""
    warprt.save_image(render(load("soft_shadows")), str(out / "soft_shadows.png"))


def soft_shadows_samples(out: Path, panels: Panels) -> None:
    """The penumbrae under the rectangle and sphere lights at 4 spp with 1 and 16 shadow rays per
    light, and a converged reference; zoomed 2x."""
    base = load("soft_shadows")
    crop, zoom = (20, 95, 200, 185), 2
    row = [panels(render(with_light(base, samples=1), 4), "samples = 1, 4 spp", crop, zoom),
           panels(render(with_light(base, samples=16), 4), "samples = 16, 4 spp", crop, zoom),
           panels(render(with_light(base, samples=4), 256), "reference (1024 rays/light)", crop, zoom)]
    side_by_side(row, out / "soft_shadows_samples.png")


def depth_of_field(out: Path, panels: Panels) -> None:
    """scenes/depth_of_field.toml at its size and 64 spp."""
    warprt.save_image(render(load("depth_of_field")), str(out / "depth_of_field.png"))


def depth_of_field_focus(out: Path, panels: Panels) -> None:
    """Pinhole, the file's lens (focused on the third sphere) and the same lens focused on the
    second sphere."""
    base = load("depth_of_field", 256, 160)
    row = [panels(render(base.with_camera(aperture=0.0), 16), "aperture = 0 (pinhole)"),
           panels(render(base, 64), "aperture = 0.15, focus 5.5"),
           panels(render(base.with_camera(focus_distance=4.0), 64), "aperture = 0.15, focus 4.0")]
    side_by_side(row, out / "depth_of_field_focus.png")


def motion_blur(out: Path, panels: Panels) -> None:
    """scenes/motion_blur.toml at its size and 48 spp."""
    warprt.save_image(render(load("motion_blur")), str(out / "motion_blur.png"))


def motion_blur_shutter(out: Path, panels: Panels) -> None:
    """The same scene with the shutter closed at time 0, open over half the motion, and the
    file's [0, 1]."""
    base = load("motion_blur", 256, 160)
    row = [panels(render(base.with_camera(shutter=(0.0, 0.0)), 16), "shutter [0, 0]"),
           panels(render(base.with_camera(shutter=(0.0, 0.5)), 48), "shutter [0, 0.5]"),
           panels(render(base, 48), "shutter [0, 1]")]
    side_by_side(row, out / "motion_blur_shutter.png")


def mirror(out: Path, panels: Panels) -> None:
    """scenes/mirror.toml at its size (240x180), 16 spp."""
    warprt.save_image(render(load("mirror"), 16), str(out / "mirror.png"))


def refraction(out: Path, panels: Panels) -> None:
    """scenes/refraction.toml at its size (240x180), 16 spp."""
    warprt.save_image(render(load("refraction"), 16), str(out / "refraction.png"))


def refraction_depth(out: Path, panels: Panels) -> None:
    """The glass ball with max_depth 0, 1, 2 and the default 5."""
    base = load("refraction", 200, 150)
    row = [panels(render(base.with_settings(max_depth=d), 16), f"max_depth = {d}") for d in (0, 1, 2, 5)]
    side_by_side(row, out / "refraction_depth.png")


def shadows(out: Path, panels: Panels) -> None:
    """scenes/shadows.toml at its size (240x180), 16 spp."""
    warprt.save_image(render(load("shadows"), 16), str(out / "shadows.png"))


def radiometry(out: Path, panels: Panels) -> None:
    """A sphere on a floor lit from (0, 2, 1) by: a point light with falloff "none" (I = 1), one
    with "inverse_square" (I = 4: the same irradiance right under the light, 2 below it), a
    sphere light of radius 0.05 and radiance 4/r^2 (its point-light limit is the inverse-square
    light of I = Le r^2 = 4), and one of radius 0.5 with the same Le r^2."""
    pos = (0.0, 2.0, 1.0)
    base = warprt.Scene(
        camera=warprt.Camera(eye=(0.0, 2.2, 5.0), look_at=(0.0, 0.4, 0.0), fov=40, width=scaled(200),
                             height=scaled(150)),
        shapes=(warprt.Plane(material="floor"), warprt.Sphere(center=(0.0, 0.5, 0.0), radius=0.5, material="ball")),
        materials={"floor": warprt.Material(kd=0.7), "ball": warprt.Material(kd=(0.8, 0.3, 0.2), ks=0.3, p=40)},
        ambient=0.03, render=warprt.RenderSettings(sampler="sobol"))

    def lit(light):
        return base.replace(lights=(light,))

    row = [panels(render(lit(warprt.PointLight(position=pos, intensity=1.0)), 16), 'point, "none", I = 1'),
           panels(render(lit(warprt.PointLight(position=pos, intensity=4.0, falloff="inverse_square")), 16),
                  'point, "inverse_square", I = 4'),
           panels(render(lit(warprt.SphereLight(center=pos, radius=0.05, radiance=4.0 / 0.05 ** 2, samples=4)), 64),
                  "sphere, r = 0.05, Le = 4/r^2"),
           panels(render(lit(warprt.SphereLight(center=pos, radius=0.5, radiance=4.0 / 0.5 ** 2, samples=4)), 64),
                  "sphere, r = 0.5, Le = 4/r^2")]
    side_by_side(row, out / "radiometry.png")


IMAGES: dict[str, Callable[[Path, Panels], None]] = {f.__name__: f for f in (
    showcase, antialiasing, antialiasing_samplers, glossy, soft_shadows, soft_shadows_samples, depth_of_field,
    depth_of_field_focus, motion_blur, motion_blur_shutter, mirror, refraction, refraction_depth, shadows,
    radiometry)}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out_dir", nargs="?", default=str(DEFAULT_OUT),
                        help="folder for the PNGs (default docs/images/)")
    parser.add_argument("--only", nargs="+", metavar="NAME", choices=sorted(IMAGES), help="make only these images")
    parser.add_argument("--list", action="store_true", help="list the images and exit")
    parser.add_argument("--scale", type=float, default=1.0,
                        help="scale every image size and crop by this factor (default 1: the docs' images)")
    parser.add_argument("--max-spp", type=int, metavar="N", help="render at most N samples per pixel")
    args = parser.parse_args(argv)
    if not 0 < args.scale <= 1:
        parser.error(f"--scale must be in (0, 1], got {args.scale}")
    if args.max_spp is not None and args.max_spp < 1:
        parser.error(f"--max-spp must be at least 1, got {args.max_spp}")
    global SCALE, MAX_SPP
    SCALE, MAX_SPP = args.scale, args.max_spp
    if args.list:
        for name, f in IMAGES.items():
            print(f"{name}.png: {' '.join((f.__doc__ or '').split())}")
        return 0

    out = Path(args.out_dir)
    out.mkdir(parents=True, exist_ok=True)
    start = time.perf_counter()
    total_bytes = 0
    with tempfile.TemporaryDirectory() as tmp:
        panels = Panels(Path(tmp))
        for name in args.only or IMAGES:
            t0 = time.perf_counter()
            IMAGES[name](out, panels)
            path = out / f"{name}.png"
            size = path.stat().st_size
            total_bytes += size
            with Image.open(path) as im:
                w, h = im.size
            print(f"{path}: {w}x{h}, {size / 1024:.0f} KiB, {time.perf_counter() - t0:.1f} s", flush=True)
    print(f"{len(args.only or IMAGES)} images, {total_bytes / 1024:.0f} KiB, {time.perf_counter() - start:.1f} s "
          f"(kernel compiles included)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
