"""Scene description: frozen dataclasses with defaults and validation.

Conventions (the whole renderer follows them):

* right-handed world, y up; the camera looks along -w, where w = normalize(eye - look_at);
* angles are degrees in scene descriptions, radians inside the code;
* colours and radiance are linear RGB; a colour field accepts one number (grey) or three;
* time runs over the camera shutter [open, close]; a moving object gives its pose at time 0
  (``center``/``transform``) and at time 1 (``center_end``/``transform_end``), and is linearly
  interpolated (rotations by slerp) in between and beyond.

The TOML loader (:mod:`warprt.scene.loader`) and the Python API build the same objects. Every
class validates itself in ``__post_init__`` and raises :class:`warprt.SceneError` naming the
field; the loader adds the file name and the position in the file.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field, replace
from typing import Any, Mapping, Sequence

import numpy as np

from ..errors import SceneError
from .meshfile import read_mesh_file, validate_uv
from .texture import Texture, as_texture
from .transform import Transform, as_transform, quaternion_product, quaternion_y_to, same_hemisphere
from .values import (
    FLT_MIN_NORMAL, RGB, Vec3, as_choice, as_direction, as_float, as_int, as_keyframes, as_rgb, as_vec3, checked_keywords, norm,
    set_field,
)

SAMPLERS = ("regular", "independent", "stratified", "sobol")  # RenderSettings.sampler (ids: their order)
LIGHT_SAMPLING = ("uniform", "cosine")  # RenderSettings.light_sampling (ids: their order)
FALLOFFS = ("none", "inverse_square")
FRESNEL_MODES = ("none", "schlick", "exact")
CAMERA_MODELS = ("pinhole", "opencv", "fisheye", "orthographic")  # Camera.model (ids: their order)
MAX_DEPTH_LIMIT = 64
# most samples per pixel one render may ask for (scene files, --spp, Renderer.render); to render
# "as long as it takes", ask for SPP_LIMIT with a time_budget or a target_error instead
SPP_LIMIT = 1 << 20
SPP_LIMIT_HINT = "for 'as long as it takes' give a time_budget or target_error instead"
# largest render.clamp: the kernel works in float32 (max 3.4e38) and sums up to 2^20 clamped samples
# per pixel, so a larger clamp (1e300 is finite in Python, inf on the device) let Inf pixels through
CLAMP_LIMIT = 1e30


@checked_keywords
@dataclass(frozen=True)
class Animation:
    """Frames of an animated scene: frame f shows time f / fps (seconds); keyframed objects take
    their pose at that time, and at time (f + 1) / fps as their motion-blur end pose."""

    frames: int = 1
    fps: float = 24.0

    def __post_init__(self):
        set_field(self, "frames", as_int(self.frames, "frames", minimum=1, maximum=1 << 20))
        set_field(self, "fps", as_float(self.fps, "fps", minimum=0.0, strict_min=True))


# --- camera --------------------------------------------------------------------------------


@checked_keywords
@dataclass(frozen=True)
class Camera:
    """The camera: a pinhole or thin lens, an OpenCV-calibrated camera with lens distortion, an
    OpenCV fisheye (Kannala-Brandt) or an orthographic view (``model``).

    The image plane sits at distance ``distance`` (the lecture's D) along -w; its half height is
    D·tan(fov/2) and its half width that times width/height. Pixel (i, j), with j counted from the
    top row, has its centre at raster position (i + 0.5, j + 0.5).

    Intrinsics ``fx``, ``fy``, ``cx``, ``cy`` are in pixels with OpenCV's meaning: the centre of
    pixel (i, j) is at (i, j) in OpenCV's pixel coordinates (raster position (i + 0.5, j + 0.5)
    here), so a calibration's camera matrix is pasted as it is. ``distortion`` is OpenCV's
    ``distCoeffs`` in its order: (k1, k2, p1, p2[, k3[, k4, k5, k6[, s1, s2, s3, s4]]]) for the
    ``opencv`` model, (k1, k2, k3, k4) for ``fisheye``. ``rolling_shutter`` is the line delay:
    row j is exposed over [open + j·delay, close + j·delay] (time units per row).
    """

    eye: Vec3 = (0.0, 0.0, 5.0)
    look_at: Vec3 = (0.0, 0.0, 0.0)
    up: Vec3 = (0.0, 1.0, 0.0)
    fov: float | None = None  # vertical field of view, degrees (45 unless fx is given)
    width: int = 320  # pixels
    height: int = 240  # pixels
    distance: float = 1.0  # D: eye to image plane, scene units (does not change a pinhole image)
    aperture: float = 0.0  # thin-lens radius, scene units; 0 is a pinhole
    focus_distance: float | None = None  # distance of the plane in focus; default |look_at - eye|
    shutter: tuple[float, float] = (0.0, 1.0)  # open and close times
    eye_end: Vec3 | None = None  # eye at time 1 (camera motion)
    look_at_end: Vec3 | None = None  # look_at at time 1
    keyframes: tuple = ()  # animation: [{time, eye, look_at}, ...]
    model: str = "pinhole"  # "pinhole", "opencv", "fisheye" or "orthographic" (CAMERA_MODELS)
    fx: float | None = None  # focal length in pixels (orthographic: pixels per scene unit); else from fov
    fy: float | None = None  # default fx
    cx: float | None = None  # principal point, OpenCV pixels (pixel centres at integers); default (width - 1) / 2
    cy: float | None = None  # default (height - 1) / 2
    distortion: tuple = ()  # OpenCV distCoeffs (see above); () is none
    rolling_shutter: float = 0.0  # line delay: time units per row (0: a global shutter)

    def __post_init__(self):
        set_field(self, "eye", as_vec3(self.eye, "eye"))
        set_field(self, "look_at", as_vec3(self.look_at, "look_at"))
        set_field(self, "up", as_direction(self.up, "up"))
        set_field(self, "model", as_choice(self.model, "model", CAMERA_MODELS))
        set_field(self, "width", as_int(self.width, "width", minimum=1, maximum=1 << 15))
        set_field(self, "height", as_int(self.height, "height", minimum=1, maximum=1 << 15))
        self._check_intrinsics()
        set_field(self, "distance",
                  as_float(self.distance, "distance", minimum=0.0, strict_min=True, float32="normal"))
        set_field(self, "aperture", as_float(self.aperture, "aperture", minimum=0.0, float32="range"))
        if self.focus_distance is not None:
            set_field(self, "focus_distance",
                 as_float(self.focus_distance, "focus_distance", minimum=0.0, strict_min=True, float32="normal"))
        sh = self.shutter
        if isinstance(sh, (str, bytes)) or not isinstance(sh, (Sequence, np.ndarray)) or len(sh) != 2:
            raise SceneError(f"expected [open, close], got {sh!r}", "shutter")
        sh = (as_float(sh[0], "shutter[0]"), as_float(sh[1], "shutter[1]"))
        if sh[1] < sh[0]:
            raise SceneError(f"close time {sh[1]:g} is before open time {sh[0]:g}", "shutter")
        set_field(self, "shutter", sh)
        if self.eye_end is not None:
            set_field(self, "eye_end", as_vec3(self.eye_end, "eye_end"))
        if self.look_at_end is not None:
            set_field(self, "look_at_end", as_vec3(self.look_at_end, "look_at_end"))
        set_field(self, "keyframes", as_keyframes(self.keyframes, "keyframes", ("eye", "look_at")))
        set_field(self, "rolling_shutter", as_float(self.rolling_shutter, "rolling_shutter", minimum=0.0))
        if self.rolling_shutter > 0.0:
            # poses are given at times 0 and 1 (and the scene's bounds cover that span): every
            # row's exposure must lie within it
            last = self.shutter[1] + (self.height - 1) * self.rolling_shutter
            if self.shutter[0] < 0.0 or last > 1.0:
                raise SceneError(f"the last row's exposure ends at {self.shutter[1]:g} + {self.height - 1} × "
                                 f"{self.rolling_shutter:g} = {last:g}, after time 1 (poses are given at times 0 and "
                                 "1): shorten the shutter or the line delay", "rolling_shutter")
        if self.aperture > 0.0 and self.model in ("fisheye", "orthographic"):
            raise SceneError(f"a thin lens (aperture > 0) is for the pinhole and opencv models, not {self.model!r}",
                             "aperture")
        for t in (0.0, 1.0):
            self.basis(t)  # raises when the view is degenerate
        self._check_float32()

    def _check_intrinsics(self) -> None:
        """fov or the intrinsics (fx, fy, cx, cy), and the distortion's coefficients for the model."""
        model = self.model
        if self.fx is None:
            for name in ("fy", "cx", "cy"):
                if getattr(self, name) is not None:
                    raise SceneError(f"{name} is given without fx (give fx, and fy, cx, cy as needed)", name)
            if model in ("fisheye", "orthographic"):
                what = "pixels per scene unit" if model == "orthographic" else "pixels per radian"
                raise SceneError(f"the {model} model needs fx ({what}); fov is for the pinhole and opencv models", "fx")
            fov = 45.0 if self.fov is None else self.fov
            set_field(self, "fov", as_float(fov, "fov", minimum=0.0, strict_min=True))
            if self.fov >= 180.0:
                raise SceneError(f"must be < 180 degrees, got {self.fov:g}", "fov")
        else:
            if self.fov is not None:
                raise SceneError("give fov or the intrinsics fx (fy, cx, cy), not both (fov=None to use fx)", "fov")
            # (fy, cx, cy left out stay None: fx, and the centre of the image at its present size)
            set_field(self, "fx", as_float(self.fx, "fx", minimum=0.0, strict_min=True, float32="normal"))
            if self.fy is not None:
                set_field(self, "fy", as_float(self.fy, "fy", minimum=0.0, strict_min=True, float32="normal"))
            for name in ("cx", "cy"):
                if getattr(self, name) is not None:
                    set_field(self, name, as_float(getattr(self, name), name, float32="range"))
        d = self.distortion
        if isinstance(d, (str, bytes)) or not isinstance(d, (Sequence, np.ndarray)) or np.ndim(d) > 1 and \
                not (np.ndim(d) == 2 and 1 in np.shape(d)):
            raise SceneError(f"expected a list of coefficients (OpenCV's distCoeffs), got {d!r:.80}", "distortion")
        d = tuple(as_float(v, f"distortion[{i}]", float32="range") for i, v in enumerate(np.ravel(np.asarray(d, dtype=object))))
        if model == "opencv":
            if len(d) == 14:
                raise SceneError("14 coefficients: the tilted-sensor terms (tauX, tauY) are not supported; give 4, 5, "
                                 "8 or 12 (k1, k2, p1, p2[, k3[, k4, k5, k6[, s1, s2, s3, s4]]])", "distortion")
            if len(d) not in (0, 4, 5, 8, 12):
                raise SceneError(f"the opencv model takes 4, 5, 8 or 12 coefficients in OpenCV's order (k1, k2, p1, p2"
                                 f"[, k3[, k4, k5, k6[, s1, s2, s3, s4]]]), got {len(d)}", "distortion")
        elif model == "fisheye":
            if len(d) not in (0, 4):
                raise SceneError(f"the fisheye model takes 4 coefficients (k1, k2, k3, k4), got {len(d)}", "distortion")
        elif d:
            raise SceneError(f"the {model} model has no distortion (use model = \"opencv\" or \"fisheye\"), got "
                             f"{len(d)} coefficients", "distortion")
        set_field(self, "distortion", d)

    @classmethod
    def from_aperture(cls, focal_length: float, horizontal_aperture: float, vertical_aperture: float,
                      horizontal_aperture_offset: float = 0.0, vertical_aperture_offset: float = 0.0,
                      **fields) -> "Camera":
        """A pinhole from USD's (and Newton's ``SensorCamera.compute_camera_rays_pinhole``) film
        description: focal length and the film's apertures and offsets, in any one unit (only
        their ratios count; offsets move the film window right and up). ``fields`` are the
        camera's others (``width`` and ``height`` among them); the result has fx = focal ·
        width / horizontal aperture, fy = focal · height / vertical aperture and the principal
        point moved by the offsets from the image centre."""
        names = ("focal_length", "horizontal_aperture", "vertical_aperture")
        for name, value in zip(names, (focal_length, horizontal_aperture, vertical_aperture)):
            as_float(value, name, minimum=0.0, strict_min=True)
        h_off = as_float(horizontal_aperture_offset, "horizontal_aperture_offset")
        v_off = as_float(vertical_aperture_offset, "vertical_aperture_offset")
        width = as_int(fields.get("width", 320), "width", minimum=1)
        height = as_int(fields.get("height", 240), "height", minimum=1)
        fx = focal_length * width / horizontal_aperture
        fy = focal_length * height / vertical_aperture
        return cls(fx=fx, fy=fy, cx=(width - 1) / 2.0 - h_off * fx / focal_length,
                   cy=(height - 1) / 2.0 + v_off * fy / focal_length, **fields)

    def intrinsics(self) -> tuple[float, float, float, float]:
        """(fx, fy, cx, cy) in pixels, OpenCV's convention (pixel centres at integers); from the
        field of view where fx is not given (fx = fy = height / (2 tan(fov / 2)), centred)."""
        cx = (self.width - 1) / 2.0 if self.cx is None else self.cx
        cy = (self.height - 1) / 2.0 if self.cy is None else self.cy
        if self.fx is not None:
            return self.fx, self.fx if self.fy is None else self.fy, cx, cy
        f = self.height / (2.0 * math.tan(math.radians(self.fov) / 2.0))
        return f, f, cx, cy

    def camera_matrix(self) -> np.ndarray:
        """OpenCV's 3×3 camera matrix K of :meth:`intrinsics`."""
        fx, fy, cx, cy = self.intrinsics()
        return np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])

    def dist_coeffs(self) -> np.ndarray:
        """The distortion as OpenCV takes it: 12 coefficients for ``opencv`` (zeros padded), 4 for
        ``fisheye``, none otherwise."""
        n = {"opencv": 12, "fisheye": 4}.get(self.model, 0)
        return np.array(list(self.distortion) + [0.0] * (n - len(self.distortion)), np.float64)

    @property
    def aspect(self) -> float:
        return self.width / self.height

    @property
    def moves(self) -> bool:
        return (self.eye_end is not None and self.eye_end != self.eye) or (
            self.look_at_end is not None and self.look_at_end != self.look_at)

    @property
    def focus(self) -> float:
        if self.focus_distance is not None:
            return self.focus_distance
        return norm(np.subtract(self.look_at, self.eye))

    def pose(self, time: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
        eye0, look0 = np.array(self.eye), np.array(self.look_at)
        eye1 = np.array(self.eye_end) if self.eye_end is not None else eye0
        look1 = np.array(self.look_at_end) if self.look_at_end is not None else look0
        return eye0 + (eye1 - eye0) * time, look0 + (look1 - look0) * time

    def _check_float32(self) -> None:
        """The device computes the camera frame in float32 (``camera.camera_frame``): w from
        eye - look_at, the image plane's half height from distance · tan(fov / 2). Refuse a camera
        whose float64 frame is fine but whose float32 one collapses: eye and look_at closer than
        float32 can tell apart at their magnitude (1e-30 apart at the origin, 1e-3 apart at 1e8),
        or a half height below float32's normal range; such a camera renders black."""
        f32 = np.float32
        for t, (eye, look) in ((0.0, (self.eye, self.look_at)), (1.0, self.pose(1.0))):
            d = np.asarray(eye, f32) - np.asarray(look, f32)
            with np.errstate(under="ignore", over="ignore"):
                d2 = np.sum(d * d, dtype=f32)
            if not d2 >= FLT_MIN_NORMAL:  # (an overflow: the scene's extent warning, build.py)
                gap = norm(np.subtract(eye, look))
                field = "look_at" if t == 0.0 else ("look_at_end" if self.look_at_end is not None else "eye_end")
                why = "are the same point" if not d.any() else "differ by a vector whose squared length underflows"
                raise SceneError(f"eye and look_at are {gap:.3g} apart, but in float32, which the renderer computes "
                                 f"in, they {why}: the camera has no viewing direction; move look_at further (any "
                                 "point along the view gives the same image) or scale the scene", field)
        if self.fx is not None:
            return  # (fx is a normal float32 and the image at most 2^15 pixels: the plane's size is fine)
        with np.errstate(under="ignore"):
            top = f32(self.distance) * f32(math.tan(math.radians(self.fov) / 2.0))
        if not top >= FLT_MIN_NORMAL:
            raise SceneError(f"{self.fov:g} degrees at distance {self.distance:g} gives an image plane "
                             f"{2 * self.distance * math.tan(math.radians(self.fov) / 2):.3g} high, below float32's "
                             "normal range (every pixel would see the same ray)", "fov")

    def basis(self, time: float = 0.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The lecture's camera frame: w = normalize(eye - look_at), u = normalize(up x w), v = w x u."""
        eye, look = self.pose(time)
        w = eye - look
        if np.linalg.norm(w) == 0.0:
            raise SceneError("eye and look_at coincide", "look_at")
        w = w / np.linalg.norm(w)
        up = np.asarray(self.up, dtype=float)
        u = np.cross(up, w)
        # relative to |up| (w is a unit vector): |up x w| = |up| sin(angle), so a tiny but valid up
        # such as (0, 1e-10, 0) is accepted and only the angle decides
        if np.linalg.norm(u) < 1e-9 * np.linalg.norm(up):
            raise SceneError("up is parallel to the viewing direction", "up")
        u = u / np.linalg.norm(u)
        return u, np.cross(w, u), w


# --- materials -----------------------------------------------------------------------------


@checked_keywords
@dataclass(frozen=True)
class Material:
    """Whitted/Phong material with the distribution extensions.

    Local shading is L = ka·Ia + Σ_lights kd·I·max(0, n·l) + ks·I·max(0, n·h)^p. ``mirror`` (km)
    weights the reflected ray and ``transparency`` (kt) the refracted one; with ``fresnel`` on,
    the transmitted share kt is split into reflection F·kt and refraction (1-F)·kt.

    Textures (:class:`warprt.Texture`: a bitmap or a checker; a path stands for a bitmap file)
    multiply a coefficient by their value at the hit: ``texture`` multiplies kd and ka (the
    diffuse colour map), ``specular_texture`` ks and ``mirror_texture`` mirror.
    """

    kd: RGB = (0.8, 0.8, 0.8)  # diffuse reflectance
    ka: RGB | None = None  # ambient reflectance; defaults to kd
    ks: RGB = (0.0, 0.0, 0.0)  # Blinn-Phong specular coefficient
    p: float = 32.0  # Blinn-Phong exponent
    mirror: RGB = (0.0, 0.0, 0.0)  # km, mirror reflectance
    transparency: RGB = (0.0, 0.0, 0.0)  # kt, refracted share
    ior: float = 1.5  # index of refraction of the inside
    fresnel: str = "none"  # "none", "schlick" or "exact" dielectric Fresnel for transparent surfaces
    glossy_exponent: float = 0.0  # Phong lobe exponent around the mirror direction; 0 is a perfect mirror
    frosted_exponent: float = 0.0  # lobe exponent around the refracted direction; 0 is clear glass
    texture: Texture | str | None = None  # multiplies kd and ka
    specular_texture: Texture | str | None = None  # multiplies ks
    mirror_texture: Texture | str | None = None  # multiplies mirror

    TEXTURE_FIELDS = ("texture", "specular_texture", "mirror_texture")

    def __post_init__(self):
        for name in self.TEXTURE_FIELDS:
            set_field(self, name, as_texture(getattr(self, name), name))
        set_field(self, "kd", as_rgb(self.kd, "kd"))
        set_field(self, "ka", self.kd if self.ka is None else as_rgb(self.ka, "ka"))
        set_field(self, "ks", as_rgb(self.ks, "ks"))
        set_field(self, "p", as_float(self.p, "p", minimum=0.0))
        set_field(self, "mirror", as_rgb(self.mirror, "mirror"))
        set_field(self, "transparency", as_rgb(self.transparency, "transparency"))
        set_field(self, "ior", as_float(self.ior, "ior", minimum=0.0, strict_min=True))
        set_field(self, "fresnel", as_choice(self.fresnel, "fresnel", FRESNEL_MODES))
        set_field(self, "glossy_exponent", as_float(self.glossy_exponent, "glossy_exponent", minimum=0.0))
        set_field(self, "frosted_exponent", as_float(self.frosted_exponent, "frosted_exponent", minimum=0.0))


DEFAULT_MATERIAL = "default"


# --- shapes --------------------------------------------------------------------------------


def _check_material(obj: Any) -> None:
    if not isinstance(obj.material, str) or not obj.material:
        raise SceneError(f"expected a material name, got {obj.material!r}", "material")


@checked_keywords
@dataclass(frozen=True)
class Sphere:
    center: Vec3 = (0.0, 0.0, 0.0)
    radius: float = 1.0
    material: str = DEFAULT_MATERIAL
    center_end: Vec3 | None = None  # centre at time 1 (motion blur)
    transform: Transform | None = None  # applied to the centre (translate, rotate, uniform scale)
    keyframes: tuple = ()  # animation: [{time, center}, ...]

    def __post_init__(self):
        set_field(self, "keyframes", as_keyframes(self.keyframes, "keyframes", ("center",)))
        set_field(self, "center", as_vec3(self.center, "center"))
        set_field(self, "radius", as_float(self.radius, "radius", minimum=0.0, float32="range"))
        _check_material(self)
        if self.center_end is not None:
            set_field(self, "center_end", as_vec3(self.center_end, "center_end"))
        set_field(self, "transform", as_transform(self.transform, "transform"))
        if self.transform is not None and self.transform.uniform_scale is None:
            raise SceneError("a sphere takes only a uniform positive scale (use a mesh for an ellipsoid)",
                             "transform.scale")

    def world(self) -> tuple[Vec3, Vec3, float]:
        """Centre at time 0, centre at time 1 and radius, with the transform applied."""
        c0, c1, r = self.center, self.center_end if self.center_end is not None else self.center, self.radius
        if self.transform is not None:
            c0, c1 = self.transform.apply_point(c0), self.transform.apply_point(c1)
            r = r * self.transform.uniform_scale
        return c0, c1, r


@checked_keywords
@dataclass(frozen=True)
class Plane:
    point: Vec3 = (0.0, 0.0, 0.0)
    normal: Vec3 = (0.0, 1.0, 0.0)
    material: str = DEFAULT_MATERIAL
    transform: Transform | None = None

    def __post_init__(self):
        set_field(self, "point", as_vec3(self.point, "point"))
        set_field(self, "normal", as_direction(self.normal, "normal"))
        _check_material(self)
        set_field(self, "transform", as_transform(self.transform, "transform"))

    def world(self) -> tuple[Vec3, Vec3]:
        p, n = self.point, self.normal
        if self.transform is not None:
            p, n = self.transform.apply_point(p), self.transform.apply_normal(n)
        return p, tuple(c / norm(n) for c in n)  # type: ignore


@checked_keywords
@dataclass(frozen=True)
class Rectangle:
    """The parallelogram corner + a·edge1 + b·edge2 for a, b in [0, 1]; its normal is edge1 x edge2."""

    corner: Vec3 = (-0.5, 0.0, -0.5)
    edge1: Vec3 = (0.0, 0.0, 1.0)
    edge2: Vec3 = (1.0, 0.0, 0.0)
    material: str = DEFAULT_MATERIAL
    transform: Transform | None = None

    def __post_init__(self):
        set_field(self, "corner", as_vec3(self.corner, "corner"))
        set_field(self, "edge1", as_direction(self.edge1, "edge1"))
        set_field(self, "edge2", as_direction(self.edge2, "edge2"))
        _check_material(self)
        set_field(self, "transform", as_transform(self.transform, "transform"))
        if norm(np.cross(self.edge1, self.edge2)) <= 1e-12 * norm(self.edge1) * norm(self.edge2):
            raise SceneError("edge1 and edge2 are parallel: the rectangle has no area", "edge2")

    def world(self) -> tuple[Vec3, Vec3, Vec3]:
        if self.transform is None:
            return self.corner, self.edge1, self.edge2
        t = self.transform
        return t.apply_point(self.corner), t.apply_vector(self.edge1), t.apply_vector(self.edge2)


@checked_keywords
@dataclass(frozen=True)
class Disk:
    center: Vec3 = (0.0, 0.0, 0.0)
    normal: Vec3 = (0.0, 1.0, 0.0)
    radius: float = 1.0
    material: str = DEFAULT_MATERIAL

    def __post_init__(self):
        set_field(self, "center", as_vec3(self.center, "center"))
        set_field(self, "normal", as_direction(self.normal, "normal"))
        set_field(self, "radius", as_float(self.radius, "radius", minimum=0.0, float32="range"))
        _check_material(self)


class _Posed:
    """What boxes, capsules and cylinders share: a ``transform`` (scale, rotate, translate) at
    time 0, an optional ``transform_end`` at time 1 (motion blur), ``keyframes`` like a mesh's."""

    def _check_pose(self, uniform: bool) -> None:
        set_field(self, "keyframes",
                  as_keyframes(self.keyframes, "keyframes", ("translate", "rotate", "quaternion", "scale")))
        _check_material(self)
        set_field(self, "transform", as_transform(self.transform, "transform"))
        set_field(self, "transform_end", as_transform(self.transform_end, "transform_end"))
        what = type(self).__name__.lower()
        for name in ("transform", "transform_end"):
            t = getattr(self, name)
            if uniform and t is not None and t.uniform_scale is None:
                raise SceneError(f"a {what} takes only a uniform positive scale (a stretched one is no longer a "
                                 f"{what}; use a mesh)", f"{name}.scale")
        t0, t1 = self.transform or Transform(), self.transform_end
        if t1 is not None and not np.allclose(np.abs(t1.scale), np.abs(t0.scale), rtol=1e-12, atol=0.0):
            raise SceneError(f"the end pose must keep the scale of the start pose ({list(t0.scale)}), got "
                             f"{list(t1.scale)}", "transform_end.scale")

    @property
    def moves(self) -> bool:
        return self.transform_end is not None and self.transform_end != (self.transform or Transform())

    def _poses(self, center, q_local) -> tuple:
        """(pos0, rot0, pos1, rot1): the local frame (centred on ``center``, turned by ``q_local``)
        placed by the transforms at times 0 and 1 (rot1 in rot0's hemisphere)."""
        t0 = self.transform or Transform()
        t1 = self.transform_end or t0
        r0 = quaternion_product(t0.quaternion(), q_local)
        r1 = same_hemisphere(quaternion_product(t1.quaternion(), q_local), r0)
        return t0.apply_point(center), tuple(float(x) for x in r0), t1.apply_point(center), tuple(float(x) for x in r1)


@checked_keywords
@dataclass(frozen=True)
class Box(_Posed):
    """A solid box with edges ``size`` along its own x, y and z axes, centred on ``center``;
    ``transform`` places it (any scale: it scales the edges), ``transform_end`` at time 1."""

    center: Vec3 = (0.0, 0.0, 0.0)
    size: Vec3 = (1.0, 1.0, 1.0)  # full edge lengths
    material: str = DEFAULT_MATERIAL
    transform: Transform | None = None
    transform_end: Transform | None = None
    keyframes: tuple = ()  # animation: [{time, translate, rotate or quaternion, scale}, ...]

    def __post_init__(self):
        set_field(self, "center", as_vec3(self.center, "center"))
        size = as_vec3(self.size, "size")
        for i, c in enumerate(size):
            as_float(c, f"size[{i}]", minimum=0.0, strict_min=True, float32="normal")
        set_field(self, "size", size)
        self._check_pose(uniform=False)

    def world(self) -> tuple:
        """(pos0, rot0, pos1, rot1, half extents) of the box in world space."""
        t = self.transform or Transform()
        half = tuple(0.5 * c * abs(s) for c, s in zip(self.size, t.scale))
        return (*self._poses(self.center, np.array([0.0, 0.0, 0.0, 1.0])), half)


@dataclass(frozen=True)
class _Round(_Posed):
    """The fields capsules and cylinders share: an axis segment from ``start`` to ``end`` and a
    radius about it."""

    start: Vec3 = (0.0, -0.5, 0.0)
    end: Vec3 = (0.0, 0.5, 0.0)
    radius: float = 0.25
    material: str = DEFAULT_MATERIAL
    transform: Transform | None = None
    transform_end: Transform | None = None
    keyframes: tuple = ()

    def __post_init__(self):
        set_field(self, "start", as_vec3(self.start, "start"))
        set_field(self, "end", as_vec3(self.end, "end"))
        set_field(self, "radius", as_float(self.radius, "radius", minimum=0.0, float32="range"))
        self._check_pose(uniform=True)

    def world(self) -> tuple:
        """(pos0, rot0, pos1, rot1, (radius, half length, 0)): local y runs from start to end."""
        a, b = np.asarray(self.start, np.float64), np.asarray(self.end, np.float64)
        s = (self.transform or Transform()).uniform_scale or 1.0
        size = (self.radius * s, 0.5 * float(np.linalg.norm(b - a)) * s, 0.0)
        return (*self._poses(tuple(0.5 * (a + b)), quaternion_y_to(b - a)), size)


@checked_keywords
@dataclass(frozen=True)
class Capsule(_Round):
    """The points within ``radius`` of the segment from ``start`` to ``end``: a cylinder with a
    hemisphere at each end (start = end gives a sphere). A uniform scale only."""


@checked_keywords
@dataclass(frozen=True)
class Cylinder(_Round):
    """A solid circular cylinder of ``radius`` about the segment from ``start`` to ``end``, closed
    by flat caps. A uniform scale only."""

    def __post_init__(self):
        super().__post_init__()
        if self.start == self.end:
            raise SceneError("start and end are the same point: the cylinder has no height", "end")


SOLID_TYPES = (Box, Capsule, Cylinder)


@checked_keywords
@dataclass(frozen=True, eq=False)
class Mesh:
    """A triangle mesh from a file (OBJ/PLY/STL/GLB/OFF through trimesh), inline arrays, or a
    ``trimesh.Trimesh`` (``Mesh(tm, material=...)``: its arrays become inline arrays). A file with
    several objects is flattened into one mesh with one material; ``warprt.load_assets`` keeps
    them apart.

    Assets are shared: meshes naming the same file (or the same arrays) use one ``wp.Mesh`` and
    differ only by their instance transform. ``smooth`` interpolates vertex normals for shading.
    """

    file: str | None = None  # path, relative to the scene file
    vertices: Any = None  # (N, 3) numbers
    faces: Any = None  # (M, 3) vertex indices
    material: str = DEFAULT_MATERIAL
    transform: Transform | None = None
    transform_end: Transform | None = None  # instance transform at time 1 (motion blur)
    smooth: bool = False
    uv: Any = None  # (N, 2) texture coordinates of inline vertices (a file brings its own)
    degenerate: str = "error"  # "error" or "drop": what to do with zero-area faces
    keyframes: tuple = ()  # animation: [{time, translate, rotate or quaternion, scale}, ...] (instance transform)

    def __post_init__(self):
        set_field(self, "keyframes",
                  as_keyframes(self.keyframes, "keyframes", ("translate", "rotate", "quaternion", "scale")))
        # a trimesh.Trimesh, given first (Mesh(tm, ...)) or as vertices, becomes inline arrays
        for name in ("file", "vertices"):
            tm = getattr(self, name)
            if _is_trimesh(tm):
                if name == "file" and self.vertices is not None:
                    raise SceneError("give either a trimesh.Trimesh or vertices, not both", "vertices")
                if self.faces is not None:
                    raise SceneError("a trimesh.Trimesh brings its own faces: drop faces", "faces")
                set_field(self, "file", None)
                set_field(self, "vertices", np.asarray(tm.vertices))
                set_field(self, "faces", np.asarray(tm.faces))
                tm_uv = getattr(getattr(tm, "visual", None), "uv", None)
                if self.uv is None and tm_uv is not None and len(tm_uv) == len(tm.vertices):
                    set_field(self, "uv", np.asarray(tm_uv))
                break
        if (self.file is None) == (self.vertices is None):
            raise SceneError("give either file or vertices (with faces)", "file")
        if self.file is not None and (not isinstance(self.file, str) or not self.file):
            raise SceneError(f"expected a path, got {self.file!r}", "file")
        if self.vertices is not None and self.faces is None:
            raise SceneError("inline vertices need faces", "faces")
        _check_material(self)
        set_field(self, "transform", as_transform(self.transform, "transform"))
        set_field(self, "transform_end", as_transform(self.transform_end, "transform_end"))
        if not isinstance(self.smooth, bool):
            raise SceneError(f"expected true or false, got {self.smooth!r}", "smooth")
        set_field(self, "degenerate", as_choice(self.degenerate, "degenerate", ("error", "drop")))
        if self.vertices is not None:
            v, f = validate_arrays(self.vertices, self.faces)
            set_field(self, "vertices", v)
            set_field(self, "faces", f)
        if self.uv is not None:
            if self.file is not None:
                raise SceneError("a mesh file brings its own texture coordinates (through trimesh): drop uv", "uv")
            set_field(self, "uv", validate_uv(self.uv, len(self.vertices)))
        # a missing file is refused now, not when a render builds the scene; a relative path is
        # taken from the current folder, where the build would read it (scene files resolve
        # theirs against their own folder first)
        if self.file is not None and not os.path.isfile(self.file):
            where = os.path.abspath(self.file)
            what = "is a folder, not a mesh file" if os.path.isdir(self.file) else "mesh file not found"
            raise SceneError(f"{what}: {self.file!r}" + (f" (looked in {where!r})" if where != self.file else ""),
                             "file")

    @classmethod
    def from_trimesh(cls, mesh: Any, **fields: Any) -> "Mesh":
        """A mesh shape from a ``trimesh.Trimesh`` (its vertices and faces, checked like inline
        arrays; its visuals are not read: give ``material``). ``Mesh(trimesh_obj, ...)`` is the same."""
        if not _is_trimesh(mesh):
            raise SceneError(f"expected a trimesh.Trimesh, got {type(mesh).__name__}", "mesh")
        return cls(vertices=mesh, **fields)

    @property
    def moves(self) -> bool:
        return self.transform_end is not None and self.transform_end != (self.transform or Transform())


def _is_trimesh(x: Any) -> bool:
    """A ``trimesh.Trimesh`` (checked without importing trimesh for scenes that do not use it); a
    ``trimesh.Scene`` (several meshes, several materials) raises, pointing to ``load_assets``."""
    module = type(x).__module__ or ""
    if not module.startswith("trimesh"):
        return False
    import trimesh

    if isinstance(x, trimesh.Scene):
        raise SceneError("a trimesh.Scene holds several meshes and materials: load it with "
                         "warprt.load_assets(scene), which gives one shape per node", "file")
    if not isinstance(x, trimesh.Trimesh):
        raise SceneError(f"a {type(x).__name__} is not a triangle mesh (only trimesh.Trimesh is)", "file")
    return True


def validate_arrays(vertices: Any, faces: Any) -> tuple[np.ndarray, np.ndarray]:
    try:
        v = np.asarray(vertices, dtype=np.float64)
    except (TypeError, ValueError):
        raise SceneError("vertices must be numbers", "vertices") from None
    if v.ndim != 2 or v.shape[1] != 3:
        raise SceneError(f"vertices must have shape (N, 3), got {v.shape}", "vertices")
    if len(v) == 0:
        raise SceneError("the mesh has no vertices", "vertices")
    bad = ~np.isfinite(v).all(axis=1)
    if bad.any():
        raise SceneError(f"{int(bad.sum())} vertices are NaN or infinite (first: vertex {int(np.argmax(bad))})",
                         "vertices")
    if np.abs(v).max() > 1e30:
        raise SceneError("vertex coordinates exceed 1e30", "vertices")
    try:
        f_in = np.asarray(faces)
    except (TypeError, ValueError):
        raise SceneError("faces must be integers", "faces") from None
    if f_in.size and not np.issubdtype(f_in.dtype, np.integer):
        if (not np.issubdtype(f_in.dtype, np.floating) or not np.isfinite(f_in).all()
                or not np.all(np.mod(f_in, 1) == 0)):
            raise SceneError("faces must be integer vertex indices", "faces")
    if f_in.size and (f_in.ndim != 2 or f_in.shape[1] != 3):
        raise SceneError(f"faces must have shape (M, 3) (triangles), got {f_in.shape}", "faces")
    f = f_in.astype(np.int64).reshape(-1, 3) if f_in.size else np.zeros((0, 3), np.int64)
    if len(f) == 0:
        raise SceneError("the mesh has no faces", "faces")
    if f.min() < 0 or f.max() >= len(v):
        raise SceneError(f"face indices must be in [0, {len(v) - 1}], found {int(f.min())}..{int(f.max())}", "faces")
    return v, f


# --- lights --------------------------------------------------------------------------------


@checked_keywords
@dataclass(frozen=True)
class PointLight:
    position: Vec3 = (0.0, 5.0, 5.0)
    intensity: RGB = (1.0, 1.0, 1.0)  # I in the lecture's formula
    falloff: str = "none"  # "none" (the lecture's) or "inverse_square" (I / r^2)

    def __post_init__(self):
        set_field(self, "position", as_vec3(self.position, "position"))
        set_field(self, "intensity", as_rgb(self.intensity, "intensity"))
        set_field(self, "falloff", as_choice(self.falloff, "falloff", FALLOFFS))


@checked_keywords
@dataclass(frozen=True)
class DirectionalLight:
    """Light from infinitely far away (the sun; a robotics camera's usual key light): every point
    receives it along the same direction, with no falloff. ``direction`` is the way the light
    travels (from the light into the scene); shading is the point light's with falloff "none",
    L = I·(kd·max(0, n·l) + ks·max(0, n·h)^p) with l = -direction, and its shadow rays run to
    infinity."""

    direction: Vec3 = (0.0, -1.0, 0.0)
    intensity: RGB = (1.0, 1.0, 1.0)  # I in the lecture's formula

    def __post_init__(self):
        d = as_direction(self.direction, "direction")
        set_field(self, "direction", tuple(float(x) / norm(d) for x in d))
        set_field(self, "intensity", as_rgb(self.intensity, "intensity"))


# an area light's ``samples`` may say "auto": the renderer picks the shadow rays per camera sample
# from the variance split it measures (warprt.splitting)
AUTO_SAMPLES = "auto"


def _area_light_common(obj: Any) -> None:
    set_field(obj, "radiance", as_rgb(obj.radiance, "radiance"))
    if isinstance(obj.samples, str):
        if obj.samples != AUTO_SAMPLES:
            raise SceneError(f'expected a whole number of shadow rays or "{AUTO_SAMPLES}", got {obj.samples!r}',
                             "samples")
    else:
        set_field(obj, "samples", as_int(obj.samples, "samples", minimum=1, maximum=1024))


@checked_keywords
@dataclass(frozen=True)
class RectLight:
    """A one-sided emitting parallelogram (emits along edge1 x edge2), visible to camera rays."""

    corner: Vec3 = (-0.5, 4.0, -0.5)
    edge1: Vec3 = (1.0, 0.0, 0.0)
    edge2: Vec3 = (0.0, 0.0, 1.0)
    radiance: RGB = (1.0, 1.0, 1.0)  # Le, emitted radiance
    # shadow rays per shading point and camera sample, or "auto": chosen per scene by a small pilot
    # (warprt.splitting), which pays where one renderer renders long or often (its cost is the
    # renderer's once)
    samples: int | str = 1

    def __post_init__(self):
        r = Rectangle(self.corner, self.edge1, self.edge2)
        set_field(self, "corner", r.corner)
        set_field(self, "edge1", r.edge1)
        set_field(self, "edge2", r.edge2)
        _area_light_common(self)

    @property
    def area(self) -> float:
        return norm(np.cross(self.edge1, self.edge2))

    def shape(self) -> Rectangle:
        """The surface that emits (an area light is emission on a shape)."""
        return Rectangle(self.corner, self.edge1, self.edge2)


@checked_keywords
@dataclass(frozen=True)
class SphereLight:
    """An emitting sphere, sampled by the cone of directions it subtends."""

    center: Vec3 = (0.0, 4.0, 0.0)
    radius: float = 0.5
    radiance: RGB = (1.0, 1.0, 1.0)
    samples: int | str = 1  # (as RectLight's)

    def __post_init__(self):
        set_field(self, "center", as_vec3(self.center, "center"))
        set_field(self, "radius", as_float(self.radius, "radius", minimum=0.0, float32="range"))
        _area_light_common(self)

    def shape(self) -> Sphere:
        return Sphere(self.center, self.radius)


@checked_keywords
@dataclass(frozen=True)
class DiskLight:
    """A one-sided emitting disk (emits along ``normal``)."""

    center: Vec3 = (0.0, 4.0, 0.0)
    normal: Vec3 = (0.0, -1.0, 0.0)
    radius: float = 0.5
    radiance: RGB = (1.0, 1.0, 1.0)
    samples: int | str = 1  # (as RectLight's)

    def __post_init__(self):
        set_field(self, "center", as_vec3(self.center, "center"))
        set_field(self, "normal", as_direction(self.normal, "normal"))
        set_field(self, "radius", as_float(self.radius, "radius", minimum=0.0, float32="range"))
        _area_light_common(self)

    def shape(self) -> Disk:
        return Disk(self.center, self.normal, self.radius)


# --- depth sensor ---------------------------------------------------------------------------

INVALID_DEPTH = ("nan", "zero")  # DepthSensor.invalid


def _as_far_limit(value: Any, name: str) -> float:
    """A far limit (a positive float32-range distance) or infinity, meaning none."""
    if isinstance(value, (int, float)) and not isinstance(value, bool) and value == math.inf:
        return math.inf
    return as_float(value, name, minimum=0.0, strict_min=True, float32="range")


@checked_keywords
@dataclass(frozen=True)
class DepthSensor:
    """What a depth camera reports instead of the exact depth: stereo noise, range limits and
    dropouts at grazing angles (``sensor_z`` and ``sensor_depth`` outputs; :mod:`warprt.sensor`).

    * **stereo noise**: the sensor measures the disparity d = f·b / Z (``focal_length`` f in
      pixels, ``baseline`` b in scene units) with a Gaussian error of ``disparity_sigma`` pixels,
      rounded to ``disparity_step`` pixels when that is set, and reports Z' = f·b / d'. To first
      order σ_Z = Z²·σ_d / (f·b) (:meth:`sigma_z`).
    * **range limits**: a reported Z' outside [``min_range``, ``max_range``] is invalid.
    * **grazing-angle dropouts**: a pixel whose surface normal makes an angle θ with the ray back
      to the camera is dropped with probability 0 for θ < ``dropout_start``, 1 for θ >=
      ``dropout_end`` and (θ - start) / (end - start) in between (:meth:`dropout_probability`);
      start 90 (the default) drops nothing.

    Invalid pixels (and pixels that see nothing) read ``invalid``: ``"nan"`` or ``"zero"``.
    Every effect is off by default; the noise is seeded by the render's seed.
    """

    baseline: float | None = None  # b: distance between the stereo pair's centres, scene units
    focal_length: float | None = None  # f: the stereo pair's focal length, pixels
    disparity_sigma: float = 0.0  # σ_d: standard deviation of the disparity error, pixels
    disparity_step: float = 0.0  # disparity quantisation step, pixels (0: none; 1/8 for subpixel 3 bits)
    min_range: float = 0.0  # shortest valid reported depth Z', scene units
    max_range: float = math.inf  # longest valid reported depth Z', scene units
    dropout_start: float = 90.0  # degrees: no dropouts below this angle
    dropout_end: float = 90.0  # degrees: every pixel dropped from this angle on
    invalid: str = "nan"  # value of invalid pixels: "nan" or "zero"

    def __post_init__(self):
        for name in ("baseline", "focal_length"):
            if getattr(self, name) is not None:
                set_field(self, name, as_float(getattr(self, name), name, minimum=0.0, strict_min=True,
                                               float32="normal"))
        set_field(self, "disparity_sigma", as_float(self.disparity_sigma, "disparity_sigma", minimum=0.0,
                                                    float32="range"))
        set_field(self, "disparity_step", as_float(self.disparity_step, "disparity_step", minimum=0.0,
                                                   float32="range"))
        if self.stereo:
            for name in ("baseline", "focal_length"):
                if getattr(self, name) is None:
                    raise SceneError("needed with disparity_sigma or disparity_step (the disparity is "
                                     "focal_length · baseline / Z)", name)
        set_field(self, "min_range", as_float(self.min_range, "min_range", minimum=0.0, float32="range"))
        set_field(self, "max_range", _as_far_limit(self.max_range, "max_range"))
        if self.max_range <= self.min_range:
            raise SceneError(f"must exceed min_range ({self.min_range:g}), got {self.max_range:g}", "max_range")
        for name in ("dropout_start", "dropout_end"):
            set_field(self, name, as_float(getattr(self, name), name, minimum=0.0, maximum=90.0))
        if self.dropout_end < self.dropout_start:
            raise SceneError(f"must be >= dropout_start ({self.dropout_start:g}), got {self.dropout_end:g}",
                             "dropout_end")
        set_field(self, "invalid", as_choice(self.invalid, "invalid", INVALID_DEPTH))

    @property
    def stereo(self) -> bool:
        """Whether depth goes through the disparity (noise or quantisation)."""
        return self.disparity_sigma > 0.0 or self.disparity_step > 0.0

    @property
    def dropouts(self) -> bool:
        return self.dropout_start < 90.0

    def sigma_z(self, z):
        """The first-order standard deviation of the reported depth at true depth ``z``:
        z² · disparity_sigma / (focal_length · baseline) (0 without stereo noise)."""
        if not self.disparity_sigma:
            return 0.0 * np.asarray(z, np.float64)
        return np.asarray(z, np.float64) ** 2 * self.disparity_sigma / (self.focal_length * self.baseline)

    def dropout_probability(self, angle):
        """The probability that a pixel seeing its surface at ``angle`` degrees from the normal
        is dropped."""
        a = np.asarray(angle, np.float64)
        if not self.dropouts:
            return np.zeros_like(a)
        if self.dropout_end == self.dropout_start:
            return (a >= self.dropout_end).astype(np.float64)
        return np.clip((a - self.dropout_start) / (self.dropout_end - self.dropout_start), 0.0, 1.0)


# --- render settings and the scene ------------------------------------------------------------


@checked_keywords
@dataclass(frozen=True)
class RenderSettings:
    spp: int = 1  # samples per pixel
    sampler: str = "sobol"  # "regular", "independent", "stratified" or "sobol"
    max_depth: int = 5  # reflection/refraction bounces after the camera ray
    min_weight: float = 1e-4  # rays whose throughput falls below this are not traced
    t_min: float = 0.0  # camera rays: nearest accepted distance
    t_max: float = math.inf  # camera rays: farthest accepted distance
    clamp: float = 1e20  # each sample's radiance is clamped to this (overflow guard)
    # rectangle lights on Lambertian surfaces: "cosine" draws directions in proportion to n·ω, so a
    # fully lit (or fully shadowed) point has no noise; "uniform" by solid angle or area
    light_sampling: str = "cosine"
    # adaptive sampling where a render takes a sample budget (``Renderer.render``'s ``adaptive``)
    adaptive: bool = True

    def __post_init__(self):
        set_field(self, "spp", as_int(self.spp, "spp", minimum=1))
        if self.spp > SPP_LIMIT:
            raise SceneError(f"must be <= {SPP_LIMIT} (2^20), got {self.spp}; {SPP_LIMIT_HINT}", "spp")
        set_field(self, "sampler", as_choice(self.sampler, "sampler", SAMPLERS))
        set_field(self, "max_depth", as_int(self.max_depth, "max_depth", minimum=0, maximum=MAX_DEPTH_LIMIT))
        set_field(self, "min_weight", as_float(self.min_weight, "min_weight", minimum=0.0, maximum=1.0))
        set_field(self, "t_min", as_float(self.t_min, "t_min", minimum=0.0, float32="range"))
        set_field(self, "t_max", _as_far_limit(self.t_max, "t_max"))
        if self.t_max <= self.t_min:
            raise SceneError(f"t_max ({self.t_max:g}) must exceed t_min ({self.t_min:g})", "t_max")
        set_field(self, "clamp", as_float(self.clamp, "clamp", minimum=0.0, strict_min=True, maximum=CLAMP_LIMIT))
        set_field(self, "light_sampling", as_choice(self.light_sampling, "light_sampling", LIGHT_SAMPLING))
        if not isinstance(self.adaptive, bool):
            raise SceneError(f"expected true or false, got {self.adaptive!r}", "adaptive")


# beyond this, squared distances (|o - c|² in the sphere test, |p - x|² to a light) overflow
# float32 (sqrt(3.4e38) = 1.8e19, less a margin for sums): surfaces and lights vanish
EXTENT_WARNING = 1e19


def scene_extent(scene: "Scene") -> float:
    """Largest absolute world coordinate (plus radii) of the camera, analytic shapes and lights
    (meshes are checked against 1e30 when their vertices are read)."""
    cam = scene.camera
    values: list[float] = [*cam.eye, *cam.look_at, *(cam.eye_end or ()), *(cam.look_at_end or ())]
    for k in cam.keyframes:
        values += [*k.get("eye", ()), *k.get("look_at", ())]
    shapes = list(scene.shapes) + [light.shape() for light in scene.lights if is_area_light(light)]
    for s in shapes:
        if isinstance(s, Sphere):
            c0, c1, r = s.world()
            values += [abs(x) + r for x in (*c0, *c1)]
            for k in s.keyframes:
                values += [abs(x) + r for x in k.get("center", ())]
        elif isinstance(s, Plane):
            values += list(s.world()[0])
        elif isinstance(s, Rectangle):
            c, e1, e2 = s.world()
            values += [abs(a) + abs(b) + abs(d) for a, b, d in zip(c, e1, e2)]
        elif isinstance(s, Disk):
            values += [abs(x) + s.radius for x in s.center]
        elif isinstance(s, SOLID_TYPES):
            pos0, _, pos1, _, size = s.world()
            reach = norm(size)
            values += [abs(x) + reach for x in (*pos0, *pos1)]
    for light in scene.lights:
        if isinstance(light, PointLight):
            values += list(light.position)
    return max((abs(v) for v in values), default=0.0)


# below this a length's square underflows float32's normal range (sqrt(1.2e-38) = 1.1e-19): ray
# tests of a shape that small (|o - c|² - r², edge cross products) lose it or give zero
UNDERFLOW_WARNING = 1e-19


def shape_size(s) -> float | None:
    """The largest dimension of an analytic shape in world space (None for a plane, infinite, and
    for a mesh, whose vertices the builder reads)."""
    if isinstance(s, Sphere):
        return s.world()[2]
    if isinstance(s, Rectangle):
        _, e1, e2 = s.world()
        return max(norm(e1), norm(e2))
    if isinstance(s, Disk):
        return s.radius
    if isinstance(s, SOLID_TYPES):
        return norm(s.world()[4])
    return None


def tiny_shapes(scene: "Scene") -> list[tuple[str, float]]:
    """(field, size) of every analytic shape and area light whose size is non-zero but below
    UNDERFLOW_WARNING (meshes are measured by the builder)."""
    out = []
    for i, s in enumerate(scene.shapes):
        size = shape_size(s)
        if size is not None and 0.0 < size < UNDERFLOW_WARNING:
            out.append((f"shapes[{i}]", size))
    for i, light in enumerate(scene.lights):
        if is_area_light(light):
            size = shape_size(light.shape())
            if size is not None and 0.0 < size < UNDERFLOW_WARNING:
                out.append((f"lights[{i}]", size))
    return out


def is_area_light(light) -> bool:
    """An area light is emission on a shape: it gives its emitting surface through ``.shape()``."""
    return callable(getattr(light, "shape", None))


def _has_uv(shape) -> bool:
    """Whether a shape has texture coordinates (rectangles and spheres by their parametrisation,
    meshes from their file or their ``uv``)."""
    if isinstance(shape, (Rectangle, Sphere)):
        return True
    if isinstance(shape, Mesh):
        if shape.file is None:
            return shape.uv is not None
        return read_mesh_file(shape.file)[2] is not None  # (the parsed file is cached for the build)
    return False


# the one list of each: scene-file type names, the classes behind them (the loader, Scene's
# validation and the package's exports read these)
SHAPE_TYPES = {"sphere": Sphere, "plane": Plane, "rectangle": Rectangle, "disk": Disk, "box": Box, "capsule": Capsule,
               "cylinder": Cylinder, "mesh": Mesh}
LIGHT_TYPES = {"point": PointLight, "directional": DirectionalLight, "rectangle": RectLight, "sphere": SphereLight, "disk": DiskLight}
Shape = Sphere | Plane | Rectangle | Disk | Box | Capsule | Cylinder | Mesh
Light = PointLight | DirectionalLight | RectLight | SphereLight | DiskLight


@checked_keywords
@dataclass(frozen=True, eq=False)
class Scene:
    """Everything needed to render one image. Build it in Python or load it with ``load_scene``."""

    camera: Camera = field(default_factory=Camera)
    shapes: tuple = ()
    materials: Mapping[str, Material] = field(default_factory=dict)
    lights: tuple = ()
    ambient: RGB = (0.0, 0.0, 0.0)  # Ia, scene ambient intensity
    background: RGB = (0.0, 0.0, 0.0)  # radiance of rays that hit nothing
    render: RenderSettings = field(default_factory=RenderSettings)
    animation: Animation = field(default_factory=Animation)
    source: str | None = None  # the scene file, for messages and relative mesh paths
    depth_sensor: DepthSensor | None = None  # what the sensor_z and sensor_depth outputs report

    def __post_init__(self):
        try:
            self._validate()
        except SceneError as e:
            raise e.within(source=self.source) from None

    def _validate(self) -> None:
        for name, cls in (("camera", Camera), ("render", RenderSettings), ("animation", Animation)):
            if not isinstance(getattr(self, name), cls):
                raise SceneError(f"expected a {cls.__name__}, got {type(getattr(self, name)).__name__}", name)
        if self.depth_sensor is not None and not isinstance(self.depth_sensor, DepthSensor):
            raise SceneError(f"expected a DepthSensor or None, got {type(self.depth_sensor).__name__}",
                             "depth_sensor")
        for name, kinds in (("shapes", SHAPE_TYPES), ("lights", LIGHT_TYPES)):
            value = getattr(self, name)
            if isinstance(value, tuple(kinds.values())):
                raise SceneError(f"expected a list of {name}, got one {type(value).__name__} (write "
                                 f"{name}=[{type(value).__name__}(...)])", name)
            if isinstance(value, (str, bytes, Mapping)) or not isinstance(value, (Sequence, np.ndarray)):
                raise SceneError(f"expected a list of {name}, got {type(value).__name__}", name)
            set_field(self, name, tuple(value))
        if not isinstance(self.materials, Mapping):
            raise SceneError(f"expected a dict of name: Material, got {type(self.materials).__name__}", "materials")
        mats = dict(self.materials)
        for key, m in mats.items():
            if not isinstance(key, str) or not key:
                raise SceneError(f"material names must be non-empty strings, got {key!r}", "materials")
            if not isinstance(m, Material):
                raise SceneError(f"expected a Material, got {type(m).__name__}", f"materials.{key}")
        mats.setdefault(DEFAULT_MATERIAL, Material())
        set_field(self, "materials", mats)
        for i, s in enumerate(self.shapes):
            if not isinstance(s, tuple(SHAPE_TYPES.values())):
                names = ", ".join(c.__name__ for c in SHAPE_TYPES.values())
                raise SceneError(f"expected a shape ({names}), got {type(s).__name__}", f"shapes[{i}]")
            if s.material not in mats:
                known = ", ".join(sorted(mats))
                raise SceneError(f"unknown material {s.material!r} (known: {known})", f"shapes[{i}].material")
            uv_maps = [name for name in Material.TEXTURE_FIELDS
                       if getattr(mats[s.material], name) is not None and getattr(mats[s.material], name).projection == "uv"]
            if uv_maps and not _has_uv(s):
                what = ("its mesh has no texture coordinates (give uv, or a file with UVs)" if isinstance(s, Mesh)
                        else f"a {type(s).__name__.lower()} has no texture coordinates")
                raise SceneError(f"material {s.material!r} maps its {uv_maps[0]} by uv, but {what}; use "
                                 f"projection = \"triplanar\" or \"cubic\"", f"shapes[{i}].material")
        for i, light in enumerate(self.lights):
            if not isinstance(light, tuple(LIGHT_TYPES.values())):
                raise SceneError(f"expected a light, got {type(light).__name__}", f"lights[{i}]")
        set_field(self, "ambient", as_rgb(self.ambient, "ambient"))
        set_field(self, "background", as_rgb(self.background, "background"))

    def replace(self, **changes: Any) -> "Scene":
        """A copy with some fields changed (``camera``, ``render`` ...)."""
        return replace(self, **changes)

    def with_settings(self, **changes: Any) -> "Scene":
        """A copy with render settings changed, e.g. ``scene.with_settings(spp=64)``."""
        return replace(self, render=replace(self.render, **changes))

    def with_camera(self, **changes: Any) -> "Scene":
        return replace(self, camera=replace(self.camera, **changes))

