"""Command line: ``warprt render SCENE -o OUT [...]`` (also ``python -m warprt``).

Exit status: 0 on success, 2 for a bad scene or argument (one line naming the file, field and
problem, no traceback) and for an image that could not be written (a full disk, a quota, an I/O
error: one line naming the file and the space free on its disk; the image is written to the
system's temporary folder instead and the line says where), 130 when interrupted (Ctrl-C,
SIGINT), 143 when terminated (SIGTERM, as sent by ``timeout``, Slurm or ``docker stop``), which is
handled as Ctrl-C is. A render interrupted after its first pass still writes the samples
reached: the output line says "interrupted: partial image", and the file carries
``warprt:partial = true`` and ``warprt_spp`` (PNG text chunks, EXR header attributes). Every file
records what reproduces it (``RenderResult.reproduction``: ``warprt_reproduce`` holds the
options, e.g. ``--spp 37 --planned-spp 1024 --seed 0 --sampler stratified`` for a render that a
time budget stopped at 37 samples of a 1024-sample pattern), and an EXR also the camera's
``worldToCamera``/``worldToNDC`` and, with ids, their names (``warprt.results``). ``--exposure``
brightens PNG and JPEG outputs; ``--bits 16`` writes a half-float EXR and a 16-bit PNG (and is
refused for a JPEG before anything renders). A signal while the images are
written is held until they are complete (one line says so; a second one abandons the files
not yet written). Outputs whose disk cannot hold them are refused before rendering.
``render-sequence`` interrupted keeps every frame written so far (each is written as it finishes),
writes no frame that was cut short, prints which frames are complete and which are not written,
and exits 130 (143 for SIGTERM).
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import time
import warnings

from .errors import RenderError, SceneError, WriteError


def _int_in(text: str, lo: int, hi: int | None, expected: str) -> int:
    """``text`` as an integer in [lo, hi] (hi None: unbounded); otherwise an argparse error that
    says what was expected and what was given."""
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected {expected}, got {text!r}") from None
    if v < lo or (hi is not None and v > hi):
        raise argparse.ArgumentTypeError(f"expected {expected}, got {v}")
    return v


def _positive_int(text: str) -> int:
    return _int_in(text, 1, None, "a positive integer")


def _spp(text: str) -> int:
    from .scene.description import SPP_LIMIT

    v = _positive_int(text)
    if v > SPP_LIMIT:
        raise argparse.ArgumentTypeError(f"expected at most {SPP_LIMIT} (2^20) samples per pixel, got {v}; "
                                         "for 'as long as it takes' use --time-budget (or time_budget / "
                                         "target_error in the Python API)")
    return v


def _seed(text: str) -> int:
    return _int_in(text, 0, (1 << 32) - 1, f"an integer from 0 to 2^32 - 1 = {(1 << 32) - 1}")


def _non_negative_int(text: str) -> int:
    return _int_in(text, 0, None, "an integer >= 0")


def _stops(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number of stops, got {text!r}") from None
    if not math.isfinite(v):
        raise argparse.ArgumentTypeError(f"expected a finite number of stops, got {text}")
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
    r = sub.add_parser("render", help="render a TOML scene to .png, .jpg or .exr")
    r.add_argument("scene", help="scene file (TOML)")
    r.add_argument("-o", "--output", required=True, action="append",
                   help="output image (.png, .jpg or .exr); repeat for several formats")
    r.add_argument("--spp", type=_spp, help="samples per pixel (default: the scene's)")
    r.add_argument("--seed", type=_seed, default=0, help="random seed, 0 to 2^32 - 1 (default 0)")
    r.add_argument("--planned-spp", type=_spp,
                   help="lay the sampler's pattern out for this many samples and run the first --spp of them "
                        "(reproduces an image stopped early: its warprt_reproduce header gives both)")
    r.add_argument("--width", type=_positive_int, help="image width in pixels")
    r.add_argument("--height", type=_positive_int, help="image height in pixels")
    r.add_argument("--max-depth", type=_non_negative_int, help="reflection/refraction depth limit")
    r.add_argument("--sampler", choices=["regular", "independent", "stratified", "sobol"],
                   help="pixel sampler (default: the scene's render.sampler, sobol unless it says otherwise)")
    r.add_argument("--device", help="Warp device: cpu, cuda, cuda:0 ... (default: cuda when present)")
    r.add_argument("--workers", type=_positive_int, help="CPU worker threads (default: one per core)")
    r.add_argument("--time-budget", type=_positive_float, help="stop after this many seconds of rendering")
    r.add_argument("--adaptive", action=argparse.BooleanOptionalAction, default=None,
                   help="adaptive sampling: spp is the mean per pixel, noisy pixels get more (decided after the "
                        "first spp/2); by default on (the scene's render.adaptive) unless --time-budget or "
                        "--planned-spp is given; --no-adaptive renders every pixel at spp")
    r.add_argument("--no-progress", action="store_true", help="no progress bar")
    r.add_argument("--aovs", type=_aov_list, default=[],
                   help="extra EXR layers, comma separated: depth,z,normal,albedo,position,coverage,object_id,"
                        "material,motion (coverage makes the EXR premultiplied RGBA); sensor_z,sensor_depth with "
                        "the scene's [depth_sensor]")
    r.add_argument("--exposure", type=_stops, default=0.0,
                   help="brighten .png and .jpg outputs by this many stops (x 2^stops) before the sRGB curve; "
                        ".exr keeps the radiance (default 0)")
    r.add_argument("--bits", type=int, choices=[8, 16, 32],
                   help="bits per channel: 16 writes a half-float .exr and a 16-bit .png (default: 32-bit float "
                        ".exr, 8-bit .png and .jpg)")
    q = sub.add_parser("render-sequence", help="render the frames of an animated scene to numbered images")
    q.add_argument("scene", help="scene file (TOML) with an [animation] table and keyframes")
    q.add_argument("-o", "--output", required=True,
                   help="output pattern, e.g. out/frame_####.png (#### becomes the frame number)")
    q.add_argument("--frames", type=_frame_range,
                   help="frames to render: N, A:B (B excluded) or A:B:STEP, within the animation's frames")
    q.add_argument("--spp", type=_spp, help="samples per pixel (default: the scene's)")
    q.add_argument("--seed", type=_seed, default=0, help="random seed, 0 to 2^32 - 1; frame f uses seed + f (mod 2^32)")
    q.add_argument("--width", type=_positive_int, help="image width in pixels")
    q.add_argument("--height", type=_positive_int, help="image height in pixels")
    q.add_argument("--device", help="Warp device")
    q.add_argument("--executor", choices=["local", "thread", "process", "ray"], default="local",
                   help="where frames render (default: local, one after another)")
    q.add_argument("--jobs", type=_positive_int,
                   help="frames in flight at once with --executor thread or process (default: the pool's)")
    q.add_argument("--no-progress", action="store_true", help="no progress bar")
    return parser


def _aov_list(text: str) -> list[str]:
    from .aov import AOV_NAMES

    known = (*AOV_NAMES, "sensor_z", "sensor_depth")  # (the depth sensor's: warprt.sensor)
    names = [n.strip() for n in text.split(",") if n.strip()]
    bad = [n for n in names if n not in known]
    if bad:
        raise argparse.ArgumentTypeError(f"unknown AOV(s) {', '.join(bad)}; choose from {', '.join(known)}")
    return names


def _frame_range(text: str) -> range:
    try:
        parts = [int(p) for p in text.split(":")]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected N, A:B or A:B:STEP, got {text!r}") from None
    if len(parts) == 1 and parts[0] >= 0:
        return range(parts[0], parts[0] + 1)
    if len(parts) in (2, 3) and all(p >= 0 for p in parts) and (len(parts) == 2 or parts[2] > 0):
        return range(*parts)
    raise argparse.ArgumentTypeError(f"expected N, A:B or A:B:STEP with non-negative numbers, got {text!r}")


def _render(args: argparse.Namespace, run) -> int:
    from .aov import AOVS
    from .errors import WriteError
    from .image import check_bits, check_free_space, check_output, estimate_file_bytes, save_image_or_fallback
    from .memory import check_memory
    from .render import Renderer
    from .scene.loader import load_scene
    from .signals import Deferred, signal_name

    for out in args.output:  # every output checked (and its writer imported) before anything is built
        check_output(out, create_folders=True)
        if args.bits is not None:
            check_bits(os.path.splitext(out)[1].lower(), args.bits, out)
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
    if args.adaptive and args.time_budget is not None:
        raise RenderError("--adaptive takes a sample budget (--spp), not --time-budget")
    if args.planned_spp is not None and args.planned_spp < (args.spp or scene.render.spp):
        raise RenderError(f"--planned-spp ({args.planned_spp}) must be at least --spp ({args.spp or scene.render.spp})")
    if args.planned_spp is not None and args.adaptive:
        raise RenderError("--planned-spp does not combine with --adaptive")
    width, height = scene.camera.width, scene.camera.height
    channels = sum(AOVS[a].channels if a in AOVS else 1 for a in args.aovs)
    check_free_space({out: estimate_file_bytes(out, width, height, channels, args.bits) for out in args.output})
    start = time.perf_counter()
    renderer = Renderer(scene, device=args.device)
    check_memory(width, height, args.aovs, [os.path.splitext(o)[1] for o in args.output],
                 film_on_host=renderer.device.is_cpu, bits=args.bits)  # before compiling or rendering
    # (the render loads the scene's kernel, or starts on the general one while it compiles)
    result = renderer.render(spp=args.spp, seed=args.seed, workers=args.workers, time_budget=args.time_budget,
                             progress=not args.no_progress, aovs=args.aovs or None, adaptive=args.adaptive,
                             planned_spp=args.planned_spp)
    # (the result brings its metadata: what reproduces it, warprt:partial = true for a partial
    # image, the camera matrices, the background and the ids' names)

    # the samples are done: from here a signal waits for the files (a second one abandons those
    # not yet written), and a full disk sends the image to the temporary folder
    written: list[str] = []
    failed: list[WriteError] = []

    def finishing(signum: int) -> None:
        pending = [o for o in args.output if o not in written]
        print(f"warprt: {signal_name(signum)}: writing {', '.join(pending)} first; press Ctrl-C again to abandon",
              file=sys.stderr, flush=True)

    try:
        with Deferred(abandon_on=2, on_first=finishing):
            for out in args.output:
                folder = os.path.dirname(out)
                if folder:
                    os.makedirs(folder, exist_ok=True)
                try:
                    save_image_or_fallback(result, out, exposure=args.exposure, bits=args.bits)
                    written.append(out)
                except WriteError as e:
                    failed.append(e)
    except KeyboardInterrupt:
        lost = [o for o in args.output if o not in written]
        print(f"warprt: interrupted while writing: {', '.join(lost)} abandoned (not written)"
              + (f"; {', '.join(written)} written" if written else ""), file=sys.stderr)
        return run.exit_code()
    for e in failed:
        print(f"warprt: error: {e}", file=sys.stderr)
    total = time.perf_counter() - start
    h, w = result.image.shape[:2]
    note = " (interrupted: partial image)" if result.interrupted else ""
    if run.received and not result.interrupted:
        note = f" (interrupted by {signal_name(run.first)} while writing: the files are complete)"
    if result.stack_overflows:
        print(f"warning: {result.stack_overflows} rays dropped on full ray stacks (lower max_depth)", file=sys.stderr)
    general = (f"; {result.general_passes} passes on the general kernel while the scene's own compiled"
               if result.general_passes else "")
    if written:
        print(f"{', '.join(written)}: {w}x{h}, {result.spp} spp{note}, render {result.wall_time:.2f} s "
              f"(total {total:.2f} s, kernel load {result.kernel_load:.2f} s{general}), {result.rays / 1e6:.2f} Mrays, "
              f"{result.mrays_per_s:.2f} Mrays/s on {result.device}")
    if failed:
        return 2
    return run.exit_code() if (result.interrupted or run.received) else 0


def _render_sequence(args: argparse.Namespace, run) -> int:
    from .animation import check_frames, frame_path, render_sequence
    from .batch import render_frames
    from .errors import FramesInterrupted
    from .image import check_free_space, check_output, estimate_file_bytes
    from .scene.loader import load_scene

    check_output(args.output, create_folders=True)  # the pattern's extension and folder, before rendering
    scene = load_scene(args.scene)
    cam = {k: v for k, v in (("width", args.width), ("height", args.height)) if v is not None}
    if cam:
        try:
            scene = scene.with_camera(**cam)
        except SceneError as e:
            raise e.within(source=args.scene) from None
    frames = check_frames(scene, args.frames, name=f"{args.scene}: --frames")  # (named after the file)
    check_free_space({frame_path(args.output, f): estimate_file_bytes(args.output, scene.camera.width,
                                                                      scene.camera.height) for f in frames})
    start = time.perf_counter()
    try:
        if args.executor == "local":
            paths = render_sequence(scene, output=args.output, frames=frames, spp=args.spp, seed=args.seed,
                                    device=args.device, progress=not args.no_progress)
        else:
            paths = render_frames(scene, frames=frames, spp=args.spp, seed=args.seed, executor=args.executor,
                                  device=args.device, max_workers=args.jobs, output=args.output)
    except FramesInterrupted as e:  # the finished frames are written; the one(s) cut short are not
        print(e.summary())
        return run.exit_code()
    total = time.perf_counter() - start
    print(f"{len(paths)} frames ({paths[0]} ... {paths[-1]}) in {total:.2f} s, {total / len(paths):.2f} s per frame")
    return run.exit_code() if run.received else 0


def _show_warning(message, category, filename, lineno, file=None, line=None) -> None:
    """Warnings (huge scene extents, dropped mesh faces) as one line each, without source lines."""
    print(f"warprt: warning: {message}", file=sys.stderr)


def main(argv: list[str] | None = None) -> int:
    """Run the command line; returns the exit status. ``argv`` None: the process's own arguments,
    and the process exits here once the work is over (see :func:`_leave`), SIGINT and SIGTERM
    ignored from then on (nothing of the exit can be interrupted into a traceback); with ``argv``
    the previous handlers come back and the status is returned."""
    from .signals import program, signal_name

    with program(ignore_after=argv is None) as run:
        try:
            args = build_parser().parse_args(argv)
            with warnings.catch_warnings():
                warnings.showwarning = _show_warning
                code = _main(args, run)
        except KeyboardInterrupt:  # e.g. while Warp or the scene was loading, or a kernel compiled
            print("warprt: interrupted" + (f" ({signal_name(run.first)})" if run.first not in (None, 2) else ""),
                  file=sys.stderr)
            code = run.exit_code()
        except Exception:
            # an interrupt that a library turned into its own error (a KeyboardInterrupt inside
            # NumPy's C import of datetime comes out as an ImportError): the signal decides
            if not run.received:
                raise
            print("warprt: interrupted" + (f" ({signal_name(run.first)})" if run.first != 2 else ""), file=sys.stderr)
            code = run.exit_code()
    if argv is None:
        _leave(code)
    return code


def _leave(code: int) -> None:
    """End the process now, with ``code``, once the outputs are written and the streams flushed:
    the interpreter's normal teardown unloads Warp's runtime and modules, which takes about a
    second (the time a Ctrl-C would otherwise wait after the work had stopped), and a compile the
    command stopped waiting for (``warprt._warp.abandoned_compiles``, its build folder removed)
    would be waited for or torn down under it. Not where Ray was started (its own exit handler
    stops the local cluster)."""
    warp_side = sys.modules.get("warprt._warp")
    if warp_side is not None:
        warp_side.abandoned_compiles()
    compiles = sys.modules.get("warprt.kernels")
    if compiles is not None:  # (os._exit runs no exit handlers: the background compiles' hand-over here)
        compiles._hand_over_compiles()
    ray = sys.modules.get("ray")
    if ray is not None and getattr(ray, "is_initialized", lambda: False)():
        return
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):
            pass
    os._exit(code)


def _main(args: argparse.Namespace, run) -> int:
    try:
        if args.command == "render":
            return _render(args, run)
        if args.command == "render-sequence":
            return _render_sequence(args, run)
    except (SceneError, RenderError) as e:
        if run.received and not isinstance(e, WriteError):
            raise  # (an error of an interrupted step: main reports the interrupt)
        print(f"warprt: error: {e}", file=sys.stderr)
        return 2
    return 2


if __name__ == "__main__":
    sys.exit(main())
