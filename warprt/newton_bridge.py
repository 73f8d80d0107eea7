"""Render a Newton simulation (``newton.Model`` / ``newton.State``) with warprt, every world at once.

``pip install 'warprt[newton]'``. Importing warprt never imports Newton; this module does.

:func:`scene_from_model` turns the model's shapes into one warprt scene structure: the shapes of
world 0 (every world of a replicated model holds the same shapes) plus the global shapes (world
-1, e.g. the ground), each described in its own local frame, with a Lambert material of its
colour (Newton's colours are display sRGB; warprt shades in linear RGB, so they are converted as
Newton's own renderer does). :class:`NewtonRenderer` builds a :class:`warprt.BatchRenderer` over
``model.world_count`` worlds and, on every :meth:`~NewtonRenderer.update`, launches one kernel
that writes each shape's world pose ``body_q[body] * shape_transform`` straight into the batch's
``shape_poses``: no host copy, no rebuild, no recompile.

Shape kinds: spheres, boxes, capsules and cylinders stay analytic (exact; warprt's own ``Sphere``,
``Box``, ``Capsule`` and ``Cylinder``), and so do planes (a plane with a finite width/length
becomes a rectangle); cones and ellipsoids become triangle meshes inscribed in them
(``trimesh.creation``, ``TESSELLATION`` below: 64 sections around the axis, an icosphere of 5120
faces for an ellipsoid; every facet lies within 1 − cos(π/64) = 0.12% of the shape's largest
radius of the analytic surface, which the tests check against Newton's own intersections);
meshes and convex hulls keep their triangles (times their scale). A plane's scale holds its full
width and length (0: infinite), as in Newton's ray cast. Height fields, SDFs, Gaussians,
particles, barrel cylinders and planes finite along one axis only are refused with the shape's
index; invisible shapes (no ``VISIBLE`` flag, e.g. collision-only ones) are skipped as Newton's
camera skips them; opacity and Newton's textures are not read (every shape is an opaque Lambert
surface of its colour). For domain randomisation, each world's colours and textures of the shapes
and intensities of the lights change between frames (``set_shape_colors``,
``set_shape_textures`` with the ``textures`` given to the constructor or added with
``add_texture``, ``set_light_intensities``): runtime data, no rebuild, no recompile.
Up axis: a Newton model is z-up unless built with ``ModelBuilder(up_axis="Y")`` (or "X");
``model.up_axis`` says which (:attr:`NewtonRenderer.up_axis`). Shapes are placed by their own
transforms whatever the axis; what depends on it follows the model as Newton's camera does: the
default light (Newton's, (-1, 1, -1)/√3 for z-up, turned with the up axis so that it always
points down), the default camera's placement and its up, and the up axis against which
``set_camera_poses`` checks the roll of the poses (:mod:`warprt.poses`). Cameras are placed with
``camera_poses`` (camera to world, looking along local -z, +y up), like Newton's own camera
transforms; :func:`warprt.look_at` makes them from an eye, a target and ``renderer.up_axis``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import warp as wp

from .checks import check_bodies
from .colour import srgb_to_linear
from .errors import RenderError, SceneError
from .poses import look_at, up_vector
from .scene.description import (
    Box, Camera, Capsule, Cylinder, DepthSensor, DirectionalLight, Material, Mesh, Plane, Rectangle, RenderSettings,
    Scene, Sphere,
)
from .worlds import BatchRenderer

TESSELLATION = dict(sphere_subdivisions=4, cylinder_sections=64)  # meshes for curved Newton shapes

# newton.GeoType values (checked against the installed Newton on import of the model)
_PLANE, _HFIELD, _SPHERE, _CAPSULE, _ELLIPSOID, _CYLINDER, _BOX, _MESH, _CONE, _CONVEX = 1, 2, 3, 4, 5, 6, 7, 8, 9, 10
_VISIBLE = 1  # newton.ShapeFlags.VISIBLE


def _check_newton_enums() -> None:
    import newton

    expected = dict(PLANE=_PLANE, HFIELD=_HFIELD, SPHERE=_SPHERE, CAPSULE=_CAPSULE, ELLIPSOID=_ELLIPSOID,
                    CYLINDER=_CYLINDER, BOX=_BOX, MESH=_MESH, CONE=_CONE, CONVEX_MESH=_CONVEX)
    for name, value in expected.items():
        if int(getattr(newton.GeoType, name)) != value:
            raise SceneError(f"this Newton's GeoType.{name} is {int(getattr(newton.GeoType, name))}, warprt "
                             f"expects {value}: install newton==1.8.0", "model")
    if int(newton.ShapeFlags.VISIBLE) != _VISIBLE:
        raise SceneError("this Newton's ShapeFlags.VISIBLE differs from 1.8's", "model")


MODEL_ARRAYS = ("shape_type", "shape_world", "shape_flags", "shape_scale", "shape_body", "shape_transform")


def check_model(model) -> None:
    """``model`` is a finalised Newton model (``ModelBuilder.finalize()``), else a SceneError
    naming what it is."""
    missing = [a for a in (*MODEL_ARRAYS, "world_count", "body_count", "device") if not hasattr(model, a)]
    if missing:
        kind = "a newton.ModelBuilder (call .finalize() first)" if hasattr(model, "finalize") else type(model).__name__
        raise SceneError(f"expected a newton.Model (ModelBuilder.finalize()), got {kind}", "model")
    for name in MODEL_ARRAYS:
        if not isinstance(getattr(model, name), wp.array):
            raise SceneError(f"expected a wp.array, got {type(getattr(model, name)).__name__}", f"model.{name}")


def _mesh_of(kind: int, scale, source, index: int):
    """(vertices, faces) of a Newton shape in its local frame."""
    import trimesh

    sx, sy, sz = (float(x) for x in scale)
    if kind == _CONE:
        m = trimesh.creation.cone(radius=sx, height=2 * sy, sections=TESSELLATION["cylinder_sections"])
        m.apply_translation((0, 0, -sy))  # Newton's cone is centred on its origin
    elif kind == _ELLIPSOID:
        m = trimesh.creation.icosphere(subdivisions=TESSELLATION["sphere_subdivisions"], radius=1.0)
        m.apply_scale((sx, sy, sz))
    elif kind in (_MESH, _CONVEX):
        if source is None or not hasattr(source, "vertices"):
            raise SceneError("a mesh shape without vertices", f"model.shapes[{index}]")
        v = np.asarray(source.vertices, np.float64) * np.array([sx, sy, sz])
        f = np.asarray(source.indices, np.int64).reshape(-1, 3)
        return v, f
    else:
        raise SceneError(f"shape kind {kind} (height fields, SDFs, Gaussians) cannot be rendered by warprt",
                         f"model.shapes[{index}]")
    return np.asarray(m.vertices, np.float64), np.asarray(m.faces, np.int64)


@dataclass(frozen=True)
class ShapeMap:
    """Which Newton shape each warprt shape is, in every world: ``newton_shape[w, j]``."""

    newton_shape: np.ndarray  # (W, S) int32
    global_shapes: int  # the first this many warprt shapes are Newton's global shapes (world -1)


def _warprt_shape(model, s: int, material: str):
    kind = int(model.shape_type.numpy()[s])
    scale = model.shape_scale.numpy()[s]
    if kind == _SPHERE:
        return Sphere(center=(0.0, 0.0, 0.0), radius=float(scale[0]), material=material)
    if kind == _PLANE:  # scale = (width, length, 0): full extents along local x and y, 0 = infinite
        w, h = float(scale[0]), float(scale[1])
        if w > 0 and h > 0:
            return Rectangle(corner=(-0.5 * w, -0.5 * h, 0.0), edge1=(w, 0.0, 0.0), edge2=(0.0, h, 0.0),
                             material=material)
        if w > 0 or h > 0:
            raise SceneError(f"a plane finite along one axis only (width {w}, length {h}) has no warprt "
                             "counterpart (give both extents, or neither)", f"model.shapes[{s}]")
        return Plane(point=(0.0, 0.0, 0.0), normal=(0.0, 0.0, 1.0), material=material)
    if kind == _CYLINDER and float(scale[2]) != 0.0:
        raise SceneError(f"a barrel cylinder (barrel_radius {float(scale[2])}) cannot be rendered by warprt "
                         "(straight cylinders only)", f"model.shapes[{s}]")
    if kind == _BOX:  # half extents
        return Box(size=tuple(2.0 * float(x) for x in scale), material=material)
    if kind in (_CAPSULE, _CYLINDER):  # radius, half height, along local z
        r, h = float(scale[0]), float(scale[1])
        solid = Capsule if kind == _CAPSULE else Cylinder
        return solid(start=(0.0, 0.0, -h), end=(0.0, 0.0, h), radius=r, material=material)
    v, f = _mesh_of(kind, scale, model.shape_source[s], s)
    return Mesh(vertices=v, faces=f, material=material)


def up_rotation(model) -> np.ndarray:
    """The rotation (3×3) that takes z-up to the model's up axis (Newton's
    ``Axis.Z.quat_between_axes(up_axis)``: the identity for a z-up model, -90° about x for y-up)."""
    up = model_up_axis(model)
    z = np.array([0.0, 0.0, 1.0])
    axis = np.cross(z, up)
    s, c = np.linalg.norm(axis), float(np.dot(z, up))
    if s < 1e-12:
        return np.eye(3) if c > 0 else np.diag([1.0, -1.0, -1.0])
    k = axis / s
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + s * K + (1 - c) * K @ K


def model_up_axis(model) -> np.ndarray:
    """The model's up axis as a unit vector (``model.up_axis``: Newton's ``Axis``; z when absent)."""
    return up_vector(getattr(model, "up_axis", 2), "model.up_axis")


def scene_from_model(model, camera: Camera | None = None, lights=None, ambient=0.0, background=(0.0, 0.0, 0.0),
                     render: RenderSettings | None = None, depth_sensor: DepthSensor | None = None
                     ) -> tuple[Scene, ShapeMap]:
    """A warprt scene of one Newton world (plus the global shapes) and the map from its shapes to
    Newton's shapes in every world. ``lights`` default to Newton's default light (directional,
    along (-1, 1, -1)/√3 for a z-up model, turned to the model's up axis otherwise, intensity 1);
    the default camera looks at the origin from (4, -4, 3) (turned likewise) with the model's up.
    ``depth_sensor``: the scene's :class:`warprt.DepthSensor` (``sensor_z`` / ``sensor_depth``)."""
    check_model(model)
    _check_newton_enums()
    types = model.shape_type.numpy()
    worlds = model.shape_world.numpy()
    flags = model.shape_flags.numpy()
    colors = model.shape_color.numpy() if model.shape_color is not None else np.full((len(types), 3), 0.7)
    visible = (flags & _VISIBLE) != 0
    n_worlds = max(int(model.world_count), 1)
    global_shapes = [s for s in range(len(types)) if worlds[s] < 0 and visible[s]]
    per_world = [[s for s in range(len(types)) if worlds[s] == w and visible[s]] for w in range(n_worlds)]
    for w in range(1, n_worlds):
        if [int(types[s]) for s in per_world[w]] != [int(types[s]) for s in per_world[0]] or not np.allclose(
                model.shape_scale.numpy()[per_world[w]], model.shape_scale.numpy()[per_world[0]]):
            raise SceneError(f"world {w} holds other shapes than world 0; warprt renders worlds of one structure "
                             "(build them with ModelBuilder.replicate)", "model")
    shapes, materials = [], {}
    for j, s in enumerate(global_shapes + per_world[0]):
        name = f"shape{j}"
        materials[name] = Material(kd=tuple(map(float, srgb_to_linear(np.asarray(colors[s], np.float64)))), ka=0.0)
        shapes.append(_warprt_shape(model, s, name))
    table = np.array([global_shapes + per_world[w] for w in range(n_worlds)], np.int32).reshape(n_worlds, len(shapes))
    R = up_rotation(model)

    def turned(v):
        return tuple(float(x) + 0.0 for x in R @ np.asarray(v, np.float64))

    scene = Scene(camera=camera or Camera(eye=turned((4, -4, 3)), look_at=turned((0, 0, 0.5)), up=turned((0, 0, 1)),
                                          fov=45, width=128, height=128),
                  shapes=tuple(shapes), materials=materials,
                  lights=tuple(lights) if lights is not None else (
                      DirectionalLight(direction=turned((-1, 1, -1)), intensity=1.0),),
                  ambient=ambient, background=background, render=render or RenderSettings(spp=1),
                  depth_sensor=depth_sensor)
    return scene, ShapeMap(newton_shape=table, global_shapes=len(global_shapes))


@wp.kernel(module="warprt_newton", enable_backward=False)
def _shape_poses(newton_shape: wp.array2d(dtype=wp.int32), shape_body: wp.array(dtype=wp.int32),
                 shape_transform: wp.array(dtype=wp.transform), body_q: wp.array(dtype=wp.transform),
                 poses: wp.array2d(dtype=wp.transform)):
    w, j = wp.tid()
    s = newton_shape[w, j]
    X = shape_transform[s]
    b = shape_body[s]
    if b >= 0:
        X = wp.transform_multiply(body_q[b], X)
    poses[w, j] = X


class NewtonRenderer:
    """Every world of a Newton model through ``cameras`` cameras each, from the simulation state.

    ``camera``: the warprt camera giving image size, field of view, aperture, focus and shutter
    (its pose is the default of every camera); ``lights``/``ambient``/``background`` as in
    :func:`scene_from_model`; ``motion_blur=True`` blurs between the previous and the current
    state (call :meth:`update` every step). Soft shadows come from area lights in ``lights``,
    depth of field from the camera's aperture. ``check_inputs``: every :meth:`update` checks, on
    the device, the poses of the bodies that carry shapes (finite, unit quaternions: an exploded
    simulation is named by body and world, see ``warprt.checks``), and every render the camera
    arrays; False skips both once the pipeline trusts its simulation. ``depth_sensor``: a
    :class:`warprt.DepthSensor` whose outputs (``sensor_z``, ``sensor_depth``) :meth:`render`
    gives on request.
    """

    def __init__(self, model, cameras: int = 1, camera: Camera | None = None, lights=None, ambient=0.0,
                 background=(0.0, 0.0, 0.0), render: RenderSettings | None = None, motion_blur: bool = False,
                 device: str | None = None, check_inputs: bool = True, depth_sensor: DepthSensor | None = None,
                 textures=()):
        check_model(model)
        self.model = model
        self.scene, self.shape_map = scene_from_model(model, camera, lights, ambient, background, render,
                                                      depth_sensor)
        #: the model's up axis (a unit vector): ``warprt.look_at(eye, target, renderer.up_axis)``
        self.up_axis = model_up_axis(model)
        self.batch = BatchRenderer(self.scene, worlds=self.shape_map.newton_shape.shape[0], cameras=cameras,
                                   device=device if device is not None else str(model.device),
                                   motion_blur=motion_blur, check_inputs=check_inputs, up_axis=self.up_axis,
                                   textures=textures)
        dev = self.batch.device
        self._map = wp.array(self.shape_map.newton_shape, dtype=wp.int32, device=dev)
        self._updates = 0
        # the bodies whose poses place a rendered shape (checked every update)
        body = model.shape_body.numpy()[self.shape_map.newton_shape.reshape(-1)] if self.scene.shapes else []
        used = np.unique(np.asarray(body, np.int64))
        self._bodies = wp.array(used[used >= 0].astype(np.int32), dtype=wp.int32, device=dev)
        self._body_labels = list(getattr(model, "body_label", None) or [])
        self._body_worlds = model.body_world.numpy() if isinstance(getattr(model, "body_world", None), wp.array) \
            else None

    @property
    def check_inputs(self) -> bool:
        return self.batch.check_inputs

    @check_inputs.setter
    def check_inputs(self, value: bool) -> None:
        self.batch.check_inputs = bool(value)

    @property
    def counters(self) -> dict:
        return self.batch.counters

    def update(self, state) -> None:
        """Shape poses from ``state.body_q`` (on the device; the previous ones become the
        shutter-open poses when motion blur is on)."""
        b = self.batch
        body_q = getattr(state, "body_q", None)
        if not isinstance(body_q, wp.array) or body_q.dtype != wp.transform or body_q.ndim != 1:
            got = type(body_q).__name__ if not isinstance(body_q, wp.array) else \
                f"{getattr(body_q.dtype, '__name__', body_q.dtype)} {tuple(body_q.shape)}"
            raise RenderError(f"state.body_q: expected a wp.array of wp.transform (a newton.State), got {got}")
        if body_q.device != b.device:
            raise RenderError(f"state.body_q is on {body_q.device}, the renderer on {b.device}")
        if self.check_inputs:
            if getattr(self, "_check_answer", None) is None:
                self._check_answer = wp.zeros(2, dtype=int, device=b.device)
            check_bodies(body_q, self._bodies, b.device, self._body_labels, self._body_worlds, self._check_answer)
        if b.motion_blur:
            wp.copy(b.shape_poses, b.shape_poses_end if self._updates else b.shape_poses)
            target = b.shape_poses_end
        else:
            target = b.shape_poses
        if self.scene.shapes:
            wp.launch(_shape_poses, dim=self._map.shape, device=b.device,
                      inputs=[self._map, self.model.shape_body, self.model.shape_transform, body_q, target])
        if b.motion_blur and not self._updates:
            wp.copy(b.shape_poses, target)
        self._updates += 1

    # per-world looks (domain randomisation): shape j of scene.shapes has material "shape{j}", so
    # the batch's material columns 0..S-1 are the shapes' (S is the last, warprt's default)
    def _per_shape(self, values, current: "wp.array") -> np.ndarray:
        S = len(self.scene.shapes)
        full = current.numpy().copy()
        a = np.asarray(values)
        full[:, :S] = np.broadcast_to(a, full[:, :S].shape) if a.shape != full[:, :S].shape else a
        return full

    def set_shape_colors(self, colors) -> None:
        """Each world's linear RGB colour of each rendered shape, (W, S, 3) (S = len(scene.shapes);
        broadcast: (S, 3) for every world alike). sRGB colours: ``warprt.srgb_to_linear`` first."""
        b = self.batch
        try:
            full = self._per_shape(np.asarray(colors, np.float64), b.material_colors)
        except ValueError:
            raise RenderError(f"shape colors: expected ({b.worlds}, {len(self.scene.shapes)}, 3) values, got "
                              f"{np.shape(colors)}") from None
        b.set_material_colors(full)

    def set_shape_textures(self, indices) -> None:
        """Each world's texture of each rendered shape, (W, S) indices into ``textures`` (-1: none).
        Newton's shapes other than meshes with UVs have no texture coordinates: give their
        textures ``projection="triplanar"`` or ``"cubic"``."""
        b = self.batch
        try:
            full = self._per_shape(np.asarray(indices), b.material_textures)
        except ValueError:
            raise RenderError(f"shape textures: expected ({b.worlds}, {len(self.scene.shapes)}) indices, got "
                              f"{np.shape(indices)}") from None
        b.set_material_textures(full)

    @property
    def textures(self) -> list:
        """The textures ``set_shape_textures`` indexes (see :attr:`warprt.BatchRenderer.textures`)."""
        return self.batch.textures

    def add_texture(self, texture) -> int:
        """Add a texture and return its index (see :meth:`warprt.BatchRenderer.add_texture`)."""
        return self.batch.add_texture(texture)

    def set_light_intensities(self, intensities) -> None:
        """(W, L, 3) intensities of the point and directional lights (see
        :meth:`warprt.BatchRenderer.set_light_intensities`)."""
        self.batch.set_light_intensities(intensities)

    def set_camera_poses(self, poses, end=None) -> None:
        """(W, C) camera-to-world poses (see :meth:`warprt.BatchRenderer.set_camera_poses`)."""
        self.batch.set_camera_poses(poses, end)

    def render(self, spp: int | None = None, seed: int = 0, aovs=()):
        """Every world and camera (:meth:`warprt.BatchRenderer.render`); give each simulation step
        its own ``seed`` for independent sampling and depth-sensor noise from frame to frame."""
        return self.batch.render(spp=spp or self.scene.render.spp, seed=seed, aovs=aovs)


def look_at_pose(eye, target, up="z") -> np.ndarray:
    """:func:`warprt.look_at` with Newton's default up axis, z (for a model of another up axis
    give ``up=renderer.up_axis``)."""
    return look_at(eye, target, up)
