"""warprt scenes as Mitsuba 3 scenes with the same physics, and what Mitsuba needs to render them.

Used by the six-scene side by side (``benchmarks.peers``) and the corpus (``benchmarks.corpus``).

``to_mitsuba(scene, mi)`` turns a ``warprt.Scene`` into a Mitsuba scene dict, or raises
``ExportError`` naming what has no equal counterpart. What exports, and as what:

* camera: ``perspective`` (``thinlens`` with an aperture; both focus on a plane) with the
  vertical field of view, a box pixel filter, no border samples;
* materials: Lambert (kd only) as ``twosided(diffuse)``, a bitmap ``texture`` by uv as its
  ``bitmap`` reflectance (``bitmap``: the same linear texels, bilinear, flipped to Mitsuba's v); a perfect mirror (kd = ks = kt = 0,
  km > 0, no glossy lobe) as ``twosided(conductor)`` with ``material = "none"`` (F = 1) and
  ``specular_reflectance`` = km; clear glass (kd = ks = km = 0, kt > 0, ``fresnel = "exact"``,
  no frosted lobe) as ``dielectric`` with ``int_ior`` = ior, ``ext_ior`` = 1 (not Mitsuba's
  default, air's 1.000277) and both specular weights kt: warprt's reflected ray carries kt·F and
  the refracted one kt·(1 − F), Mitsuba picks one of the two with probability F and weights it
  kt. Schlick or no Fresnel, Blinn-Phong, mixed diffuse and specular materials and glossy lobes
  have no Mitsuba BSDF with the same weights: they raise;
* shapes: spheres, rectangles, disks and planes (a square of half side ``plane_half``, 100, or
  1e4 under a directional light: Mitsuba has no infinite plane, ``plane_beyond_extent`` bounds
  what that changes) as Mitsuba's analytic
  shapes; boxes as ``cube`` (a 12-triangle mesh, the same box); cylinders as Mitsuba's open
  ``cylinder`` and two ``disk`` caps; capsules as the cylinder and two ``sphere`` ends (the ends'
  inner halves lie inside the closed tube, where no ray reaches); meshes as flat-shaded ``ply``
  files (``face_normals``) placed by ``to_world`` = ``Transform.matrix()`` (scale, rotate,
  translate; Mitsuba transforms normals by the inverse transpose, so non-uniform scales shade
  the same), meshes sharing one asset and material as one ``shapegroup`` with an ``instance``
  each;
* lights: inverse-square point lights (warprt's I/π is Mitsuba's I: warprt's point light has no
  1/π), directional lights (``irradiance`` = π·I for the same reason), rectangle, sphere and disk
  lights as ``area`` emitters on their shape with a black BSDF (one-sided like warprt's: the
  emitting side is the shape's normal side; a sphere emits outwards);
* integrator: Mitsuba's ``direct`` (one emitter sample, no BSDF sample) where no material
  mirrors or refracts, else ``whitted`` (``WhittedIntegrator`` below, the same direct light at
  non-specular hits plus the specular recursion to ``max_depth``, and shadow rays through
  transparent surfaces with kt per crossing, as warprt's).

Motion has no Mitsuba counterpart: Mitsuba 3 has no animated transforms (shapes and sensors take
one ``to_world``), so a moving scene raises, and ``scene_at_time`` gives the still scene at one
time of the shutter: the average of still renders at stratified times is an unbiased estimate of
the motion-blurred image (what ``benchmarks.corpus`` takes as such scenes' reference).
"""

from __future__ import annotations

import glob
import hashlib
import math
import os
import re
import subprocess
from dataclasses import fields, is_dataclass, replace
from pathlib import Path

import numpy as np

import warprt

ROOT = Path(__file__).resolve().parents[1]
GROUND_HALF = 100.0  # half side of the square that stands in for an infinite plane
# ... under a directional light, whose light does not fall off: the plane beyond 100 units lights
# the pixels along the horizon. 1e4 renders the same as 100 within float round-off on the
# corpus's grounds (1e5 does not: Mitsuba's float32 rectangle loses the contact shadows' detail)
SUN_GROUND_HALF = 1e4


def ground_half(scene) -> float:
    """Half side of the square that stands in for a Plane in Mitsuba."""
    return SUN_GROUND_HALF if any(isinstance(x, warprt.DirectionalLight) for x in scene.lights) else GROUND_HALF
MESH_DIR = ROOT / ".cache" / "peers" / "meshes"


class ExportError(ValueError):
    pass


# --- scene content ------------------------------------------------------------------------------


def scene_digest(obj, h=None) -> str:
    """A digest of a scene's content (dataclass fields, arrays by their bytes): the same for two
    scenes that render the same image, whatever object identity."""
    top = h is None
    h = h or hashlib.blake2b(digest_size=12)
    if is_dataclass(obj) and not isinstance(obj, type):
        h.update(type(obj).__name__.encode())
        for f in fields(obj):
            if f.name == "source":
                continue
            h.update(f.name.encode())
            scene_digest(getattr(obj, f.name), h)
    elif isinstance(obj, np.ndarray):
        a = np.ascontiguousarray(obj)
        h.update(str((a.dtype.str, a.shape)).encode())
        h.update(a.tobytes())
    elif isinstance(obj, dict):
        for k in sorted(obj):
            h.update(repr(k).encode())
            scene_digest(obj[k], h)
    elif isinstance(obj, (list, tuple)):
        h.update(f"seq{len(obj)}".encode())
        for x in obj:
            scene_digest(x, h)
    else:
        h.update(repr(obj).encode())
    return h.hexdigest() if top else ""


# --- motion: the still scene at one time ---------------------------------------------------------


def _slerp(q0, q1, f: float) -> np.ndarray:
    a, b = np.asarray(q0, float), np.asarray(q1, float)
    if np.dot(a, b) < 0:
        b = -b
    d = min(1.0, float(np.dot(a, b)))
    theta = math.acos(d)
    q = a + (b - a) * f if theta < 1e-9 else (math.sin((1 - f) * theta) * a + math.sin(f * theta) * b) / math.sin(theta)
    return q / np.linalg.norm(q)


def _pose_at(t0, t1, f: float):
    """The instance transform at fraction f between poses t0 and t1: translation and scale
    linear, rotation by slerp along the shorter arc (the motion-blur docs' rule)."""
    t0 = t0 or warprt.Transform()
    t1 = t1 or t0
    lerp = [a + (b - a) * f for a, b in zip(t0.translate, t1.translate)]
    scale = [a + (b - a) * f for a, b in zip(t0.scale, t1.scale)]
    return warprt.Transform.from_quaternion(tuple(_slerp(t0.quaternion(), t1.quaternion(), f)), translate=lerp,
                                            scale=scale)


def scene_at_time(scene: warprt.Scene, time: float) -> warprt.Scene:
    """The still scene at ``time`` (poses at 0 and 1 interpolated, or extrapolated beyond):
    camera eye and look_at linear, sphere centres linear, mesh and solid transforms by
    ``_pose_at``."""
    cam = scene.camera
    eye, look = cam.pose(time)
    camera = replace(cam, eye=tuple(eye), look_at=tuple(look), eye_end=None, look_at_end=None)
    shapes = []
    for s in scene.shapes:
        if isinstance(s, warprt.Sphere) and s.center_end is not None:
            c0, c1 = np.asarray(s.center, float), np.asarray(s.center_end, float)
            s = replace(s, center=tuple(c0 + (c1 - c0) * time), center_end=None)
        elif isinstance(s, (warprt.Mesh, warprt.Box, warprt.Capsule, warprt.Cylinder)) and s.moves:
            s = replace(s, transform=_pose_at(s.transform, s.transform_end, time), transform_end=None)
        shapes.append(s)
    return scene.replace(camera=camera, shapes=tuple(shapes))


def moves(scene: warprt.Scene) -> bool:
    return scene.camera.moves or any(
        (isinstance(s, warprt.Sphere) and s.center_end is not None and s.center_end != s.center)
        or (hasattr(s, "moves") and s.moves) for s in scene.shapes)


# --- materials ----------------------------------------------------------------------------------


def _rgb(value):
    v = np.broadcast_to(np.asarray(value, dtype=float), (3,))
    return {"type": "rgb", "value": [float(c) for c in v]}


_BLACK = {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.0, 0.0, 0.0]}}


def material_kind(m: warprt.Material) -> str:
    """"lambert", "mirror" or "glass"; ExportError for what Mitsuba has no BSDF for."""
    if m.specular_texture is not None or m.mirror_texture is not None:
        raise ExportError("specular and mirror textures have no Mitsuba counterpart here (a diffuse bitmap does)")
    t = m.texture
    if t is not None and (t.kind != "bitmap" or t.projection != "uv"):
        raise ExportError(f"a {t.kind} texture projected by {t.projection!r}: only a bitmap by uv exports "
                          "(Mitsuba's bitmap texture)")
    nz = {k: bool(np.any(np.asarray(getattr(m, k), dtype=float) != 0)) for k in ("kd", "ks", "mirror", "transparency")}
    if nz["ks"]:
        raise ExportError("material has ks > 0: Blinn-Phong has no Mitsuba BSDF with the same weights")
    if not nz["mirror"] and not nz["transparency"]:
        return "lambert"
    if nz["kd"]:
        raise ExportError("material mixes kd with a mirror or transparency: no Mitsuba BSDF adds them with "
                          "warprt's fixed weights")
    if nz["mirror"] and nz["transparency"]:
        raise ExportError("material has both mirror and transparency: no Mitsuba BSDF has those weights")
    if nz["mirror"]:
        if m.glossy_exponent > 0:
            raise ExportError("glossy mirrors (glossy_exponent > 0) have no Mitsuba counterpart")
        return "mirror"
    if m.fresnel != "exact":
        raise ExportError(f'glass with fresnel = "{m.fresnel}": only "exact" is what Mitsuba\'s dielectric does')
    if m.frosted_exponent > 0:
        raise ExportError("frosted glass (frosted_exponent > 0) has no Mitsuba counterpart")
    return "glass"


def bsdf(m: warprt.Material) -> dict:
    kind = material_kind(m)
    if kind == "lambert":
        if m.texture is not None:
            return {"type": "twosided", "bsdf": {"type": "diffuse", "reflectance": bitmap(m.texture, m.kd)}}
        return {"type": "twosided", "bsdf": {"type": "diffuse", "reflectance": _rgb(m.kd)}}
    if kind == "mirror":
        return {"type": "twosided", "bsdf": {"type": "conductor", "material": "none",
                                             "specular_reflectance": _rgb(m.mirror)}}
    return {"type": "dielectric", "int_ior": float(m.ior), "ext_ior": 1.0,
            "specular_reflectance": _rgb(m.transparency), "specular_transmittance": _rgb(m.transparency)}


def bitmap(tex, kd) -> dict:
    """A warprt bitmap texture times kd as Mitsuba's ``bitmap`` texture: warprt's decoded linear
    texels (float32, so Mitsuba decodes nothing), bilinear, the same wrap mode, ``to_uv`` scaled
    by the texture's scale. Mitsuba's v runs down the image (row 0 at v = 0), warprt's up (OBJ's
    convention): the rows go in flipped."""
    import mitsuba as mi

    data = np.ascontiguousarray(np.flipud(tex.texels * np.asarray(kd, np.float32)), dtype=np.float32)
    return {"type": "bitmap", "bitmap": mi.Bitmap(data), "raw": True, "filter_type": "bilinear",
            "wrap_mode": tex.wrap, "to_uv": mi.ScalarTransform4f().scale([tex.scale, tex.scale, 1.0])}


# --- frames and files ----------------------------------------------------------------------------


def rect_frame(corner, e1, e2) -> np.ndarray:
    """to_world of Mitsuba's rectangle ([-1, 1]^2 in z = 0, normal +z): columns e1/2, e2/2, the
    unit normal e1 x e2, the centre. The normal column keeps the orientation (one-sided lights)."""
    corner, e1, e2 = (np.asarray(x, dtype=float) for x in (corner, e1, e2))
    n = np.cross(e1, e2)
    n /= np.linalg.norm(n)
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = e1 / 2, e2 / 2, n, corner + (e1 + e2) / 2
    return m


def disk_frame(center, normal, radius) -> np.ndarray:
    """to_world of Mitsuba's disk (unit disk in z = 0, normal +z): radius × tangent, radius ×
    bitangent, the unit normal, the centre; tangent × bitangent = normal, so the disk faces
    ``normal`` (one-sided lights)."""
    n = np.asarray(normal, float)
    n = n / np.linalg.norm(n)
    t = np.cross(n, [1.0, 0.0, 0.0] if abs(n[0]) < 0.9 else [0.0, 1.0, 0.0])
    t /= np.linalg.norm(t)
    b = np.cross(n, t)  # t x b = n
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = radius * t, radius * b, n, np.asarray(center, float)
    return m


def pose_matrix(pos, quat, scale=(1.0, 1.0, 1.0)) -> np.ndarray:
    """T(pos) R(quat (x, y, z, w)) S(scale) as a 4x4 matrix."""
    return warprt.Transform.from_quaternion(tuple(quat), translate=tuple(pos), scale=tuple(scale)).matrix()


def write_ply(path: Path, vertices, faces) -> None:
    v = np.ascontiguousarray(np.asarray(vertices, dtype="<f4"))
    f = np.asarray(faces, dtype="<i4")
    rec = np.empty(len(f), dtype=[("n", "u1"), ("i", "<i4", (3,))])
    rec["n"], rec["i"] = 3, f
    header = (f"ply\nformat binary_little_endian 1.0\nelement vertex {len(v)}\nproperty float x\nproperty float y\n"
              f"property float z\nelement face {len(f)}\nproperty list uchar int vertex_indices\nend_header\n")
    tmp = path.with_name(f"{path.name}.{os.getpid()}.tmp")
    with open(tmp, "wb") as fh:
        fh.write(header.encode("ascii"))
        fh.write(v.tobytes())
        fh.write(rec.tobytes())
    os.replace(tmp, path)


def mesh_file(vertices, faces, mesh_dir: Path) -> str:
    """A ply file of the mesh in ``mesh_dir``, named by its content (written once)."""
    v = np.asarray(vertices, dtype="<f4")
    f = np.asarray(faces, dtype="<i4")
    digest = hashlib.sha1(v.tobytes() + f.tobytes()).hexdigest()[:16]
    path = Path(mesh_dir) / f"mesh-{digest}.ply"
    if not path.exists():
        path.parent.mkdir(parents=True, exist_ok=True)
        write_ply(path, v, f)
    return str(path)


def _mesh_arrays(mesh: warprt.Mesh, base: Path | None):
    if mesh.vertices is not None:
        return np.asarray(mesh.vertices, np.float64), np.asarray(mesh.faces, np.int64)
    import trimesh

    path = Path(mesh.file)
    if not path.is_absolute() and base is not None:
        path = base / path
    tm = trimesh.load(path, force="mesh", process=False)
    return np.asarray(tm.vertices, np.float64), np.asarray(tm.faces, np.int64)


# --- the export -----------------------------------------------------------------------------------


def has_specular(scene: warprt.Scene) -> bool:
    used = {s.material for s in scene.shapes}
    return any(material_kind(scene.materials[m]) != "lambert" for m in used)


def to_mitsuba(scene: warprt.Scene, mi, *, sampler: str = "independent", spp: int = 1,
               mesh_dir: Path | None = None, plane_half: float | None = None, emitter_samples: int = 1,
               integrator: str | None = None, instancing: bool = True) -> dict:
    """A Mitsuba 3 scene dict with the same physics as ``scene`` (see the module docstring).

    ``integrator``: "direct" or "whitted" (default: whitted where a used material mirrors or
    refracts, else direct; "whitted" needs ``register_whitted(mi)`` first). ``instancing``:
    meshes that share an asset and a material become one shapegroup and its instances (else
    each is its own ply shape)."""
    mesh_dir = Path(mesh_dir) if mesh_dir is not None else MESH_DIR
    plane_half = ground_half(scene) if plane_half is None else plane_half
    if np.any(np.asarray(scene.ambient, dtype=float) != 0) or np.any(np.asarray(scene.background, dtype=float) != 0):
        raise ExportError("ambient and background must be 0 (Mitsuba's direct integrator has neither)")
    rs, default = scene.render, warprt.RenderSettings()
    if rs.t_min != default.t_min or rs.t_max != default.t_max:
        raise ExportError("render.t_min / t_max clip camera rays: no Mitsuba counterpart")
    if moves(scene):
        raise ExportError("motion (a moving camera, sphere, mesh or solid): Mitsuba 3 has no animated transforms; "
                          "render scene_at_time(scene, t) at several times instead")
    cam = scene.camera
    if cam.model != "pinhole" or cam.fx is not None:
        raise ExportError(f"camera model {cam.model!r} from intrinsics: the export writes Mitsuba's perspective sensor "
                          "from a field of view only")
    to_world = mi.ScalarTransform4f().look_at(origin=list(map(float, cam.eye)), target=list(map(float, cam.look_at)),
                                             up=list(map(float, cam.up)))
    sensor = {"type": "perspective", "fov": float(cam.fov), "fov_axis": "y", "to_world": to_world,
              "film": {"type": "hdrfilm", "width": int(cam.width), "height": int(cam.height),
                       "rfilter": {"type": "box"}, "pixel_format": "rgb", "sample_border": False},
              "sampler": {"type": sampler, "sample_count": int(spp)}}
    if cam.aperture > 0:
        sensor.update(type="thinlens", aperture_radius=float(cam.aperture), focus_distance=float(cam.focus))
    specular = has_specular(scene)
    integrator = integrator or ("whitted" if specular else "direct")
    if integrator == "direct":
        if specular:
            raise ExportError("mirrors or glass need the whitted integrator (Mitsuba's direct stops at them)")
        integ = {"type": "direct", "emitter_samples": int(emitter_samples), "bsdf_samples": 0}
    elif integrator == "whitted":
        integ = {"type": "whitted", "max_depth": int(rs.max_depth), "min_weight": float(rs.min_weight),
                 "emitter_samples": int(emitter_samples),
                 "transparent_shadows": any(material_kind(scene.materials[s.material]) == "glass"
                                            for s in scene.shapes)}
    else:
        raise ExportError(f"unknown integrator {integrator!r}")
    out = {"type": "scene", "integrator": integ, "sensor": sensor}
    bsdfs = {name: bsdf(scene.materials[name]) for name in {s.material for s in scene.shapes}}
    base = Path(scene.source).parent if scene.source else None

    def T(m):
        return mi.ScalarTransform4f(np.asarray(m, dtype=float).tolist())

    # meshes sharing one asset and material: one shapegroup, instanced
    groups: dict = {}
    arrays = {}
    for k, s in enumerate(scene.shapes):
        if isinstance(s, warprt.Mesh):
            if s.smooth:
                raise ExportError(f"shapes[{k}]: smooth meshes interpolate normals warprt's way; only flat ones export")
            v, f = _mesh_arrays(s, base)
            arrays[k] = (v, f)
            key = (hashlib.sha1(v.astype("<f4").tobytes() + f.astype("<i4").tobytes()).hexdigest(), s.material)
            groups.setdefault(key, []).append(k)
    grouped = {}
    if instancing:
        for g, (key, members) in enumerate(groups.items()):
            if len(members) > 1:
                v, f = arrays[members[0]]
                out[f"group_{g:03d}"] = {"type": "shapegroup", "mesh": {
                    "type": "ply", "filename": mesh_file(v, f, mesh_dir), "face_normals": True,
                    "bsdf": bsdfs[key[1]]}}
                for k in members:
                    grouped[k] = f"group_{g:03d}"

    for k, shape in enumerate(scene.shapes):
        key = f"shape_{k:04d}"
        b = bsdfs[shape.material]
        if isinstance(shape, warprt.Sphere):
            c0, _, r = shape.world()
            out[key] = {"type": "sphere", "center": list(map(float, c0)), "radius": float(r), "bsdf": b}
        elif isinstance(shape, warprt.Rectangle):
            out[key] = {"type": "rectangle", "to_world": T(rect_frame(*shape.world())), "bsdf": b}
        elif isinstance(shape, warprt.Disk):
            out[key] = {"type": "disk", "to_world": T(disk_frame(shape.center, shape.normal, shape.radius)), "bsdf": b}
        elif isinstance(shape, warprt.Plane):
            point, normal = (np.asarray(x, dtype=float) for x in shape.world())
            t1 = np.cross(normal, [1.0, 0.0, 0.0] if abs(normal[0]) < 0.9 else [0.0, 0.0, 1.0])
            t1 *= 2 * plane_half / np.linalg.norm(t1)
            t2 = np.cross(normal, t1)  # t1 x t2 is along the normal
            out[key] = {"type": "rectangle", "to_world": T(rect_frame(point - (t1 + t2) / 2, t1, t2)), "bsdf": b}
        elif isinstance(shape, warprt.Box):
            pos, rot, _, _, half = shape.world()
            out[key] = {"type": "cube", "to_world": T(pose_matrix(pos, rot, half)), "bsdf": b}
        elif isinstance(shape, (warprt.Cylinder, warprt.Capsule)):
            pos, rot, _, _, (radius, half_len, _) = shape.world()
            m = pose_matrix(pos, rot)
            axis = m[:3, 1]  # the local y axis runs from start to end
            p0, p1 = np.asarray(pos) - half_len * axis, np.asarray(pos) + half_len * axis
            out[key] = {"type": "cylinder", "p0": p0.tolist(), "p1": p1.tolist(), "radius": float(radius), "bsdf": b}
            for j, (p, n) in enumerate(((p0, -axis), (p1, axis))):
                if isinstance(shape, warprt.Cylinder):
                    out[f"{key}_cap{j}"] = {"type": "disk", "to_world": T(disk_frame(p, n, radius)), "bsdf": b}
                else:
                    out[f"{key}_end{j}"] = {"type": "sphere", "center": p.tolist(), "radius": float(radius), "bsdf": b}
        elif isinstance(shape, warprt.Mesh):
            m = (shape.transform or warprt.Transform()).matrix()
            if k in grouped:
                out[key] = {"type": "instance", "shapegroup": {"type": "ref", "id": grouped[k]}, "to_world": T(m)}
            else:
                v, f = arrays[k]
                out[key] = {"type": "ply", "filename": mesh_file(v, f, mesh_dir), "face_normals": True,
                            "to_world": T(m), "bsdf": b}
        else:
            raise ExportError(f"shapes[{k}]: {type(shape).__name__} does not export")
    for k, light in enumerate(scene.lights):
        key = f"light_{k:02d}"
        if isinstance(light, warprt.PointLight):
            if light.falloff != "inverse_square":
                raise ExportError(f"lights[{k}]: only inverse-square point lights have a physical counterpart")
            out[key] = {"type": "point", "position": list(map(float, light.position)),
                        "intensity": _rgb(np.asarray(light.intensity, dtype=float) * math.pi)}
        elif isinstance(light, warprt.DirectionalLight):
            out[key] = {"type": "directional", "direction": list(map(float, light.direction)),
                        "irradiance": _rgb(np.asarray(light.intensity, dtype=float) * math.pi)}
        elif isinstance(light, warprt.RectLight):
            out[key] = {"type": "rectangle", "to_world": T(rect_frame(light.corner, light.edge1, light.edge2)),
                        "bsdf": _BLACK, "emitter": {"type": "area", "radiance": _rgb(light.radiance)}}
        elif isinstance(light, warprt.SphereLight):
            out[key] = {"type": "sphere", "center": list(map(float, light.center)), "radius": float(light.radius),
                        "bsdf": _BLACK, "emitter": {"type": "area", "radiance": _rgb(light.radiance)}}
        elif isinstance(light, warprt.DiskLight):
            out[key] = {"type": "disk", "to_world": T(disk_frame(light.center, light.normal, light.radius)),
                        "bsdf": _BLACK, "emitter": {"type": "area", "radiance": _rgb(light.radiance)}}
        else:
            raise ExportError(f"lights[{k}]: {type(light).__name__} does not export")
    return out


# --- the Whitted integrator for Mitsuba ---------------------------------------------------------------


_WHITTED = {}


def register_whitted(mi) -> None:
    """Register the ``whitted`` integrator with Mitsuba (once per variant)."""
    variant = mi.variant()
    if variant in _WHITTED:
        return
    import drjit as dr

    # @dr.syntax recompiles the methods below against this module's globals (closures are lost)
    globals().update(mi=mi, dr=dr)

    class WhittedIntegrator(mi.SamplingIntegrator):
        """warprt's recursion in Mitsuba: a vectorised loop over one path per camera sample.

        At every hit: add the emitter's radiance (the front of an area light) times the
        throughput; at a non-specular surface take ``emitter_samples`` emitter samples as
        Mitsuba's ``direct`` does (the shadow ray's transmittance the product of kt over the
        transparent surfaces it crosses, warprt's rule, where ``transparent_shadows``) and stop;
        at a delta BSDF (mirror, glass) multiply the throughput by its sampled weight and follow
        the sampled direction, up to ``max_depth`` bounces, while the throughput's largest
        component stays above ``min_weight``. Glass picks reflection or refraction with
        probability F (one path; warprt follows both, the same expectation). The BSDF context
        is in importance mode: no η² factor on refraction (warprt has none; on a closed glass
        body the factors of the way in and out cancel anyway)."""

        def __init__(self, props):
            super().__init__(props)
            self.max_depth = int(props.get("max_depth", 5))
            self.min_weight = float(props.get("min_weight", 1e-4))
            self.emitter_samples = int(props.get("emitter_samples", 1))
            self.transparent_shadows = bool(props.get("transparent_shadows", False))
            self.scalar = mi.variant().startswith("scalar")

        def sample(self, scene, sampler, ray, medium=None, active=True):
            if self.scalar:
                return self.sample_scalar(scene, sampler, ray)
            return self.sample_wide(scene, sampler, ray, active)

        def transmittance_scalar(self, scene, si, target):
            ray = si.spawn_ray_to(target)
            T = mi.Spectrum(1.0)
            while True:
                hit = scene.ray_intersect(ray)
                if not hit.is_valid():
                    return T
                b = hit.bsdf()
                if not mi.has_flag(b.flags(), mi.BSDFFlags.DeltaTransmission):
                    return mi.Spectrum(0.0)
                T *= b.eval_attribute_3("specular_transmittance", hit)
                if dr.max(T) <= 0:
                    return T
                ray = hit.spawn_ray_to(target)

        def sample_scalar(self, scene, sampler, ray):
            """The same, one sample at a time (the scalar variants: no loop recording, and no
            pointer where there is no emitter or no surface)."""
            ctx = mi.BSDFContext(mi.TransportMode.Importance)
            L, beta, valid = mi.Spectrum(0.0), mi.Spectrum(1.0), False
            for depth in range(self.max_depth + 1):
                si = scene.ray_intersect(ray)
                if not si.is_valid():
                    break
                valid = valid or depth == 0
                emitter = si.emitter(scene)
                if emitter is not None:
                    L += beta * emitter.eval(si)
                b = si.bsdf(ray)
                if not mi.has_flag(b.flags(), mi.BSDFFlags.Delta):
                    for _ in range(self.emitter_samples):
                        ds, em_w = scene.sample_emitter_direction(si, sampler.next_2d(), False)
                        if ds.pdf == 0:
                            continue
                        if self.transparent_shadows:
                            vis = self.transmittance_scalar(scene, si, ds.p)
                        else:
                            vis = 0.0 if scene.ray_test(si.spawn_ray_to(ds.p)) else 1.0
                        L += beta * b.eval(ctx, si, si.to_local(ds.d)) * em_w * vis / self.emitter_samples
                    break
                if depth == self.max_depth:
                    break
                bs, w = b.sample(ctx, si, sampler.next_1d(), sampler.next_2d())
                beta *= w
                if dr.max(beta) <= self.min_weight:
                    break
                ray = si.spawn_ray(si.to_world(bs.wo))
            return L, valid, []

        @dr.syntax
        def transmittance(self, scene, si, target, active):
            ray = si.spawn_ray_to(target)
            T = mi.Spectrum(1.0)
            active = mi.Bool(active)
            while dr.hint(active, label="whitted_shadow"):
                hit = scene.ray_intersect(ray, mi.RayFlags.Minimal, False, active)
                blocked = active & hit.is_valid()
                b = hit.bsdf()
                passes = mi.has_flag(b.flags(), mi.BSDFFlags.DeltaTransmission)
                kt = b.eval_attribute_3("specular_transmittance", hit, blocked & passes)
                T[blocked] = dr.select(passes, T * kt, 0.0)
                active = blocked & passes & (dr.max(T) > 0)
                ray[active] = hit.spawn_ray_to(target)
            return T

        @dr.syntax
        def sample_wide(self, scene, sampler, ray, active):
            ctx = mi.BSDFContext(mi.TransportMode.Importance)
            ray = mi.Ray3f(ray)
            L = mi.Spectrum(0.0)
            beta = mi.Spectrum(1.0)
            depth = mi.UInt32(0)
            active = mi.Bool(active)
            valid = mi.Bool(False)
            while dr.hint(active, max_iterations=self.max_depth + 1, label="whitted"):
                si = scene.ray_intersect(ray, active)
                valid |= active & si.is_valid() & (depth == 0)
                L += beta * si.emitter(scene).eval(si, active)
                active &= si.is_valid()
                bsdf_ = si.bsdf(ray)
                delta = mi.has_flag(bsdf_.flags(), mi.BSDFFlags.Delta)
                smooth = active & ~delta
                for _ in range(self.emitter_samples):
                    ds, em_w = scene.sample_emitter_direction(si, sampler.next_2d(smooth), False, smooth)
                    lit = smooth & (ds.pdf != 0)
                    if dr.hint(self.transparent_shadows, mode="scalar"):
                        vis = self.transmittance(scene, si, ds.p, lit)
                    else:
                        vis = dr.select(scene.ray_test(si.spawn_ray_to(ds.p), lit), 0.0, 1.0)
                    f = bsdf_.eval(ctx, si, si.to_local(ds.d), lit)
                    L[lit] = L + beta * f * em_w * vis / self.emitter_samples
                go = active & delta & (depth < self.max_depth)
                bs, w = bsdf_.sample(ctx, si, sampler.next_1d(go), sampler.next_2d(go), go)
                beta[go] = beta * w
                go &= dr.max(beta) > self.min_weight
                ray[go] = si.spawn_ray(si.to_world(bs.wo))
                depth += 1
                active = go
            return L, valid, []

        def aov_names(self):
            return []

        def to_string(self):
            return f"WhittedIntegrator[max_depth={self.max_depth}, emitter_samples={self.emitter_samples}]"

    mi.register_integrator("whitted", lambda props: WhittedIntegrator(props))
    _WHITTED[variant] = WhittedIntegrator


# --- Mitsuba set-up --------------------------------------------------------------------------------


def _find_libllvm() -> str | None:
    try:
        text = subprocess.run(["ldconfig", "-p"], capture_output=True, text=True, timeout=10).stdout
    except (OSError, subprocess.SubprocessError):
        text = ""
    paths = re.findall(r"=>\s*(\S*libLLVM[^\s]*\.so[^\s]*)", text)
    paths += glob.glob("/usr/lib/llvm-*/lib/libLLVM*.so*") + glob.glob("/usr/lib/x86_64-linux-gnu/libLLVM*.so*")

    def version(p: str) -> int:
        m = re.search(r"libLLVM[-.]?(?:so\.)?(\d+)", os.path.basename(p))
        return int(m.group(1)) if m else 0

    paths = sorted({p for p in paths if os.path.exists(p)}, key=version, reverse=True)
    return paths[0] if paths else None


def load_mitsuba(prefer: str = "llvm_ad_rgb", threads: int = 2):
    """(mi, dr, variant, note) or None when Mitsuba is not installed; the ``whitted`` integrator
    registered, Dr.Jit on ``threads`` threads."""
    if prefer.startswith("llvm") and not os.environ.get("DRJIT_LIBLLVM_PATH"):
        lib = _find_libllvm()
        if lib:
            os.environ["DRJIT_LIBLLVM_PATH"] = lib
    try:
        import drjit as dr
        import mitsuba as mi
    except ImportError:
        return None
    note = ""
    try:
        mi.set_variant(prefer)
    except Exception as e:  # noqa: BLE001 (no LLVM: Dr.Jit says so in many ways)
        mi.set_variant("scalar_rgb")
        note = (f"{prefer} unavailable ({str(e).splitlines()[0][:120] if str(e) else type(e).__name__}): "
                "using scalar_rgb, slower than the vectorised variant; install LLVM and set DRJIT_LIBLLVM_PATH")
    mi.set_log_level(mi.LogLevel.Error)  # multijitter warns on every spp it rounds up
    dr.set_thread_count(threads)
    register_whitted(mi)
    return mi, dr, mi.variant(), note


# --- the ground's stand-in square ----------------------------------------------------------------------


def _light_points(light):
    """(points bounding the light, its largest power factor: I (W/sr, Mitsuba's) for a point
    light, Le × area for an area light); None for a directional light."""
    if isinstance(light, warprt.PointLight):
        return [np.asarray(light.position, float)], float(np.max(light.intensity)) * math.pi
    if isinstance(light, warprt.RectLight):
        c, e1, e2 = (np.asarray(x, float) for x in (light.corner, light.edge1, light.edge2))
        return [c, c + e1, c + e2, c + e1 + e2], float(np.max(light.radiance)) * float(np.linalg.norm(np.cross(e1, e2)))
    if isinstance(light, (warprt.SphereLight, warprt.DiskLight)):
        c, r = np.asarray(light.center, float), float(light.radius)
        pts = [c + s * r * e for e in np.eye(3) for s in (-1.0, 1.0)]
        return pts, float(np.max(light.radiance)) * math.pi * r * r
    return None


def _far_radiance_bound(scene: warprt.Scene, plane: warprt.Plane, half: float) -> float:
    """An upper bound on the radiance of ``plane`` (Lambert, direct light only) at in-plane
    distance >= ``half`` from its point: E <= sum I h / r^3 over point lights (Mitsuba's I, W/sr)
    and Le A h / r^3 over area lights, with h a light's largest height above the plane and r its
    smallest distance to that far region, plus pi I for a directional light; L <= kd / pi E."""
    p0, n = (np.asarray(x, float) for x in plane.world())
    e = 0.0
    for light in scene.lights:
        if isinstance(light, warprt.PointLight) and light.falloff != "inverse_square":
            return math.inf
        got = _light_points(light)
        if got is None:
            if isinstance(light, warprt.DirectionalLight):
                e += math.pi * float(np.max(light.intensity))
                continue
            return math.inf
        pts, power = got
        h = max(max(float(np.dot(q - p0, n)) for q in pts), 0.0)
        reach = max(float(np.linalg.norm((q - p0) - np.dot(q - p0, n) * n)) for q in pts)
        r = math.hypot(max(half - reach, 0.0), max(min(float(np.dot(q - p0, n)) for q in pts), 0.0))
        if r <= 0:
            return math.inf
        e += power * h / r ** 3
    kd = float(np.max(scene.materials[plane.material].kd))
    return kd / math.pi * e


def plane_beyond_extent(scene: warprt.Scene, image: np.ndarray, half: float | None = None, n: int = 4) -> dict:
    """How much of ``image`` can come from a Plane farther than ``half`` from its point (outside
    the disk inscribed in Mitsuba's stand-in square): n x n camera rays per pixel (with lens
    samples) give each pixel's fraction f of such hits, ``_far_radiance_bound`` the most radiance
    L there; the relative MSE that the missing ground can make is at most mean((f L)^2) /
    mean(image^2). Camera rays only: a plane seen in a mirror is not counted (the corpus keeps
    mirrors away from the horizon)."""
    half = ground_half(scene) if half is None else half
    planes = [i for i, s in enumerate(scene.shapes) if isinstance(s, warprt.Plane)]
    h, w = image.shape[:2]
    if not planes:
        return {"pixels": 0, "radiance_bound": 0.0, "rel_mse_bound": 0.0}
    g = (np.arange(n) + 0.5) / n
    jj, ii, sy, sx = np.meshgrid(np.arange(h), np.arange(w), g, g, indexing="ij")
    points = np.stack([(ii + sx).ravel(), (jj + sy).ravel()], axis=1)
    lens = np.random.default_rng(0).random((len(points), 2))
    origins, directions = warprt.camera_rays(scene, points, lens=lens)
    hits = warprt.trace_rays(scene, origins, directions)
    contrib = np.zeros(len(points))
    worst = 0.0
    for i in planes:
        plane = scene.shapes[i]
        point, normal = (np.asarray(x, float) for x in plane.world())
        d = hits["position"].astype(np.float64) - point
        d -= np.outer(d @ normal, normal)
        far = hits["hit"] & (hits["shape"] == i) & (np.linalg.norm(d, axis=1) > half)
        if far.any():
            bound = _far_radiance_bound(scene, plane, half)
            worst = max(worst, bound)
            contrib = np.maximum(contrib, far * bound)
    per_pixel = contrib.reshape(h, w, n * n).mean(axis=2)
    img = np.asarray(image, dtype=np.float64)
    rel = float(np.mean(per_pixel ** 2) / max(float(np.mean(img ** 2)), 1e-30))
    return {"pixels": int((per_pixel > 0).sum()), "radiance_bound": worst, "rel_mse_bound": rel}
