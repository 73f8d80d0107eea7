"""Errors raised for bad scenes and bad arguments.

Every message names where the problem is (file and field, or argument) and what it is, so a user
can fix the input without reading a traceback from inside Warp.
"""

from __future__ import annotations


class SceneError(ValueError):
    """A scene description (file or Python objects) is invalid.

    ``field`` is the dotted path of the offending field (``shapes[2].radius``), ``source`` the
    scene file, when there is one.
    """

    def __init__(self, message: str, field: str | None = None, source: str | None = None):
        self.problem = message
        self.field = field
        self.source = source
        super().__init__(self._format())

    def _format(self) -> str:
        where = ": ".join(part for part in (self.source, self.field) if part)
        return f"{where}: {self.problem}" if where else self.problem

    def within(self, prefix: str | None = None, source: str | None = None) -> "SceneError":
        """Return the same error located under ``prefix`` (a parent field) and/or in ``source``."""
        field = self.field
        if prefix:
            field = prefix if not field else (f"{prefix}{field}" if field.startswith("[") else f"{prefix}.{field}")
        return SceneError(self.problem, field, source or self.source)


class RenderError(RuntimeError):
    """Rendering could not be carried out (bad argument, unavailable device, failed output)."""


class WriteError(RenderError):
    """An image could not be written although its folder was writable when checked: a full disk,
    a quota, an I/O error. ``path``: the output; ``free``: bytes free on its disk when it failed
    (None where unknown); ``fallback``: where the image was written instead (None if nowhere)."""

    def __init__(self, message: str, path: str, free: int | None = None, fallback: str | None = None):
        self.path = path
        self.free = free
        self.fallback = fallback
        super().__init__(message)


class FramesInterrupted(KeyboardInterrupt):
    """Ctrl-C stopped a sequence of frames (:func:`warprt.animation.render_sequence`,
    :func:`warprt.batch.render_frames`). Every frame that had finished is kept (written, with an
    ``output``, as it finished); a frame cut short is neither written nor returned.

    ``frames``: the complete frame numbers, in the order asked for; ``results``: their images (or
    paths, with ``output``), aligned with ``frames``; ``cut_short``: the frames stopped part way;
    ``not_started``: the frames asked for that never began (in order; empty where unknown).
    A subclass of ``KeyboardInterrupt``, so code that does not look for it still stops on Ctrl-C.
    """

    def __init__(self, frames, results, cut_short=(), total: int | None = None, not_started=()):
        self.frames = list(frames)
        self.results = list(results)
        self.cut_short = sorted(cut_short)
        self.not_started = list(not_started)
        self.total = total
        super().__init__(self.summary())

    def summary(self) -> str:
        """One line: the complete frames (with the files written, where they were), then every
        frame not written and why: "interrupted: 2 of 8 frames complete (0-1: out/f_0000.png ...
        out/f_0001.png); not written: 2 (cut short), 3-7 (not started)"."""
        of = f" of {self.total}" if self.total is not None else ""
        done = frame_list(self.frames) if self.frames else "none"
        paths = [r for r in self.results if isinstance(r, str)]
        if paths and len(paths) == len(self.frames):
            done += f": {paths[0]}" if len(paths) == 1 else f": {paths[0]} ... {paths[-1]}"
        text = f"interrupted: {len(self.frames)}{of} frames complete ({done})"
        missing = []
        if self.cut_short:
            missing.append(f"{frame_list(self.cut_short)} (cut short)")
        if self.not_started:
            missing.append(f"{frame_list(self.not_started)} (not started)")
        if missing:
            text += f"; not written: {', '.join(missing)}"
        return text


def frame_list(frames) -> str:
    """Frame numbers for a message, runs of consecutive numbers as ranges: "0-3, 7, 9-12"."""
    frames = [int(f) for f in frames]
    parts, i = [], 0
    while i < len(frames):
        j = i
        while j + 1 < len(frames) and frames[j + 1] == frames[j] + 1:
            j += 1
        parts.append(str(frames[i]) if j == i else f"{frames[i]}-{frames[j]}")
        i = j + 1
    return ", ".join(parts)
