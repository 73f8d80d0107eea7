"""Build: turn a :class:`Scene` into device tables and the :class:`Features` it uses.

* Analytic spheres, planes, rectangles and disks stay analytic (exact normals, exact light
  sampling) in struct-of-array tables.
* Each mesh *asset* (a file, or one set of inline arrays) becomes one ``wp.Mesh`` in object
  space; every mesh shape is an *instance* of an asset with a transform at time 0 and time 1, so
  moving or re-posing a mesh never rebuilds its BVH.
* Area lights add their emitting shape to the tables (so camera rays see them) and a light entry
  that points at it.
* ``Features`` records which kernel code the scene needs; the integrator compiles one kernel per
  distinct ``Features`` value.
"""

from __future__ import annotations

import hashlib
import math
import os
import threading
import warnings
from dataclasses import dataclass, fields

import numpy as np
import warp as wp

from .errors import SceneError
from .sampling import SAMPLER_IDS
from .scene.description import (
    Disk, DiskLight, Material, Mesh, Plane, PointLight, Rectangle, RectLight, Scene, Sphere, SphereLight,
    Transform, _validate_arrays,
)


# shape kinds, as reported by ray queries and id AOVs
KIND_NONE, KIND_SPHERE, KIND_PLANE, KIND_RECT, KIND_DISK, KIND_MESH = -1, 0, 1, 2, 3, 4
LIGHT_RECT, LIGHT_SPHERE, LIGHT_DISK = 0, 1, 2
FRESNEL_IDS = {"none": 0, "schlick": 1, "exact": 2}
SPHERE_BVH_MIN = 16  # from this many spheres on, rays find them through a BVH instead of a loop


@dataclass(frozen=True)
class Features:
    """What a scene uses; each flag adds code to the render kernel."""

    meshes: bool = False  # triangle meshes (wp.Mesh BVH queries)
    area_lights: bool = False  # rectangle / sphere / disk emitters and soft shadows
    secondary: bool = False  # mirror reflection or refraction: rays spawned at hits
    refraction: bool = False  # transparent materials (refraction, TIR, Fresnel, coloured shadows)
    glossy: bool = False  # glossy reflection or frosted refraction lobes
    lens: bool = False  # thin-lens depth of field
    motion: bool = False  # moving objects or camera (motion blur)

    @classmethod
    def full(cls) -> "Features":
        return cls(**{f.name: True for f in fields(cls)})

    def union(self, other: "Features") -> "Features":
        return Features(**{f.name: getattr(self, f.name) or getattr(other, f.name) for f in fields(self)})

    @property
    def key(self) -> str:
        on = [f.name for f in fields(self) if getattr(self, f.name)]
        return "+".join(on) if on else "basic"


@wp.struct
class SphereRec:
    c0: wp.vec3  # centre at time 0
    c1: wp.vec3  # centre at time 1
    r: float
    mat: int


@wp.struct
class PlaneRec:
    p: wp.vec3
    n: wp.vec3  # unit normal
    mat: int


@wp.struct
class RectRec:
    c: wp.vec3  # corner
    e1: wp.vec3
    e2: wp.vec3
    n: wp.vec3  # unit normal, along e1 x e2
    mat: int


@wp.struct
class DiskRec:
    c: wp.vec3
    n: wp.vec3  # unit normal
    r: float
    mat: int


@wp.struct
class InstRec:
    mesh: wp.uint64  # wp.Mesh id of the asset
    pos0: wp.vec3  # pose at time 0: translation, rotation, scale
    rot0: wp.quat
    scl0: wp.vec3
    pos1: wp.vec3  # pose at time 1
    rot1: wp.quat
    scl1: wp.vec3
    mat: int
    smooth: int
    nrm_off: int  # first vertex normal of the asset in SceneData.normals


@wp.struct
class MatRec:
    ka: wp.vec3
    kd: wp.vec3
    ks: wp.vec3
    p: float
    km: wp.vec3
    kt: wp.vec3
    ior: float
    fresnel: int
    gloss: float
    frost: float
    emit: wp.vec3  # emitted radiance (area lights' own shapes)


@wp.struct
class PointLightRec:
    pos: wp.vec3
    intensity: wp.vec3  # I
    inv_sq: int  # 1: inverse-square falloff


@wp.struct
class AreaLightRec:
    kind: int  # LIGHT_RECT / LIGHT_SPHERE / LIGHT_DISK
    shape: int  # index into the rect / sphere / disk table
    le: wp.vec3  # radiance
    samples: int


@wp.struct
class SceneData:
    """Every table as an array of records. Warp passes structs to device functions by value, so
    this struct is kept small: a dozen array headers, not one per field."""

    n_spheres: int
    spheres: wp.array(dtype=SphereRec)
    sph_bvh: wp.uint64  # BVH over the spheres' (swept) bounds, 0 when they are few
    n_planes: int
    planes: wp.array(dtype=PlaneRec)
    n_rects: int
    rects: wp.array(dtype=RectRec)
    n_disks: int
    disks: wp.array(dtype=DiskRec)
    n_inst: int
    insts: wp.array(dtype=InstRec)
    normals: wp.array(dtype=wp.vec3)
    mats: wp.array(dtype=MatRec)
    n_plights: int
    plights: wp.array(dtype=PointLightRec)
    n_alights: int
    alights: wp.array(dtype=AreaLightRec)
    ambient: wp.vec3
    background: wp.vec3


def _table(struct, rows: list[dict], device) -> "wp.array":
    """An array of ``struct`` records from dicts of field values (one zero record when empty)."""
    data = np.zeros(max(len(rows), 1), dtype=struct.numpy_dtype())
    for name in data.dtype.names:
        if rows:
            data[name] = [row[name] for row in rows]
    return wp.array(data, dtype=struct, device=device)


@wp.struct
class CameraData:
    eye0: wp.vec3
    eye1: wp.vec3
    look0: wp.vec3
    look1: wp.vec3
    up: wp.vec3
    top: float  # half height of the image plane at distance D
    right: float  # half width
    dist: float  # D
    lens_radius: float
    focus: float
    t_open: float
    t_close: float
    width: int
    height: int


@wp.struct
class RenderParams:
    spp: int  # planned samples per pixel (strata count)
    sampler: int
    seed: wp.uint32
    max_depth: int
    min_weight: float
    t_min: float
    t_max: float
    clamp: float
    moving: int  # 1 when something in the scene moves: sample time (runtime guard for general kernels)


# --- mesh assets ------------------------------------------------------------------------------

_asset_cache: dict[tuple, tuple[np.ndarray, np.ndarray]] = {}
_asset_lock = threading.Lock()


def _read_mesh_file(path: str) -> tuple[np.ndarray, np.ndarray]:
    try:
        st = os.stat(path)
    except OSError:
        raise SceneError(f"mesh file not found: {path!r}", "file") from None
    key = (path, st.st_mtime_ns, st.st_size)
    with _asset_lock:
        if key in _asset_cache:
            return _asset_cache[key]
    import trimesh

    try:
        loaded = trimesh.load(path, force="mesh", process=False)
    except Exception as e:  # trimesh raises many types for unreadable files
        raise SceneError(f"cannot read mesh file {os.path.basename(path)!r}: {e}", "file") from None
    v = np.asarray(getattr(loaded, "vertices", np.zeros((0, 3))), dtype=np.float64)
    f = np.asarray(getattr(loaded, "faces", np.zeros((0, 3))), dtype=np.int64)
    if len(v) == 0 or len(f) == 0:
        raise SceneError(f"mesh file {os.path.basename(path)!r} holds no triangles", "file")
    with _asset_lock:
        _asset_cache[key] = (v, f)
    return v, f


def prepare_mesh(v: np.ndarray, f: np.ndarray, degenerate: str = "error") -> tuple[np.ndarray, np.ndarray]:
    """Check a triangle mesh and return float32 vertices and int32 faces.

    NaN/Inf vertices, out-of-range indices and empty meshes raise; zero-area faces raise unless
    ``degenerate="drop"``, which removes them (with a warning).
    """
    v, f = _validate_arrays(v, f)
    a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    area2 = np.linalg.norm(np.cross(b - a, c - a), axis=1)
    edge = np.maximum(np.maximum(np.linalg.norm(b - a, axis=1), np.linalg.norm(c - a, axis=1)),
                      np.linalg.norm(c - b, axis=1))
    bad = (area2 <= 1e-12 * edge * edge) | (f[:, 0] == f[:, 1]) | (f[:, 1] == f[:, 2]) | (f[:, 0] == f[:, 2])
    if bad.any():
        if degenerate == "error":
            raise SceneError(
                f"{int(bad.sum())} of {len(f)} faces have zero area (first: face {int(np.argmax(bad))}); "
                "fix the mesh or set degenerate = \"drop\"", "faces")
        warnings.warn(f"dropping {int(bad.sum())} zero-area faces of {len(f)}", stacklevel=3)
        f = f[~bad]
        if len(f) == 0:
            raise SceneError("every face has zero area: nothing is left to render", "faces")
    v32 = v.astype(np.float32)
    return v32, f.astype(np.int32)


def vertex_normals(v: np.ndarray, f: np.ndarray) -> np.ndarray:
    """Area-weighted vertex normals (unit; a vertex with no area gets +z)."""
    fn = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]]).astype(np.float64)
    n = np.zeros((len(v), 3))
    for k in range(3):
        np.add.at(n, f[:, k], fn)
    length = np.linalg.norm(n, axis=1, keepdims=True)
    out = np.where(length > 0, n / np.where(length > 0, length, 1), np.array([0.0, 0.0, 1.0]))
    return out.astype(np.float32)


# --- the device scene -------------------------------------------------------------------------


class DeviceScene:
    """A scene's tables on one device. Keeps every ``wp.Mesh`` alive while its id is in use."""

    def __init__(self, scene: Scene, device: "wp.context.Device", assets: dict | None = None):
        self.scene = scene
        self.device = device
        # mesh assets by key: (wp.Mesh, vertex normals); a previous DeviceScene's assets can be
        # passed in so that re-posed or re-lit frames never rebuild a BVH
        self.assets: dict[tuple, tuple] = dict(assets or {})
        try:
            self._build()
        except SceneError as e:
            raise e.within(source=scene.source) from None

    # the tables are built in numpy lists, then copied once to the device
    def _build(self) -> None:
        scene, dev = self.scene, self.device
        mat_index: dict[str, int] = {}
        mats: list[tuple[Material, tuple]] = []
        for name, m in scene.materials.items():
            mat_index[name] = len(mats)
            mats.append((m, (0.0, 0.0, 0.0)))

        def emitter_material(le) -> int:
            mats.append((Material(kd=0.0, ka=0.0), tuple(le)))
            return len(mats) - 1

        sph, pln, rct, dsk, ins = [], [], [], [], []
        self.meshes: list[wp.Mesh] = []
        asset_ids: dict[object, int] = {}
        normals: list[np.ndarray] = []
        nrm_offsets: list[int] = []
        n_normals = 0
        self.instance_assets: list[tuple] = []  # asset key of each mesh instance
        shape_ids: list[tuple[int, int]] = []  # (kind, index in its table) for each scene shape
        features = dict(meshes=False, area_lights=False, secondary=False, refraction=False,
                        glossy=False, lens=scene.camera.aperture > 0.0, motion=scene.camera.moves)

        for i, s in enumerate(scene.shapes):
            where = f"shapes[{i}]"
            mi = mat_index[s.material]
            try:
                if isinstance(s, Sphere):
                    c0, c1, r = s.world()
                    shape_ids.append((KIND_SPHERE, len(sph)))
                    sph.append((c0, c1, r, mi))
                    features["motion"] |= c0 != c1
                elif isinstance(s, Plane):
                    p, n = s.world()
                    shape_ids.append((KIND_PLANE, len(pln)))
                    pln.append((p, n, mi))
                elif isinstance(s, Rectangle):
                    c, e1, e2 = s.world()
                    shape_ids.append((KIND_RECT, len(rct)))
                    rct.append((c, e1, e2, mi))
                elif isinstance(s, Disk):
                    shape_ids.append((KIND_DISK, len(dsk)))
                    dsk.append((s.center, _unit(s.normal), s.radius, mi))
                elif isinstance(s, Mesh):
                    key = _asset_key(s)
                    if key not in asset_ids:
                        if key not in self.assets:
                            v, f = _read_mesh_file(s.file) if s.file is not None else (s.vertices, s.faces)
                            v32, f32 = prepare_mesh(v, f, s.degenerate)
                            mesh = wp.Mesh(points=wp.array(v32, dtype=wp.vec3, device=dev),
                                           indices=wp.array(f32.reshape(-1), dtype=wp.int32, device=dev))
                            self.assets[key] = (mesh, vertex_normals(v32, f32))
                        mesh, vn = self.assets[key]
                        asset_ids[key] = len(self.meshes)
                        self.meshes.append(mesh)
                        normals.append(vn)
                        nrm_offsets.append(n_normals)
                        n_normals += len(vn)
                    a = asset_ids[key]
                    t0 = s.transform or Transform()
                    t1 = s.transform_end or t0
                    shape_ids.append((KIND_MESH, len(ins)))
                    self.instance_assets.append(key)
                    ins.append((self.meshes[a].id, t0, t1, mi, int(s.smooth), nrm_offsets[a]))
                    features["meshes"] = True
                    features["motion"] |= s.moves
            except SceneError as e:
                raise e.within(where) from None

        alights = []
        for j, light in enumerate(scene.lights):
            if isinstance(light, RectLight):
                alights.append((LIGHT_RECT, len(rct), light.radiance, light.samples))
                rct.append((light.corner, light.edge1, light.edge2, emitter_material(light.radiance)))
            elif isinstance(light, SphereLight):
                alights.append((LIGHT_SPHERE, len(sph), light.radiance, light.samples))
                sph.append((light.center, light.center, light.radius, emitter_material(light.radiance)))
            elif isinstance(light, DiskLight):
                alights.append((LIGHT_DISK, len(dsk), light.radiance, light.samples))
                dsk.append((light.center, _unit(light.normal), light.radius, emitter_material(light.radiance)))
        self.normal_offsets = dict(zip(asset_ids, nrm_offsets))
        features["area_lights"] = bool(alights)
        self.area_lights = alights  # (light kind, row in its shape table, radiance, samples)
        plights = [l for l in scene.lights if isinstance(l, PointLight)]

        used = {s.material for s in scene.shapes}
        for name in used:
            m = scene.materials[name]
            features["secondary"] |= m.reflects or m.refracts
            features["refraction"] |= m.refracts
            features["glossy"] |= m.glossy
        self.features = Features(**features)
        self.shape_ids = shape_ids

        # --- copy to the device
        d = SceneData()
        d.n_spheres = len(sph)
        d.spheres = _table(SphereRec, [dict(c0=c0, c1=c1, r=r, mat=m) for c0, c1, r, m in sph], dev)
        d.n_planes = len(pln)
        d.planes = _table(PlaneRec, [dict(p=p, n=n, mat=m) for p, n, m in pln], dev)
        d.n_rects = len(rct)
        d.rects = _table(RectRec, [dict(c=c, e1=e1, e2=e2, n=_unit(np.cross(e1, e2)), mat=m) for c, e1, e2, m in rct], dev)
        d.n_disks = len(dsk)
        d.disks = _table(DiskRec, [dict(c=c, n=n, r=r, mat=m) for c, n, r, m in dsk], dev)
        d.n_inst = len(ins)
        d.insts = _table(InstRec, [dict(mesh=mid, pos0=t0.translate, rot0=t0.quaternion(), scl0=t0.scale,
                                        pos1=t1.translate, rot1=_same_hemisphere(t1.quaternion(), t0.quaternion()),
                                        scl1=t1.scale, mat=m, smooth=sm, nrm_off=off)
                                   for mid, t0, t1, m, sm, off in ins], dev)
        d.normals = wp.array(np.concatenate(normals) if normals else np.zeros((1, 3), np.float32),
                             dtype=wp.vec3, device=dev)
        d.mats = _table(MatRec, [dict(ka=m.ka, kd=m.kd, ks=m.ks, p=m.p, km=m.mirror, kt=m.transparency, ior=m.ior,
                                      fresnel=FRESNEL_IDS[m.fresnel], gloss=m.glossy_exponent,
                                      frost=m.frosted_exponent, emit=le) for m, le in mats], dev)
        d.n_plights = len(plights)
        d.plights = _table(PointLightRec, [dict(pos=l.position, intensity=l.intensity,
                                                inv_sq=int(l.falloff == "inverse_square")) for l in plights], dev)
        d.n_alights = len(alights)
        d.alights = _table(AreaLightRec, [dict(kind=k, shape=i, le=le, samples=n) for k, i, le, n in alights], dev)
        d.ambient = wp.vec3(*scene.ambient)
        d.background = wp.vec3(*scene.background)
        self._sphere_bvh(d, sph)
        self.data = d
        self.camera = camera_data(scene)


    def set_mesh_points(self, shape_index: int, points) -> None:
        """Move the vertices of the mesh asset behind ``scene.shapes[shape_index]`` (every
        instance of that asset follows) and refit its BVH; smooth normals are recomputed."""
        from .animation import as_points

        kind, row = self.shape_ids[shape_index]
        if kind != KIND_MESH:
            raise SceneError(f"shape {shape_index} is not a mesh", f"shapes[{shape_index}]")
        key = self.instance_assets[row]
        mesh, _ = self.assets[key]
        p = as_points(points, mesh.points.shape[0], self.device)
        if isinstance(p, wp.array):
            wp.copy(mesh.points, p)
        else:
            mesh.points.assign(p)
        mesh.refit()
        if any(isinstance(s, Mesh) and s.smooth for s in self.scene.shapes):
            faces = mesh.indices.numpy().reshape(-1, 3)
            vn = vertex_normals(mesh.points.numpy(), faces)
            self.assets[key] = (mesh, vn)
            off = self.normal_offsets[key]
            all_n = self.data.normals.numpy()
            all_n[off:off + len(vn)] = vn
            self.data.normals.assign(all_n)

    def _sphere_bvh(self, d: SceneData, sph: list) -> None:
        """From SPHERE_BVH_MIN spheres on, a wp.Bvh over their bounds (swept over the motion)."""
        dev = self.device
        self.sphere_bvh = None
        d.sph_bvh = wp.uint64(0)
        if len(sph) >= SPHERE_BVH_MIN:
            c0 = np.array([s[0] for s in sph], dtype=np.float64)
            c1 = np.array([s[1] for s in sph], dtype=np.float64)
            r = np.array([s[2] for s in sph], dtype=np.float64)[:, None]
            pad = r * 1e-6 + np.maximum(np.abs(c0), np.abs(c1)).max(axis=1, keepdims=True) * 1e-6
            lowers = (np.minimum(c0, c1) - r - pad).astype(np.float32)
            uppers = (np.maximum(c0, c1) + r + pad).astype(np.float32)
            self.sphere_bvh = wp.Bvh(wp.array(lowers, dtype=wp.vec3, device=dev),
                                     wp.array(uppers, dtype=wp.vec3, device=dev))
            d.sph_bvh = wp.uint64(self.sphere_bvh.id)


def _asset_key(m: Mesh) -> tuple:
    """Meshes with the same file, or the same inline arrays (by content), share one asset."""
    if m.file is not None:
        return ("file", m.file, m.degenerate)
    h = hashlib.blake2b(digest_size=16)
    for a in (m.vertices, m.faces):
        h.update(str(a.shape).encode())
        h.update(np.ascontiguousarray(a).tobytes())
    return ("arrays", h.hexdigest(), m.degenerate)


def _unit(v) -> tuple[float, float, float]:
    v = np.asarray(v, dtype=np.float64)
    return tuple(float(c) for c in v / np.linalg.norm(v))  # type: ignore[return-value]


def _same_hemisphere(q: np.ndarray, ref: np.ndarray) -> np.ndarray:
    """q or -q, whichever is nearer ref (so slerp takes the short way round)."""
    return -q if float(np.dot(q, ref)) < 0.0 else q


def camera_data(scene: Scene) -> CameraData:
    cam = scene.camera
    c = CameraData()
    eye1, look1 = cam.pose(1.0)
    c.eye0, c.eye1 = wp.vec3(*cam.eye), wp.vec3(*eye1)
    c.look0, c.look1 = wp.vec3(*cam.look_at), wp.vec3(*look1)
    c.up = wp.vec3(*cam.up)
    c.top = cam.distance * math.tan(math.radians(cam.fov) / 2.0)
    c.right = c.top * cam.aspect
    c.dist = cam.distance
    c.lens_radius = cam.aperture
    c.focus = cam.focus
    c.t_open, c.t_close = cam.shutter
    c.width, c.height = cam.width, cam.height
    return c


def render_params(scene: Scene, spp: int, seed: int, features: Features | None = None) -> RenderParams:
    s = scene.render
    p = RenderParams()
    p.spp = spp
    p.sampler = SAMPLER_IDS[s.sampler]
    p.seed = wp.uint32(seed & 0xFFFFFFFF)
    p.max_depth = s.max_depth
    p.min_weight = s.min_weight
    p.t_min = s.t_min
    p.t_max = s.t_max if math.isfinite(s.t_max) else 3.0e38
    p.clamp = s.clamp
    p.moving = int(features.motion) if features is not None else 1
    return p
