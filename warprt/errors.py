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
