"""Animation: keyframed scenes, frame by frame, without kernel recompiles or BVH rebuilds.

A scene's ``[animation]`` table gives ``frames`` and ``fps``; frame f shows time f / fps. Spheres
(``center``), meshes, boxes, capsules and cylinders (``translate``/``rotate`` or
``quaternion``/``scale``) and the camera
(``eye``/``look_at``) may carry ``keyframes``: positions and scales are interpolated linearly in
time, rotations by slerp (clamped at the ends; Euler keys 180 degrees or more apart get
intermediate keys so that they turn the way their angles say, see
:func:`warprt.scene.transform.rotation_keys`).
``frame_scene(scene, f)`` gives the plain scene of frame f, with the pose at the next frame's
time as the motion-blur end pose, so the camera shutter ([0, 1] by default) spans one frame.

Rendering a sequence reuses one :class:`warprt.Renderer`: ``Renderer.update`` re-uploads the
small tables, keeps every mesh asset (its ``wp.Mesh`` and BVH) and keeps the compiled kernel as
long as the frame needs no new feature.
"""

from __future__ import annotations

import os
import re
import sys
from dataclasses import replace

import numpy as np

from .errors import FramesInterrupted, RenderError, WriteError, frame_list
from .image import check_output, save_image_or_fallback
from .render import Renderer, check_seed
from .results import RenderLayers
from .scene.description import SOLID_TYPES, Camera, Mesh, Scene, Sphere
from .scene.transform import Transform, interpolate_rotation, rotation_keys


def _interp(keyframes, t: float, name: str, default):
    keys = [k for k in keyframes if name in k]
    if not keys:
        return default
    if t <= keys[0]["time"]:
        return keys[0][name]
    if t >= keys[-1]["time"]:
        return keys[-1][name]
    for a, b in zip(keys, keys[1:]):
        if a["time"] <= t <= b["time"]:
            f = (t - a["time"]) / (b["time"] - a["time"])
            return tuple(float(x + (y - x) * f) for x, y in zip(a[name], b[name]))
    return default


def _rotation_keys(m: Mesh) -> list:
    """The mesh's rotation keys as (time, quaternion), Euler keys turned into quaternions (with
    the keys rotation_keys inserts between Euler keys 180 degrees or more apart)."""
    keys = [(k["time"], ("quaternion", k["quaternion"]) if "quaternion" in k else ("rotate", k["rotate"]))
            for k in m.keyframes if "rotate" in k or "quaternion" in k]
    return rotation_keys(keys)


def _mesh_transform(m: Mesh, t: float) -> Transform:
    base = m.transform or Transform()
    translate = _interp(m.keyframes, t, "translate", base.translate)
    scale = _interp(m.keyframes, t, "scale", base.scale)
    keys = _rotation_keys(m)
    if not keys:  # no rotation keys: the mesh keeps its own rotation, however it was given
        return Transform(translate=translate, rotate=base.rotate, scale=scale,
                         rotation_quaternion=base.rotation_quaternion)
    return Transform(translate=translate, scale=scale, rotation_quaternion=tuple(interpolate_rotation(keys, t)))


def frame_scene(scene: Scene, frame: int) -> Scene:
    """The scene at ``frame``: keyframed values at time frame/fps, end poses at (frame+1)/fps."""
    fps = scene.animation.fps
    t0, t1 = frame / fps, (frame + 1) / fps
    shapes = []
    for s in scene.shapes:
        if isinstance(s, Sphere) and s.keyframes:
            s = replace(s, center=_interp(s.keyframes, t0, "center", s.center),
                        center_end=_interp(s.keyframes, t1, "center", s.center))
        elif isinstance(s, (Mesh, *SOLID_TYPES)) and s.keyframes:
            s = replace(s, transform=_mesh_transform(s, t0), transform_end=_mesh_transform(s, t1))
        shapes.append(s)
    cam: Camera = scene.camera
    if cam.keyframes:
        cam = replace(cam, eye=_interp(cam.keyframes, t0, "eye", cam.eye),
                      look_at=_interp(cam.keyframes, t0, "look_at", cam.look_at),
                      eye_end=_interp(cam.keyframes, t1, "eye", cam.eye),
                      look_at_end=_interp(cam.keyframes, t1, "look_at", cam.look_at))
    return replace(scene, shapes=tuple(shapes), camera=cam)


def frame_path(pattern: str, frame: int) -> str:
    """Output path of a frame: ``####`` (any run of #) becomes the zero-padded frame number;
    ``{frame}`` style fields are formatted; otherwise ``_NNNN`` goes before the extension."""
    if "#" in pattern:
        return re.sub(r"#+", lambda m: f"{frame:0{len(m.group(0))}d}", pattern, count=1)
    if "{" in pattern:
        return pattern.format(frame=frame)
    root, ext = os.path.splitext(pattern)
    return f"{root}_{frame:04d}{ext}"


def check_pattern(output) -> str:
    """An output pattern must be a path (str or os.PathLike)."""
    if not isinstance(output, (str, os.PathLike)):
        raise RenderError(f"output: expected a path pattern such as 'out/frame_####.png', got {output!r:.60}")
    return os.fspath(output)


def frame_seed(seed: int, frame: int) -> int:
    """Each frame gets its own noise (seed + frame), the same wherever the frame is rendered."""
    return (int(seed) + int(frame)) & 0xFFFFFFFF


def check_frames(scene: Scene, frames=None, name: str = "frames") -> list[int]:
    """The frame numbers to render (default: all of them), each an integer in [0, animation.frames):
    a frame past the animation's end is an error, not a silent render of the last pose."""
    if not isinstance(scene, Scene):
        raise RenderError(f"expected a warprt.Scene, got {type(scene).__name__}")
    n = scene.animation.frames
    if frames is not None and (isinstance(frames, (str, bytes)) or not hasattr(frames, "__iter__")):
        raise RenderError(f"{name}: expected a list or range of frame numbers, got {frames!r:.60}")
    frames = list(range(n)) if frames is None else list(frames)
    if not frames:
        raise RenderError(f"{name}: no frames to render")
    for f in frames:
        if isinstance(f, bool) or not isinstance(f, (int, np.integer)):
            raise RenderError(f"{name}: frame numbers must be integers, got {f!r}")
        if not 0 <= f < n:
            raise RenderError(f"{name}: frame {f} is outside the animation, which has frames 0 to {n - 1} "
                              f"([animation] frames = {n})")
    return [int(f) for f in frames]


def keep_frame(output: str | None, frame: int, image, spp: int, metadata: dict | None = None, result=None):
    """A finished frame: the image itself, or with ``output`` the path it was written to
    (atomically, its folder created, with its spp and frame number in the metadata, after the
    render's own ``metadata``; ``result``, where there is one, is written whole instead of
    ``image``: its AOVs and metadata with it)."""
    if output is None:
        return image
    path = frame_path(output, frame)
    folder = os.path.dirname(path)
    if folder:
        os.makedirs(folder, exist_ok=True)
    save_image_or_fallback(image if result is None else result, path,
                           metadata={**(metadata or {}), "warprt_spp": spp, "warprt_frame": frame})
    return path


def _frames_were(frames: list) -> str:
    return f"frame {frames[0]} was" if len(frames) == 1 else f"frames {frame_list(frames)} were"


def frame_write_failed(e: WriteError, frame: int, frames: list, done: list) -> WriteError:
    """A frame's failed write (the frame itself went to the temporary folder, see
    ``image.save_image_or_fallback``) as one line that also says which frames were written and
    which were not rendered."""
    rest = [f for f in frames if f not in done and f != frame]
    text = f"frame {frame}: {e}"
    if done:
        text += f"; {_frames_were(done)} written"
    if rest:
        text += f"; {_frames_were(rest)} not rendered"
    return WriteError(text, e.path, e.free, e.fallback)


def render_sequence(scene: Scene, output: str | None = None, frames=None, spp: int | None = None, seed: int = 0,
                    device: str | None = None, progress: bool | None = None, aovs=None) -> list:
    """Render frames of an animated scene in this process, reusing one Renderer.

    Returns the images (or, with ``output``, writes each frame atomically as it finishes and
    returns the paths).

    Ctrl-C stops the frame being rendered within a pass; that frame is cut short and is neither
    written nor returned (a partial frame under the normal name would slip into a video), the
    frames after it are not rendered, and :class:`warprt.errors.FramesInterrupted` (a
    ``KeyboardInterrupt``) is raised, listing the complete frames (``.frames``) with their images
    or paths (``.results``); those frames are already written. A frame that cannot be written (a
    full disk, quota or I/O error) is written to the temporary folder instead and the sequence
    stops with a :class:`warprt.errors.WriteError` saying where it went and which frames were
    written.
    """
    from .render import _CtrlC

    frames = check_frames(scene, frames)
    check_seed(seed)
    if output is not None:
        check_pattern(output)
        check_output(frame_path(output, frames[0]), create_folders=True)  # before any rendering
    renderer = None
    done, out = [], []
    cut_short: list[int] = []
    bar = None
    show = sys.stderr.isatty() if progress is None else progress
    if show:
        from tqdm import tqdm

        bar = tqdm(total=len(frames), unit="frame", desc="sequence", file=sys.stderr)
    try:
        # one flag-only SIGINT handler over the whole loop (see render._CtrlC): a Ctrl-C between
        # frames, while a scene is updated or a frame written, only sets the flag; the render
        # reads it after each pass (``stop``) and the loop after each frame
        with _CtrlC() as ctrl_c:
            for f in frames:
                if ctrl_c.pressed:
                    raise KeyboardInterrupt
                fs = frame_scene(scene, f)
                if renderer is None:
                    renderer = Renderer(fs, device=device)
                else:
                    renderer.update(fs)
                result = renderer.render(spp=spp, seed=frame_seed(seed, f), progress=False, aovs=aovs, stop=ctrl_c)
                if result.interrupted:
                    cut_short.append(f)
                    raise KeyboardInterrupt
                image = RenderLayers({"color": result.image, **result.aovs}, result) if aovs else result.image
                try:
                    out.append(keep_frame(output, f, image, result.spp, result=result))
                except WriteError as e:  # a full disk: the sequence stops (the next frames would fail too)
                    raise frame_write_failed(e, f, frames, done) from None
                done.append(f)
                if bar is not None:
                    bar.update(1)
    except KeyboardInterrupt:
        not_started = [f for f in frames if f not in done and f not in cut_short]
        raise FramesInterrupted(done, out, cut_short, total=len(frames), not_started=not_started) from None
    finally:
        if bar is not None:
            bar.close()
    return out
