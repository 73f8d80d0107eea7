"""Command line: ``warprt render SCENE -o OUT [...]`` (also ``python -m warprt``).

Exit status: 0 on success, 2 for a bad scene or argument (one line naming the file, field and
problem, no traceback), 130 when interrupted before any sample was rendered.
"""

from __future__ import annotations

import argparse
import os
import sys
import time

from .errors import RenderError, SceneError


def _positive_int(text: str) -> int:
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}") from None
    if v < 1:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {v}")
    return v


def _non_negative_int(text: str) -> int:
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer >= 0, got {text!r}") from None
    if v < 0:
        raise argparse.ArgumentTypeError(f"expected an integer >= 0, got {v}")
    return v


def _positive_float(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number of seconds, got {text!r}") from None
    if not v > 0:
        raise argparse.ArgumentTypeError(f"expected a positive number, got {text}")
    return v


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="warprt", description="Ray trace scenes with NVIDIA Warp kernels.")
    sub = parser.add_subparsers(dest="command", required=True)
    r = sub.add_parser("render", help="render a TOML scene to .png or .exr")
    r.add_argument("scene", help="scene file (TOML)")
    r.add_argument("-o", "--output", required=True, action="append",
                   help="output image (.png or .exr); repeat for several formats")
    r.add_argument("--spp", type=_positive_int, help="samples per pixel (default: the scene's)")
    r.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    r.add_argument("--width", type=_positive_int, help="image width in pixels")
    r.add_argument("--height", type=_positive_int, help="image height in pixels")
    r.add_argument("--max-depth", type=_non_negative_int, help="reflection/refraction depth limit")
    r.add_argument("--sampler", choices=["regular", "independent", "stratified", "sobol"], help="pixel sampler")
    r.add_argument("--device", help="Warp device: cpu, cuda, cuda:0 ... (default: cuda when present)")
    r.add_argument("--workers", type=_positive_int, help="CPU worker threads (default: one per core)")
    r.add_argument("--time-budget", type=_positive_float, help="stop after this many seconds of rendering")
    r.add_argument("--no-progress", action="store_true", help="no progress bar")
    return parser


def _render(args: argparse.Namespace) -> int:
    from .image import FORMATS, save_image
    from .render import Renderer
    from .scene.loader import load_scene

    for out in args.output:
        ext = os.path.splitext(out)[1].lower()
        if ext not in FORMATS:
            raise RenderError(f"{out}: unsupported image format {ext or '(none)'!r}; use .exr or .png")
    scene = load_scene(args.scene)
    cam = {k: v for k, v in (("width", args.width), ("height", args.height)) if v is not None}
    settings = {k: v for k, v in (("max_depth", args.max_depth), ("sampler", args.sampler)) if v is not None}
    try:
        if cam:
            scene = scene.with_camera(**cam)
        if settings:
            scene = scene.with_settings(**settings)
    except SceneError as e:
        raise e.within(source=args.scene) from None
    start = time.perf_counter()
    renderer = Renderer(scene, device=args.device)
    compile_s = renderer.compile()
    result = renderer.render(spp=args.spp, seed=args.seed, workers=args.workers, time_budget=args.time_budget,
                             progress=not args.no_progress)
    meta = {"warprt_spp": result.spp, "warprt_seed": args.seed, "warprt_interrupted": int(result.interrupted)}
    for out in args.output:
        folder = os.path.dirname(out)
        if folder:
            os.makedirs(folder, exist_ok=True)
        save_image(result.image, out, metadata=meta)
    total = time.perf_counter() - start
    h, w = result.image.shape[:2]
    note = " (interrupted)" if result.interrupted else ""
    if result.stack_overflows:
        print(f"warning: {result.stack_overflows} rays dropped on full ray stacks (lower max_depth)", file=sys.stderr)
    print(f"{', '.join(args.output)}: {w}x{h}, {result.spp} spp{note}, render {result.wall_time:.2f} s "
          f"(total {total:.2f} s, kernel load {compile_s:.2f} s), {result.rays / 1e6:.2f} Mrays, "
          f"{result.mrays_per_s:.2f} Mrays/s on {result.device}")
    return 0


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        if args.command == "render":
            return _render(args)
    except (SceneError, RenderError) as e:
        print(f"warprt: error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("warprt: interrupted", file=sys.stderr)
        return 130
    return 2


if __name__ == "__main__":
    sys.exit(main())
