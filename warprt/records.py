"""Device records: the structs the kernels read, the shape-kind tags, and ``Features``.

Every table on the device is an array of records (Warp passes structs to device functions by
value, so ``SceneData`` holds a dozen array headers rather than one array per field).
``features_of(scene)`` is the one place that decides which kernel code a scene needs.
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np
import warp as wp

from .accel import BvhNode
from .scene.description import SOLID_TYPES, Disk, Material, Mesh, Rectangle, Scene, Sphere, is_area_light

# shape kinds, as reported by ray queries and id AOVs, and as area lights name their surface
KIND_NONE, KIND_SPHERE, KIND_PLANE, KIND_RECT, KIND_DISK, KIND_MESH = -1, 0, 1, 2, 3, 4
KIND_BOX, KIND_CAPSULE, KIND_CYLINDER = 5, 6, 7  # the posed solids (``SolidRec``)
FALLOFF_DIRECTIONAL = 2  # PointLightRec.inv_sq of a directional light (0: none, 1: inverse square)
FRESNEL_IDS = {"none": 0, "schlick": 1, "exact": 2}
TEX_BITMAP, TEX_CHECKER = 0, 1  # TexRec.kind


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
    solids: bool = False  # analytic boxes, capsules and cylinders (intersected in their own frame)
    analytic_bvh: bool = False  # a BVH over the bounded analytic shapes: camera rays through it in packets
    textures: bool = False  # textured materials (bitmaps, checkers; uv, triplanar or cubic projection)

    @classmethod
    def full(cls) -> "Features":
        return cls(**{f.name: True for f in fields(cls)})

    def union(self, other: "Features") -> "Features":
        return Features(**{f.name: getattr(self, f.name) or getattr(other, f.name) for f in fields(self)})

    @property
    def key(self) -> str:
        on = [f.name for f in fields(self) if getattr(self, f.name)]
        return "+".join(on) if on else "basic"


#: the feature set of the general kernel: every feature behind its run-time check, so that it
#: renders any scene with the image of the scene's own variant (warprt.kernels)
GENERAL_FEATURES = Features.full()


def _reflects(m: Material) -> bool:
    return any(m.mirror) or (_refracts(m) and m.fresnel != "none")


def _refracts(m: Material) -> bool:
    return any(m.transparency)


def _glossy(m: Material) -> bool:
    # a transparent material reflects by total internal reflection even without mirror or
    # Fresnel, and those reflections use the glossy lobe too
    return ((_reflects(m) or _refracts(m)) and m.glossy_exponent > 0) or (_refracts(m) and m.frosted_exponent > 0)


def features_of(scene: Scene) -> Features:
    """The kernel features ``scene`` needs (a pure function of the description)."""
    used = [scene.materials[name] for name in {s.material for s in scene.shapes}]
    return Features(
        meshes=any(isinstance(s, Mesh) for s in scene.shapes),
        area_lights=any(is_area_light(light) for light in scene.lights),
        secondary=any(_reflects(m) or _refracts(m) for m in used),
        refraction=any(_refracts(m) for m in used),
        glossy=any(_glossy(m) for m in used),
        lens=scene.camera.aperture > 0.0,
        motion=scene.camera.moves or any(_moves(s) for s in scene.shapes),
        solids=any(isinstance(s, SOLID_TYPES) for s in scene.shapes),
        analytic_bvh=_bounded_analytic(scene) >= ANALYTIC_BVH_MIN,
        textures=any(getattr(m, name) is not None for m in used for name in Material.TEXTURE_FIELDS),
    )


# from this many bounded analytic shapes on (all but planes), rays find them through one BVH (accel).
# A BVH beats the loop (a box test per shape) from two on: a node's one load gives a ray both
# children's boxes, and the nearer child first lets it skip what lies behind its hit, in single
# images and in batches alike (``analytic_bvh`` in ``warprt.fast``)
# (build.py builds it; features_of compiles the camera-ray packets for it)
ANALYTIC_BVH_MIN = 2


def _bounded_analytic(scene: Scene) -> int:
    """How many bounded analytic shapes the scene has, its area lights' emitting surfaces among
    them (at least as many as the builder's BVH takes: the feature only adds code, and the kernel
    checks at run time whether the BVH exists)."""
    return (sum(isinstance(s, (Sphere, Rectangle, Disk, *SOLID_TYPES)) for s in scene.shapes)
            + sum(is_area_light(light) for light in scene.lights))


def _moves(shape) -> bool:
    if isinstance(shape, Sphere):
        c0, c1, _ = shape.world()
        return c0 != c1
    return isinstance(shape, (Mesh, *SOLID_TYPES)) and shape.moves


# --- device records ----------------------------------------------------------------------------


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
class SolidRec:
    """A box, capsule or cylinder in its own frame, posed at times 0 and 1 (rotations by slerp).

    Box: ``size`` holds the half extents along the local axes. Capsule (the points within radius
    r of the segment from (0, -h, 0) to (0, h, 0)) and cylinder (radius r about the local y
    axis, |y| <= h, flat caps): ``size`` = (r, h, 0)."""

    pos0: wp.vec3  # the centre at time 0
    rot0: wp.quat  # local to world at time 0
    pos1: wp.vec3
    rot1: wp.quat  # in rot0's hemisphere (slerp along the shorter arc)
    size: wp.vec3
    mat: int
    lo: wp.vec3  # the world box over the shutter (padded): rays that miss it skip the solid
    hi: wp.vec3


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
    uv_off: int  # first vertex's texture coordinates in SceneData.uvs (-1: the asset has none)
    olo: wp.vec3  # the asset's bounding box in object space
    ohi: wp.vec3
    lo: wp.vec3  # the instance's box in world space over the shutter (rays that miss it skip the mesh)
    hi: wp.vec3
    tree_nodes: wp.uint64  # the asset's tree on the CPU (accel.MeshTree: addresses; 0 on CUDA)
    tree_kids: wp.uint64
    tree_tris: wp.uint64
    tree_root: int
    wide: wp.uint64  # its 4-wide form for the packets (accel.widen)
    balls: wp.uint64  # the asset's interior balls (accel.interior_balls) while shadow rays may use them
    n_balls: int  # 0: none (CUDA, a mesh that does not qualify, or build.DeviceScene's rules)
    escape: wp.uint64  # the asset's escape horizons (accel.escape_horizons; 0: none)
    frames: wp.uint64  # their sectors' frames (accel.escape_frames; 0: the escaping faces alone)
    cones: wp.uint64  # the asset's normal cones (accel.normal_cones) while shadow rays may use them
    wide_cones: wp.uint64  # the same in the wide tree's layout (0 with cones 0)
    shadow_packets: int  # 1: a camera packet's shadow rays go through the tree together (accel.SHADOW_PACKET_TRIANGLES)
    bins: wp.uint64  # the camera's screen-space bins of the asset's triangles (accel.camera_bins; 0: none)
    prefetch: int  # 1: packets prefetch their hits' corners (warprt.fast: hit_prefetch)


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
    tex: int  # texture (row of SceneData.texs) multiplying kd and ka; -1: none
    tex_s: int  # texture multiplying ks; -1: none
    tex_m: int  # texture multiplying km; -1: none


@wp.struct
class TexRec:
    """A texture (``warprt.scene.texture``): a bitmap's texels are rows of SceneData.texels from
    ``off`` on (w × h, row 0 the image's top), a checker's colours c0 and c1."""

    kind: int  # TEX_BITMAP or TEX_CHECKER
    off: int
    w: int
    h: int
    wrap: int  # WRAPS id: 0 repeat, 1 clamp
    proj: int  # PROJECTIONS id: 0 uv, 1 triplanar, 2 cubic
    scale: float
    sharp: float  # triplanar blend exponent
    c0: wp.vec3
    c1: wp.vec3


@wp.struct
class PointLightRec:
    pos: wp.vec3
    intensity: wp.vec3  # I
    inv_sq: int  # 1: inverse-square falloff; FALLOFF_DIRECTIONAL: a directional light (pos: unit vector towards it)
    # its light buffer (accel.light_buffer; CPU only): the first of its 6 · lb_res² cells in
    # SceneData.lb_cells (-1: none), and the farthest a shadow ray's origin may be to use it
    lb_cell0: int
    lb_res: int
    lb_reach: float


@wp.struct
class AreaLightRec:
    kind: int  # KIND_* of the emitting shape
    shape: int  # its row in that kind's table
    le: wp.vec3  # radiance
    samples: int


@wp.struct
class SceneData:
    """Every table as an array of records. Warp passes structs to device functions by value, so
    this struct is kept small: a dozen array headers, not one per field."""

    n_spheres: int
    spheres: wp.array(dtype=SphereRec)
    bvh_nodes: wp.array(dtype=BvhNode)  # BVH over the bounded analytic shapes (all but planes and meshes)
    bvh_root: int  # the node rays start from (a world's tree in a batch); -1: no BVH (few shapes)
    bvh_prims: wp.array(dtype=wp.vec2i)  # (kind, row) of each BVH primitive, in leaf order
    n_planes: int
    planes: wp.array(dtype=PlaneRec)
    n_rects: int
    rects: wp.array(dtype=RectRec)
    n_disks: int
    disks: wp.array(dtype=DiskRec)
    n_inst: int
    insts: wp.array(dtype=InstRec)
    n_boxes: int
    boxes: wp.array(dtype=SolidRec)
    n_capsules: int
    capsules: wp.array(dtype=SolidRec)
    n_cylinders: int
    cylinders: wp.array(dtype=SolidRec)
    normals: wp.array(dtype=wp.vec3)
    mats: wp.array(dtype=MatRec)
    texs: wp.array(dtype=TexRec)  # the textures the materials name
    texels: wp.array(dtype=wp.vec3)  # every bitmap's linear RGB texels
    uvs: wp.array(dtype=wp.vec2)  # the mesh assets' per-vertex texture coordinates (InstRec.uv_off)
    n_plights: int
    plights: wp.array(dtype=PointLightRec)
    lb_cells: wp.array(dtype=int)  # the point lights' buffers: each cell's first entry in lb_items, then the end
    lb_items: wp.array(dtype=int)  # the BVH primitives (their index in bvh_prims) a cell's directions may meet
    n_alights: int
    alights: wp.array(dtype=AreaLightRec)  # an "auto" light's samples 0: its count from split_n
    split_n: wp.array(dtype=int)  # each image block's count for "auto" lights (lights.map_samples)
    split_tile: int  # the tiles' size in pixels; 0: no map
    split_tx: int  # tiles across the image
    ambient: wp.vec3
    background: wp.vec3
    fast_off: int  # the kernel-stage speed mechanisms switched off (warprt.fast's FAST_* bits; 0: all on)


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
    # the camera model (camera.MODEL_*) and its run-time data (camera.camera_data); the pinhole's
    # image plane spans u in [-x_off, 2 right - x_off], v in [y_off - 2 top, y_off] (x_off = right,
    # y_off = top when centred)
    model: int
    x_off: float
    y_off: float
    pfx: float  # fx, fy in pixels (orthographic: pixels per scene unit)
    pfy: float
    pcx: float  # the principal point as a raster position: OpenCV's cx + 0.5, cy + 0.5
    pcy: float
    dk0: wp.vec4  # opencv: k1, k2, k3, k4; fisheye: k1, k2, k3, k4
    dk1: wp.vec4  # opencv: k5, k6, p1, p2
    dk2: wp.vec4  # opencv: s1, s2, s3, s4
    r_max: float  # opencv: the undistorted radius's valid limit; fisheye: theta's (camera.distortion_limit)
    d_max: float  # the distorted radius there: raster points beyond it get no ray
    line_delay: float  # rolling shutter: time per row
    from_fov: int  # 1: the plane (and fx, fy) from a field of view (BatchRenderer.fov sets it per camera)


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
    light_sampling: int  # LIGHT_SAMPLING id: 1 draws rectangle-light directions in proportion to n·ω
    aovs: int  # the AOVs the render asks for (aov.AOV_BITS; 0: none): its first hits go into aov.AovData


def table(struct, rows: list[dict], device) -> "wp.array":
    """An array of ``struct`` records from dicts of field values (one zero record when empty)."""
    data = np.zeros(max(len(rows), 1), dtype=struct.numpy_dtype())
    for name in data.dtype.names:
        if rows:
            data[name] = [row[name] for row in rows]
    return wp.array(data, dtype=struct, device=device)
