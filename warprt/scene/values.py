"""Coercion of user values into validated fields: each helper raises :class:`warprt.SceneError`
naming the field it was given."""

from __future__ import annotations

import difflib
import functools
import math
from dataclasses import fields
from typing import Any, Mapping, Sequence

import numpy as np

from ..errors import SceneError

Vec3 = tuple[float, float, float]
RGB = tuple[float, float, float]

# the kernels compute in float32: a finite Python float beyond FLT_MAX becomes Inf on the device,
# a non-zero one below FLT_MIN_NORMAL loses its precision (and below 1.4e-45 becomes 0)
FLT_MAX = float(np.finfo(np.float32).max)  # 3.4e38
FLT_MIN_NORMAL = float(np.finfo(np.float32).tiny)  # 1.2e-38


def in_float32(x: float, name: str, *, normal: bool = False) -> float:
    """``x`` if float32 holds it: |x| <= 3.4e38 and, with ``normal``, x = 0 or |x| >= 1.2e-38
    (for lengths the math divides by or squares)."""
    if abs(x) > FLT_MAX:
        raise SceneError(f"{x:g} is beyond the float32 range the renderer computes in (|x| <= {FLT_MAX:.3g})", name)
    if normal and x != 0.0 and abs(x) < FLT_MIN_NORMAL:
        raise SceneError(f"{x:g} is below float32's smallest normal number {FLT_MIN_NORMAL:.3g} and would be lost "
                         f"on the device", name)
    return x


def finite(x: float, name: str) -> float:
    if isinstance(x, bool) or not isinstance(x, (int, float, np.integer, np.floating)):
        raise SceneError(f"expected a number, got {x!r}", name)
    x = float(x)
    if not math.isfinite(x):
        raise SceneError(f"must be finite, got {x}", name)
    return x


def as_float(x: Any, name: str, *, minimum: float | None = None, maximum: float | None = None,
             strict_min: bool = False, float32: str | None = None) -> float:
    """``float32``: ``"range"`` refuses |x| > 3.4e38, ``"normal"`` also a non-zero |x| < 1.2e-38."""
    x = finite(x, name)
    if minimum is not None and (x < minimum or (strict_min and x == minimum)):
        raise SceneError(f"must be {'>' if strict_min else '>='} {minimum:g}, got {x:g}", name)
    if maximum is not None and x > maximum:
        raise SceneError(f"must be <= {maximum:g}, got {x:g}", name)
    if float32 is not None:
        in_float32(x, name, normal=float32 == "normal")
    return x


def as_int(x: Any, name: str, *, minimum: int | None = None, maximum: int | None = None) -> int:
    if isinstance(x, bool) or not isinstance(x, (int, np.integer)):
        if isinstance(x, float) and x.is_integer():
            x = int(x)
        else:
            raise SceneError(f"expected an integer, got {x!r}", name)
    x = int(x)
    if minimum is not None and x < minimum:
        raise SceneError(f"must be >= {minimum}, got {x}", name)
    if maximum is not None and x > maximum:
        raise SceneError(f"must be <= {maximum}, got {x}", name)
    return x


def as_vec3(x: Any, name: str) -> Vec3:
    if isinstance(x, (str, bytes)) or not isinstance(x, (Sequence, np.ndarray)) or len(x) != 3:
        raise SceneError(f"expected three numbers [x, y, z], got {x!r}", name)
    return tuple(in_float32(finite(v, f"{name}[{i}]"), f"{name}[{i}]")  # type: ignore[return-value]
                 for i, v in enumerate(x))


def as_direction(x: Any, name: str) -> Vec3:
    v = as_vec3(x, name)
    n = math.sqrt(sum(c * c for c in v))
    if n == 0.0 or not math.isfinite(n):
        raise SceneError("must be a non-zero vector", name)
    return v


def as_rgb(x: Any, name: str, *, maximum: float | None = None) -> RGB:
    """A colour: one number (grey) or three, each finite and >= 0."""
    if isinstance(x, (int, float, np.integer, np.floating)) and not isinstance(x, bool):
        c = as_float(x, name, minimum=0.0, maximum=maximum)
        return (c, c, c)
    if isinstance(x, (str, bytes)) or not isinstance(x, (Sequence, np.ndarray)) or len(x) != 3:
        raise SceneError(f"expected a colour: one number or three [r, g, b], got {x!r}", name)
    return tuple(as_float(v, f"{name}[{i}]", minimum=0.0, maximum=maximum) for i, v in enumerate(x))  # type: ignore


def as_choice(x: Any, name: str, choices: Sequence[str]) -> str:
    if not isinstance(x, str) or x not in choices:
        raise SceneError(f"must be one of {', '.join(repr(c) for c in choices)}, got {x!r}", name)
    return x


def checked_keywords(cls: type) -> type:
    """Class decorator, over ``@dataclass``: an unknown keyword argument (``Sphere(radisu=1)``)
    raises :class:`SceneError` naming the class and the closest field, instead of the generated
    ``__init__``'s bare TypeError. The signature, defaults and ``dataclasses.replace`` are kept.

    ``KEYWORD_ALIASES`` (a class attribute, ``{name: field}``) gives fields a second keyword, the
    name scene files use (``Transform(quaternion=q)`` sets ``rotation_quaternion``); errors about
    the field then name the keyword given."""
    init = cls.__init__
    names = [f.name for f in fields(cls) if f.init]
    aliases = dict(getattr(cls, "KEYWORD_ALIASES", {}))

    @functools.wraps(init)
    def __init__(self, *args: Any, **kwargs: Any) -> None:
        given = {}
        for alias, name in aliases.items():
            if alias in kwargs:
                if name in kwargs:
                    raise SceneError(f"give it once: {alias} and {name} are the same field", alias)
                kwargs[name] = kwargs.pop(alias)
                given[name] = alias
        for key in kwargs:
            if key not in names:
                close = difflib.get_close_matches(key, [*names, *aliases], n=1)
                hint = f"did you mean {close[0]!r}?" if close else f"fields: {', '.join(names)}"
                raise SceneError(f"{cls.__name__} has no field {key!r}; {hint}", key)
        if not given:
            init(self, *args, **kwargs)
            return
        try:
            init(self, *args, **kwargs)
        except SceneError as e:
            if e.field in given:
                raise SceneError(e.problem, given[e.field], e.source) from None
            raise

    cls.__init__ = __init__  # type: ignore[method-assign]
    return cls


def set_field(obj: Any, name: str, value: Any) -> None:
    """Set a field of a frozen dataclass (from its own ``__post_init__``)."""
    object.__setattr__(obj, name, value)


def norm(v: Sequence[float]) -> float:
    return math.sqrt(sum(c * c for c in v))


def as_keyframes(x: Any, name: str, allowed: Sequence[str]) -> tuple:
    """Keyframes: a list of tables, each with ``time`` (seconds, strictly increasing) and some of
    ``allowed`` (vectors; ``scale`` may be one number; ``quaternion`` is four numbers (x, y, z, w)
    and excludes ``rotate`` in the same key; ``rotation_quaternion`` is another name for it).
    Values missing from a key are taken from the object's own fields."""
    if x is None or (isinstance(x, (list, tuple)) and len(x) == 0):
        return ()
    if not isinstance(x, (list, tuple)):
        raise SceneError(f"expected a list of tables with time and {', '.join(allowed)}, got {x!r}", name)
    out, last = [], -math.inf
    for i, key in enumerate(x):
        where = f"{name}[{i}]"
        if not isinstance(key, Mapping):
            raise SceneError(f"expected a table, got {key!r}", where)
        if "quaternion" in allowed and "rotation_quaternion" in key:  # (Python's older name for it)
            if "quaternion" in key:
                raise SceneError("give it once: quaternion and rotation_quaternion are the same field",
                                 f"{where}.rotation_quaternion")
            key = {("quaternion" if k == "rotation_quaternion" else k): v for k, v in key.items()}
        unknown = sorted(set(key) - {"time", *allowed})
        if unknown:
            raise SceneError(f"unknown field(s) {', '.join(unknown)}; expected time and some of: {', '.join(allowed)}",
                             where)
        if "time" not in key:
            raise SceneError("every keyframe needs a time", f"{where}.time")
        t = as_float(key["time"], f"{where}.time")
        if t <= last:
            raise SceneError(f"keyframe times must increase, got {t:g} after {last:g}", f"{where}.time")
        last = t
        k = {"time": t}
        for f in allowed:
            if f in key:
                v = key[f]
                if f == "scale" and isinstance(v, (int, float)) and not isinstance(v, bool):
                    v = (v, v, v)
                if f == "quaternion":
                    if "rotate" in key:
                        raise SceneError("give the rotation once: rotate (Euler angles) or quaternion, not both",
                                         f"{where}.quaternion")
                    k[f] = as_quaternion(v, f"{where}.{f}")
                    continue
                k[f] = as_vec3(v, f"{where}.{f}")
        out.append(k)
    return tuple(out)


def as_quaternion(x: Any, name: str) -> tuple[float, float, float, float]:
    """A rotation quaternion (x, y, z, w): four finite numbers, not all zero; returned normalised
    with w >= 0 (q and -q are the same rotation)."""
    if isinstance(x, (str, bytes)) or not isinstance(x, (Sequence, np.ndarray)) or len(x) != 4:
        raise SceneError(f"expected four numbers [x, y, z, w], got {x!r}", name)
    q = np.array([finite(v, f"{name}[{i}]") for i, v in enumerate(x)], dtype=np.float64)
    n = float(np.linalg.norm(q))
    if not math.isfinite(n):
        raise SceneError(f"is too large to normalise, got {list(q)}", name)
    if n < 1e-12:
        raise SceneError(f"must not be zero (it is normalised to a unit quaternion), got {list(q)}", name)
    q = q / n
    if q[3] < 0.0:
        q = -q
    return tuple(float(c) + 0.0 for c in q)  # type: ignore[return-value]  (+0.0: no -0.0)
