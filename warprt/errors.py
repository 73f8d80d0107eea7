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


class FramesInterrupted(KeyboardInterrupt):
    """Ctrl-C stopped a sequence of frames (:func:`warprt.animation.render_sequence`,
    :func:`warprt.batch.render_frames`). Every frame that had finished is kept (written, with an
    ``output``, as it finished); a frame cut short is neither written nor returned.

    ``frames``: the complete frame numbers, in the order asked for; ``results``: their images (or
    paths, with ``output``), aligned with ``frames``; ``cut_short``: the frames stopped part way.
    A subclass of ``KeyboardInterrupt``, so code that does not look for it still stops on Ctrl-C.
    """

    def __init__(self, frames, results, cut_short=(), total: int | None = None):
        self.frames = list(frames)
        self.results = list(results)
        self.cut_short = sorted(cut_short)
        self.total = total
        super().__init__(self.summary())

    def summary(self) -> str:
        of = f" of {self.total}" if self.total is not None else ""
        done = ", ".join(map(str, self.frames)) if self.frames else "none"
        text = f"interrupted: {len(self.frames)}{of} frames complete ({done})"
        if self.cut_short:
            text += f"; cut short and not written: {', '.join(map(str, self.cut_short))}"
        return text
