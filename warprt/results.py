"""What every render hands back, in one shape: ``.image``, ``.aovs``, ``.spp`` and ``.metadata``.

:class:`warprt.RenderResult` (``Renderer.render``), :class:`warprt.BatchResult` (batches and the
Newton bridge; ``.frame(world, camera)`` gives one image as a :class:`FrameResult`), the
:class:`RenderLayers` dict that ``warprt.render(..., aovs=[...])`` returns and
:class:`FrameResult` all carry these four, and :func:`warprt.save_image` takes any of them (or a
bare array) and writes the metadata it has. In a notebook each shows itself as its image
(``_repr_png_``: the sRGB view of :mod:`warprt.colour`).

The metadata (header attributes of an EXR, text chunks of a PNG, the comment of a JPEG):

* ``worldToCamera`` and ``worldToNDC``: OpenEXR's standard attributes (4×4 float32,
  ImfStandardAttributes.h), in Imath's convention, which multiplies a **row** vector on the left:
  ``[x, y, z, 1] @ M``, so the translation is the last row. Camera space is OpenEXR's (and
  RenderMan's): x right, y up, z along the view (objects in front have z > 0). NDC is (0, 0) at
  the top-left corner of the image and (1, 1) at the bottom-right one (pixel (i, j)'s centre is
  ((i + 0.5) / W, (j + 0.5) / H)) after the division by the fourth coordinate; the third
  becomes 1/z (the matrix stays invertible; OpenEXR says to discard it). The camera at shutter
  open.
* ``warprt_background``: the scene's background radiance (RGB); :func:`warprt.save_image` takes
  it out of the colour of a render with coverage (premultiplied RGBA), and
  :func:`warprt.read_exr` puts it back.
* ``warprt_object_id_names``, ``warprt_material_names`` (with those AOVs): JSON objects from the
  value an id channel stores (id + 1; "0" is nothing) to a name: ``shapes[3] mesh bunny.obj``,
  ``lights[0] rectangle light``, a material's name.
* ``warprt_spp``, ``warprt_seed`` and the rest of :meth:`RenderResult.reproduction`, and
  ``warprt:partial`` = ``true`` for an interrupted render.
"""

from __future__ import annotations

import io
import json
import os
from dataclasses import dataclass, field

import numpy as np


def camera_matrices(eye, u, v, w, top: float, right: float, dist: float, x_off: float | None = None,
                    y_off: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(worldToCamera, worldToNDC) of a camera at ``eye`` with axes u (right), v (up), w (back)
    and an image plane at distance ``dist`` of half height ``top`` and half width ``right``,
    spanning u in [-x_off, 2 right - x_off] and v in [y_off - 2 top, y_off] (centred when not
    given; a principal point off centre): 4×4 float32 in OpenEXR's layout (see the module
    docstring). A camera model other than the pinhole gets the matrix of the pinhole with its
    fx, fy, cx, cy (a distortion, a fisheye or an orthographic view is not a 4×4 projection)."""
    eye, u, v, w = (np.asarray(x, np.float64) for x in (eye, u, v, w))
    to_camera = np.eye(4)  # for column vectors; stored transposed
    to_camera[0, :3], to_camera[1, :3], to_camera[2, :3] = u, v, -w
    to_camera[:3, 3] = 0.0 - to_camera[:3, :3] @ eye  # (0.0 - x: no -0.0 in the header)
    sx, sy = dist / (2.0 * right), dist / (2.0 * top)
    ox = 0.5 if x_off is None else x_off / (2.0 * right)
    oy = 0.5 if y_off is None else y_off / (2.0 * top)
    to_ndc = np.array([[sx, 0.0, ox, 0.0],  # x/z scaled, shifted to [0, 1]
                       [0.0, -sy, oy, 0.0],  # y down
                       [0.0, 0.0, 0.0, 1.0],  # third: 1/z after the division
                       [0.0, 0.0, 1.0, 0.0]])  # the division by z
    return to_camera.T.astype(np.float32), (to_ndc @ to_camera).T.astype(np.float32)


def _unit(x) -> np.ndarray:
    x = np.asarray(x, np.float64)
    return x / np.linalg.norm(x)


def camera_record_matrices(rec) -> tuple[np.ndarray, np.ndarray]:
    """The matrices of a device camera record (``records.CameraData``, as a struct or a numpy
    structured row) at its shutter-open time, with the device's own frame (``camera.camera_frame``)."""
    get = (lambda k: np.asarray(rec[k], np.float64)) if isinstance(rec, np.void) else \
        (lambda k: np.asarray(getattr(rec, k), np.float64))
    t = float(get("t_open"))
    eye = get("eye0") + (get("eye1") - get("eye0")) * t
    look = get("look0") + (get("look1") - get("look0")) * t
    w = _unit(eye - look)
    u = _unit(np.cross(get("up"), w))
    v = np.cross(w, u)
    return camera_matrices(eye, u, v, w, float(get("top")), float(get("right")), float(get("dist")),
                           float(get("x_off")), float(get("y_off")))


def scene_camera_matrices(camera) -> tuple[np.ndarray, np.ndarray]:
    """The matrices of a :class:`warprt.Camera` at its shutter-open time."""
    import math

    t = camera.shutter[0]
    eye, _ = camera.pose(t)
    u, v, w = camera.basis(t)
    if camera.fx is None:
        top = camera.distance * math.tan(math.radians(camera.fov) / 2.0)
        return camera_matrices(eye, u, v, w, top, top * camera.aspect, camera.distance)
    fx, fy, cx, cy = camera.intrinsics()
    d = camera.distance
    return camera_matrices(eye, u, v, w, d * camera.height / (2.0 * fy), d * camera.width / (2.0 * fx), d,
                           d * (cx + 0.5) / fx, d * (cy + 0.5) / fy)


def _shape_name(i: int, shape) -> str:
    from .scene.description import SHAPE_TYPES

    kind = {cls: name for name, cls in SHAPE_TYPES.items()}.get(type(shape), type(shape).__name__)
    file = getattr(shape, "file", None)
    return f"shapes[{i}] {kind}" + (f" {os.path.basename(file)}" if file else "")


def id_names(scene, which: str) -> dict:
    """The name table of an id AOV (``object_id`` or ``material``): stored value (id + 1, as a
    string) to name, "0" for nothing."""
    from .scene.description import LIGHT_TYPES, is_area_light

    table = {"0": "(nothing)"}
    if which == "material":
        for k, name in enumerate(scene.materials):
            table[str(k + 1)] = name
        return table
    for i, shape in enumerate(scene.shapes):
        table[str(i + 1)] = _shape_name(i, shape)
    kinds = {cls: name for name, cls in LIGHT_TYPES.items()}
    n = len(scene.shapes)
    for j, light in enumerate(scene.lights):
        if is_area_light(light):
            table[str(n + j + 1)] = f"lights[{j}] {kinds.get(type(light), type(light).__name__)} light"
    return table


ID_TABLES = {"object_id": "warprt_object_id_names", "material": "warprt_material_names"}


def scene_metadata(scene, aov_names) -> dict:
    """The background and, for the id AOVs among ``aov_names``, their name tables."""
    meta = {"warprt_background": np.asarray(scene.background, np.float32)}
    for name, key in ID_TABLES.items():
        if name in aov_names:
            meta[key] = json.dumps(id_names(scene, name), separators=(",", ":"))
    return meta


def png_bytes(image, exposure: float = 0.0) -> bytes:
    """The 8-bit sRGB PNG of a linear image (H, W, 3), as a notebook shows it."""
    from PIL import Image

    from .colour import quantize, view

    rgb = np.asarray(image.numpy() if hasattr(image, "numpy") else image, np.float32)[..., :3]
    buf = io.BytesIO()
    Image.fromarray(quantize(view(rgb, exposure), 8), mode="RGB").save(buf, format="PNG")
    return buf.getvalue()


class Displayed:
    """``_repr_png_``: Jupyter and IPython show the object as its image (sRGB, exposure 0)."""

    def _repr_png_(self) -> bytes:
        return png_bytes(self.image)


@dataclass
class FrameResult(Displayed):
    """One image with its AOVs, samples per pixel and metadata: a frame of a batch
    (:meth:`warprt.BatchResult.frame`), as numpy copies."""

    image: np.ndarray  # (H, W, 3) float32 linear radiance
    aovs: dict  # name: (H, W[, channels]) numpy array
    spp: int
    metadata: dict = field(default_factory=dict)


class RenderLayers(dict):
    """What ``warprt.render(scene, aovs=[...])`` returns: a dict ``{"color": image, "depth": ...}``
    (as it always was) that also has the result's ``.image``, ``.aovs``, ``.spp`` and
    ``.metadata``, so ``save_image`` writes the camera, the background and the id names with it."""

    def __init__(self, layers: dict, result=None):
        super().__init__(layers)
        self._result = result

    @property
    def image(self):
        return self["color"]

    @property
    def aovs(self) -> dict:
        return {k: v for k, v in self.items() if k != "color"}

    @property
    def spp(self) -> int | None:
        return None if self._result is None else self._result.spp

    @property
    def metadata(self) -> dict:
        return {} if self._result is None else self._result.metadata

    def _repr_png_(self) -> bytes:
        return png_bytes(self["color"])

    def __reduce__(self):  # (pickled as what it is: a dict with its result)
        return (RenderLayers, (dict(self), self._result))


__all__ = ["FrameResult", "RenderLayers", "camera_matrices", "id_names", "png_bytes"]
