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

from . import _warp
from .errors import SceneError
from .sampling import SAMPLER_IDS
from .scene.description import (
    Disk, DiskLight, Material, Mesh, Plane, PointLight, Rectangle, RectLight, Scene, Sphere, SphereLight,
    Transform, _validate_arrays,
)

_warp.init()

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
class SceneData:
    n_spheres: int
    sph_c0: wp.array(dtype=wp.vec3)
    sph_c1: wp.array(dtype=wp.vec3)
    sph_r: wp.array(dtype=float)
    sph_mat: wp.array(dtype=int)
    sph_bvh: wp.uint64  # BVH over the spheres' (swept) bounds, 0 when they are few

    n_planes: int
    pln_p: wp.array(dtype=wp.vec3)
    pln_n: wp.array(dtype=wp.vec3)
    pln_mat: wp.array(dtype=int)

    n_rects: int
    rct_c: wp.array(dtype=wp.vec3)
    rct_e1: wp.array(dtype=wp.vec3)
    rct_e2: wp.array(dtype=wp.vec3)
    rct_n: wp.array(dtype=wp.vec3)
    rct_mat: wp.array(dtype=int)

    n_disks: int
    dsk_c: wp.array(dtype=wp.vec3)
    dsk_n: wp.array(dtype=wp.vec3)
    dsk_r: wp.array(dtype=float)
    dsk_mat: wp.array(dtype=int)

    n_inst: int
    ins_mesh: wp.array(dtype=wp.uint64)
    ins_pos0: wp.array(dtype=wp.vec3)
    ins_rot0: wp.array(dtype=wp.quat)
    ins_scl0: wp.array(dtype=wp.vec3)
    ins_pos1: wp.array(dtype=wp.vec3)
    ins_rot1: wp.array(dtype=wp.quat)
    ins_scl1: wp.array(dtype=wp.vec3)
    ins_mat: wp.array(dtype=int)
    ins_smooth: wp.array(dtype=int)
    ins_nrm_off: wp.array(dtype=int)  # first vertex normal of the instance's asset in ``normals``
    normals: wp.array(dtype=wp.vec3)

    mat_ka: wp.array(dtype=wp.vec3)
    mat_kd: wp.array(dtype=wp.vec3)
    mat_ks: wp.array(dtype=wp.vec3)
    mat_p: wp.array(dtype=float)
    mat_km: wp.array(dtype=wp.vec3)
    mat_kt: wp.array(dtype=wp.vec3)
    mat_ior: wp.array(dtype=float)
    mat_fresnel: wp.array(dtype=int)
    mat_gloss: wp.array(dtype=float)
    mat_frost: wp.array(dtype=float)
    mat_emit: wp.array(dtype=wp.vec3)  # emitted radiance (area lights' shapes)

    n_plights: int
    plt_pos: wp.array(dtype=wp.vec3)
    plt_int: wp.array(dtype=wp.vec3)
    plt_inv_sq: wp.array(dtype=int)

    n_alights: int
    alt_kind: wp.array(dtype=int)
    alt_shape: wp.array(dtype=int)  # index into the rect / sphere / disk tables
    alt_le: wp.array(dtype=wp.vec3)
    alt_samples: wp.array(dtype=int)

    ambient: wp.vec3
    background: wp.vec3


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

    def __init__(self, scene: Scene, device: "wp.context.Device"):
        self.scene = scene
        self.device = device
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
                        v, f = _read_mesh_file(s.file) if s.file is not None else (s.vertices, s.faces)
                        v32, f32 = prepare_mesh(v, f, s.degenerate)
                        asset_ids[key] = len(self.meshes)
                        self.meshes.append(wp.Mesh(points=wp.array(v32, dtype=wp.vec3, device=dev),
                                                   indices=wp.array(f32.reshape(-1), dtype=wp.int32, device=dev)))
                        normals.append(vertex_normals(v32, f32))
                        nrm_offsets.append(n_normals)
                        n_normals += len(v32)
                    a = asset_ids[key]
                    t0 = s.transform or Transform()
                    t1 = s.transform_end or t0
                    shape_ids.append((KIND_MESH, len(ins)))
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
        features["area_lights"] = bool(alights)
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
        def arr(rows, dtype, default):
            data = rows if rows else [default]
            return wp.array(np.asarray(data, dtype=np.float32 if dtype not in (int, wp.uint64) else None),
                            dtype=dtype, device=dev)

        d = SceneData()
        z3 = (0.0, 0.0, 0.0)
        d.n_spheres = len(sph)
        d.sph_c0 = arr([s[0] for s in sph], wp.vec3, z3)
        d.sph_c1 = arr([s[1] for s in sph], wp.vec3, z3)
        d.sph_r = arr([s[2] for s in sph], float, 0.0)
        d.sph_mat = wp.array([s[3] for s in sph] or [0], dtype=int, device=dev)
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
        d.n_planes = len(pln)
        d.pln_p = arr([p[0] for p in pln], wp.vec3, z3)
        d.pln_n = arr([p[1] for p in pln], wp.vec3, z3)
        d.pln_mat = wp.array([p[2] for p in pln] or [0], dtype=int, device=dev)
        d.n_rects = len(rct)
        d.rct_c = arr([r[0] for r in rct], wp.vec3, z3)
        d.rct_e1 = arr([r[1] for r in rct], wp.vec3, z3)
        d.rct_e2 = arr([r[2] for r in rct], wp.vec3, z3)
        d.rct_n = arr([_unit(np.cross(r[1], r[2])) for r in rct], wp.vec3, z3)
        d.rct_mat = wp.array([r[3] for r in rct] or [0], dtype=int, device=dev)
        d.n_disks = len(dsk)
        d.dsk_c = arr([k[0] for k in dsk], wp.vec3, z3)
        d.dsk_n = arr([k[1] for k in dsk], wp.vec3, z3)
        d.dsk_r = arr([k[2] for k in dsk], float, 0.0)
        d.dsk_mat = wp.array([k[3] for k in dsk] or [0], dtype=int, device=dev)

        d.n_inst = len(ins)
        d.ins_mesh = wp.array([x[0] for x in ins] or [0], dtype=wp.uint64, device=dev)
        d.ins_pos0 = arr([x[1].translate for x in ins], wp.vec3, z3)
        d.ins_rot0 = arr([x[1].quaternion() for x in ins], wp.quat, (0.0, 0.0, 0.0, 1.0))
        d.ins_scl0 = arr([x[1].scale for x in ins], wp.vec3, (1.0, 1.0, 1.0))
        d.ins_pos1 = arr([x[2].translate for x in ins], wp.vec3, z3)
        d.ins_rot1 = arr([_same_hemisphere(x[2].quaternion(), x[1].quaternion()) for x in ins], wp.quat,
                         (0.0, 0.0, 0.0, 1.0))
        d.ins_scl1 = arr([x[2].scale for x in ins], wp.vec3, (1.0, 1.0, 1.0))
        d.ins_mat = wp.array([x[3] for x in ins] or [0], dtype=int, device=dev)
        d.ins_smooth = wp.array([x[4] for x in ins] or [0], dtype=int, device=dev)
        d.ins_nrm_off = wp.array([x[5] for x in ins] or [0], dtype=int, device=dev)
        d.normals = wp.array(np.concatenate(normals) if normals else np.zeros((1, 3), np.float32),
                             dtype=wp.vec3, device=dev)

        d.mat_ka = arr([m.ka for m, _ in mats], wp.vec3, z3)
        d.mat_kd = arr([m.kd for m, _ in mats], wp.vec3, z3)
        d.mat_ks = arr([m.ks for m, _ in mats], wp.vec3, z3)
        d.mat_p = arr([m.p for m, _ in mats], float, 0.0)
        d.mat_km = arr([m.mirror for m, _ in mats], wp.vec3, z3)
        d.mat_kt = arr([m.transparency for m, _ in mats], wp.vec3, z3)
        d.mat_ior = arr([m.ior for m, _ in mats], float, 1.0)
        d.mat_fresnel = wp.array([FRESNEL_IDS[m.fresnel] for m, _ in mats], dtype=int, device=dev)
        d.mat_gloss = arr([m.glossy_exponent for m, _ in mats], float, 0.0)
        d.mat_frost = arr([m.frosted_exponent for m, _ in mats], float, 0.0)
        d.mat_emit = arr([le for _, le in mats], wp.vec3, z3)

        d.n_plights = len(plights)
        d.plt_pos = arr([l.position for l in plights], wp.vec3, z3)
        d.plt_int = arr([l.intensity for l in plights], wp.vec3, z3)
        d.plt_inv_sq = wp.array([int(l.falloff == "inverse_square") for l in plights] or [0], dtype=int, device=dev)
        d.n_alights = len(alights)
        d.alt_kind = wp.array([a[0] for a in alights] or [0], dtype=int, device=dev)
        d.alt_shape = wp.array([a[1] for a in alights] or [0], dtype=int, device=dev)
        d.alt_le = arr([a[2] for a in alights], wp.vec3, z3)
        d.alt_samples = wp.array([a[3] for a in alights] or [1], dtype=int, device=dev)
        d.ambient = wp.vec3(*scene.ambient)
        d.background = wp.vec3(*scene.background)
        self.data = d
        self.camera = camera_data(scene)


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


def render_params(scene: Scene, spp: int, seed: int) -> RenderParams:
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
    return p
