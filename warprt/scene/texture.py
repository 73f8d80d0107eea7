"""Textures: a colour that varies over a surface, multiplying one of a material's coefficients.

A :class:`Texture` is one of

* a **bitmap**: ``file`` (PNG, JPEG, or any image Pillow reads) or ``image`` (a numpy array
  (H, W), (H, W, 3) or (H, W, 4); alpha is ignored). Integer images (8- and 16-bit files, uint8 or
  uint16 arrays) hold sRGB-encoded values and are decoded to linear RGB once, when the texture is
  made (:func:`warprt.colour.srgb_to_linear`); float arrays are taken as linear. ``srgb`` overrides
  the choice (``srgb = false`` for a data map such as a metallic map). Sampled **bilinearly**
  between the four texel centres around the point (texel (i, j) of a W × H image has its centre at
  u = (i + 0.5)/W, v = 1 − (j + 0.5)/H, row j = 0 the top row of the file);
* a **checker**: ``checker = [c0, c1]`` (two colours): square (i, j) = (⌊u'⌋, ⌊v'⌋) shows c0 where
  i + j is even, c1 where it is odd (u' = u·scale, v' = v·scale).

Where the texture takes its 2-D coordinates (``projection``):

* ``"uv"`` (default): the surface's own (u, v), scaled by ``scale`` (repeats per unit of uv).
  UV conventions follow OBJ and OpenGL (trimesh's ``visual.uv``): (0, 0) is the image's bottom-left
  corner, v runs up the image. Meshes: per-vertex UVs (from the file through trimesh, whose
  loaders flip glTF's top-left origin into this one, or ``Mesh(uv=...)``), interpolated with the
  hit's barycentric weights. Rectangles: p = corner + u·edge1 + v·edge2. Spheres: u the longitude
  from +x towards −z, u = atan2(−d_z, d_x)/2π (mod 1), v = 1/2 + asin(d_y)/π (v = 1 at the +y pole),
  d the unit vector from the centre. Planes, disks, boxes, capsules and cylinders have no UVs: a
  ``"uv"`` texture on them is refused when the scene is made.
* ``"triplanar"``: three planar maps of the point x (the shape's own frame: a mesh's object
  space, a solid's local frame, a sphere's offset from its centre, world space for planes,
  rectangles and disks), blended by the normal n in that frame: the x map reads (x_z, x_y), the y
  map (x_x, x_z), the z map (x_x, x_y), each times ``scale`` (repeats per scene unit), weighted
  w_k = |n_k|^sharpness / Σ_j |n_j|^sharpness.
* ``"cubic"``: the one map of the normal's largest component (the limit of triplanar as the
  sharpness grows; ties go to x, then y).

``wrap``: ``"repeat"`` tiles a bitmap (u mod 1); ``"clamp"`` repeats its edge texels beyond [0, 1].
Checkers are unbounded. The texture's value multiplies the coefficient it is given to: a
material's ``texture`` multiplies ``kd`` and ``ka``, ``specular_texture`` ``ks`` and
``mirror_texture`` ``mirror``.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from typing import Any, Mapping, Sequence

import numpy as np

from ..colour import srgb_to_linear
from ..errors import SceneError
from .values import as_choice, as_float, as_rgb, checked_keywords, set_field

PROJECTIONS = ("uv", "triplanar", "cubic")  # TexRec.proj ids: their order
WRAPS = ("repeat", "clamp")  # TexRec.wrap ids: their order
MAX_TEXELS = 1 << 26  # one texture's texels (64 M: 768 MiB as float32 RGB), a guard against mistakes


@checked_keywords
@dataclass(frozen=True, eq=False)
class Texture:
    """A bitmap (``file`` or ``image``) or a procedural ``checker``; see the module docstring."""

    file: str | None = None  # image file, relative to the scene file in TOML
    image: Any = None  # or an array (H, W[, 3 or 4]): integers sRGB-encoded, floats linear
    checker: Any = None  # or two colours [c0, c1]
    scale: float = 1.0  # repeats per unit of uv ("uv") or per scene unit ("triplanar", "cubic")
    projection: str = "uv"  # "uv", "triplanar" or "cubic"
    wrap: str = "repeat"  # bitmaps beyond [0, 1]: "repeat" or "clamp"
    sharpness: float = 4.0  # triplanar blend exponent
    srgb: bool | None = None  # decode the texels from sRGB (default: integer images yes, floats no)

    def __post_init__(self):
        given = [name for name in ("file", "image", "checker") if getattr(self, name) is not None]
        if len(given) != 1:
            raise SceneError("give one of file, image (a bitmap) or checker (two colours)"
                             + (f", not {' and '.join(given)}" if given else ""), "file")
        set_field(self, "scale", as_float(self.scale, "scale", minimum=0.0, strict_min=True, float32="normal"))
        set_field(self, "projection", as_choice(self.projection, "projection", PROJECTIONS))
        set_field(self, "wrap", as_choice(self.wrap, "wrap", WRAPS))
        set_field(self, "sharpness", as_float(self.sharpness, "sharpness", minimum=0.0, maximum=64.0))
        if self.srgb is not None and not isinstance(self.srgb, (bool, np.bool_)):
            raise SceneError(f"expected true or false, got {self.srgb!r}", "srgb")
        if self.checker is not None:
            c = self.checker
            if isinstance(c, (str, bytes, Mapping)) or not isinstance(c, (Sequence, np.ndarray)) or len(c) != 2:
                raise SceneError(f"expected two colours [c0, c1], got {c!r:.80}", "checker")
            set_field(self, "checker", (as_rgb(c[0], "checker[0]"), as_rgb(c[1], "checker[1]")))
            object.__setattr__(self, "_texels", None)
            return
        if self.file is not None:
            if not isinstance(self.file, (str, os.PathLike)) or not os.fspath(self.file):
                raise SceneError(f"expected the path of an image file, got {self.file!r}", "file")
            set_field(self, "file", os.fspath(self.file))
            texels, integer = _read_image(self.file)
        else:
            texels, integer = _as_image(self.image)
        decode = integer if self.srgb is None else bool(self.srgb)
        if texels.size // 3 > MAX_TEXELS:
            raise SceneError(f"{texels.shape[1]} × {texels.shape[0]} texels exceed {MAX_TEXELS} per texture",
                             "file" if self.file is not None else "image")
        lin = srgb_to_linear(texels) if decode else texels
        lin = np.ascontiguousarray(lin, dtype=np.float32)
        lin.setflags(write=False)
        object.__setattr__(self, "_texels", lin)

    @property
    def kind(self) -> str:
        return "checker" if self.checker is not None else "bitmap"

    @property
    def texels(self) -> np.ndarray | None:
        """A bitmap's linear RGB texels (H, W, 3) float32, row 0 the top of the image (read-only);
        None for a checker."""
        return self._texels

    def __repr__(self) -> str:
        if self.checker is not None:
            what = f"checker={list(map(list, self.checker))}"
        elif self.file is not None:
            what = f"file={self.file!r}"
        else:
            what = f"image=<{self._texels.shape[1]}×{self._texels.shape[0]}>"
        extra = "".join(f", {k}={getattr(self, k)!r}" for k, d in (("scale", 1.0), ("projection", "uv"),
                                                                   ("wrap", "repeat"), ("sharpness", 4.0))
                        if getattr(self, k) != d)
        return f"Texture({what}{extra})"


def _as_image(image: Any) -> tuple[np.ndarray, bool]:
    """An image array as (H, W, 3) float values in [0, 1] for integers (or as given for floats),
    and whether it held integers."""
    try:
        a = np.asarray(image)
    except Exception:
        raise SceneError(f"expected an image array (H, W[, 3 or 4]), got {type(image).__name__}", "image") from None
    if a.dtype == bool or a.dtype.kind not in "uif":
        raise SceneError(f"expected an image of numbers, got dtype {a.dtype}", "image")
    if a.ndim == 2:
        a = a[..., None]
    if a.ndim != 3 or a.shape[2] not in (1, 3, 4) or a.shape[0] < 1 or a.shape[1] < 1:
        raise SceneError(f"expected an image shaped (H, W), (H, W, 3) or (H, W, 4), got {a.shape}", "image")
    a = a[..., :3]
    if a.shape[2] == 1:
        a = np.repeat(a, 3, axis=2)
    if a.dtype.kind in "ui":
        if a.min() < 0:
            raise SceneError("an integer image must not be negative", "image")
        top = 65535.0 if a.dtype.itemsize >= 2 and a.max() > 255 else 255.0
        if a.dtype.itemsize >= 2 and a.max() > 65535:
            raise SceneError(f"integer texels go up to 65535 (16 bits), found {int(a.max())}", "image")
        return a.astype(np.float64) / top, True
    f = a.astype(np.float64)
    if not np.isfinite(f).all() or f.min() < 0.0:
        raise SceneError("a float image must hold finite values >= 0 (linear RGB)", "image")
    return f, False


def _read_image(path: str) -> tuple[np.ndarray, bool]:
    if not os.path.isfile(path):
        where = os.path.abspath(path)
        what = "is a folder, not an image file" if os.path.isdir(path) else "texture file not found"
        raise SceneError(f"{what}: {path!r}" + (f" (looked in {where!r})" if where != path else ""), "file")
    from PIL import Image

    try:
        with Image.open(path) as im:
            im.load()
            if im.mode in ("I;16", "I;16B", "I;16L", "I"):
                a = np.asarray(im, dtype=np.uint16 if im.mode != "I" else np.int64)
            else:
                a = np.asarray(im.convert("RGB"))
    except Exception as e:  # Pillow raises many types for unreadable files
        raise SceneError(f"cannot read texture file {os.path.basename(path)!r}: {e}", "file") from None
    try:
        return _as_image(a)
    except SceneError as e:
        raise SceneError(f"texture file {os.path.basename(path)!r}: {e.problem}", "file") from None


def as_texture(value: Any, name: str) -> Texture | None:
    """A material's texture field: None, a :class:`Texture`, a path (a bitmap file), or a table of
    Texture's fields (``{checker = [...], scale = 8}``)."""
    if value is None or isinstance(value, Texture):
        return value
    try:
        if isinstance(value, (str, os.PathLike)):
            return Texture(file=value)
        if isinstance(value, Mapping):
            return Texture(**value)
    except SceneError as e:
        raise e.within(name) from None
    raise SceneError(f"expected an image file's path, a table of texture fields or a warprt.Texture, got "
                     f"{type(value).__name__}", name)


__all__ = ["PROJECTIONS", "WRAPS", "Texture", "as_texture"]
