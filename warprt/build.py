"""Build: turn a :class:`Scene` into device tables (host to device, one direction).

* Analytic spheres, planes, rectangles and disks stay analytic (exact normals, exact light
  sampling): each becomes a row of its kind's table, as ``shapes.KINDS`` says.
* Each mesh *asset* (a file, or one set of inline arrays) becomes one ``wp.Mesh`` in object
  space; every mesh shape is an *instance* of an asset with a transform at time 0 and time 1, so
  moving or re-posing a mesh never rebuilds its BVH (``meshes`` reads and checks the assets).
* An area light is emission on a shape: its ``.shape()`` goes into that kind's table with an
  emitting material (so camera rays see it and it occludes), and a light record names it.
* ``features`` (``records.features_of``) records which kernel code the scene needs.
"""

from __future__ import annotations

import math
import warnings
import weakref

import numpy as np
import warp as wp

from . import accel, fast
from .accel import NO_TREE, BvhNode, MeshTree, build_tree, camera_bins, forest_nodes, light_buffer
from .camera import camera_data
from .errors import RenderError, SceneError
from .meshes import as_points, asset_key, prepare_mesh, vertex_normals
from .scene.meshfile import read_mesh_file
from .records import (
    ANALYTIC_BVH_MIN, FALLOFF_DIRECTIONAL, FRESNEL_IDS, KIND_MESH, KIND_RECT, AreaLightRec, Features, InstRec, MatRec, PointLightRec, RenderParams, SceneData,
    features_of, table,
)
from .sampling import SAMPLER_IDS
from .scene.description import (
    AUTO_SAMPLES, EXTENT_WARNING, LIGHT_SAMPLING, UNDERFLOW_WARNING, DirectionalLight, Material, Mesh, PointLight, Scene,
    is_area_light, scene_extent, tiny_shapes,
)
from .scene.transform import Transform, same_hemisphere
from .shapes import BY_CLASS, BY_TAG, KINDS, rect_pieces
from .textures import TexturePool
from .trace import instance_box_kernel


# each mesh asset's extent (the diagonal of its vertices' box, float64), measured once when its
# wp.Mesh is built and kept as long as the mesh (for the underflow warning)
_ASSET_EXTENT: "weakref.WeakKeyDictionary" = weakref.WeakKeyDictionary()
# each mesh asset's per-vertex texture coordinates (float32 (N, 2); absent: none), kept as long as
# the mesh
_ASSET_UV: "weakref.WeakKeyDictionary" = weakref.WeakKeyDictionary()


class DeviceScene:
    """A scene's tables on one device. Keeps every ``wp.Mesh`` alive while its id is in use."""

    def __init__(self, scene: Scene, device: "wp.context.Device", assets: dict | None = None,
                 light_buffers: bool = True, fast_off=None):
        self.scene = scene
        self.device = device
        # the speed mechanisms switched off (``warprt.fast``; None: those switched off now)
        self.fast_off: frozenset = fast.current() if fast_off is None else fast.closure(fast.check(fast_off))
        # whether CPU point lights get light buffers (_light_buffers)
        self.light_buffers = light_buffers and "light_buffers" not in self.fast_off
        # mesh assets by key: (wp.Mesh, vertex normals); a previous DeviceScene's assets can be
        # passed in so that re-posed or re-lit frames never rebuild a BVH
        self.assets: dict[tuple, tuple] = dict(assets or {})
        self.features: Features = features_of(scene)
        try:
            self._build()
        except SceneError as e:
            raise e.within(source=scene.source) from None
        extent = scene_extent(scene)
        where = f"{scene.source}: " if scene.source else ""
        if extent > EXTENT_WARNING:
            warnings.warn(f"{where}scene coordinates reach {extent:.3g}: beyond about {EXTENT_WARNING:g} the "
                          "renderer's float32 squared distances overflow and surfaces or lights may vanish; "
                          "scale the scene down", RuntimeWarning, stacklevel=3)
        tiny = sorted(tiny_shapes(scene) + self._tiny_meshes(),
                      key=lambda t: (t[0].split("[")[0], int(t[0].split("[")[1].rstrip("]"))))
        if tiny:  # the other end of float32: lengths whose squares underflow
            (field, size), more = tiny[0], len(tiny) - 1
            warnings.warn(f"{where}{field}{f' (and {more} more)' if more else ''} measures only {size:.3g} across: "
                          f"below about {UNDERFLOW_WARNING:g} the renderer's float32 squared lengths underflow and it "
                          "may vanish; scale the scene up", RuntimeWarning, stacklevel=3)

    def _tiny_meshes(self) -> list[tuple[str, float]]:
        """(field, size) of the mesh shapes whose extent (the asset's, times the largest scale)
        is non-zero but below UNDERFLOW_WARNING."""
        out = []
        for i, s in enumerate(self.scene.shapes):
            if isinstance(s, Mesh):
                key = self.instance_assets[self.shape_ids[i][1]]
                scale = max(abs(c) for c in (s.transform or Transform()).scale)
                size = _ASSET_EXTENT.get(self.assets[key][0], 0.0) * scale
                if 0.0 < size < UNDERFLOW_WARNING:
                    out.append((f"shapes[{i}]", size))
        return out

    # the tables are built as lists of record fields, then copied once to the device
    def _build(self) -> None:
        scene, dev = self.scene, self.device
        mat_index = {name: i for i, name in enumerate(scene.materials)}
        mats: list[tuple[Material, tuple]] = [(m, (0.0, 0.0, 0.0)) for m in scene.materials.values()]
        rows: dict[str, list[dict]] = {k.table: [] for k in KINDS}
        ins: list[dict] = []
        self.meshes: list[wp.Mesh] = []
        trees: list[MeshTree | None] = []  # each asset's CPU tree copy (None on CUDA)
        asset_ids: dict[object, int] = {}
        normals: list[np.ndarray] = []
        nrm_offsets: list[int] = []
        n_normals = 0
        uvs: list[np.ndarray] = []
        uv_offsets: list[int] = []
        n_uvs = 0
        self.instance_assets: list[tuple] = []  # asset key of each mesh instance
        self.shape_ids: list[tuple[int, int]] = []  # (kind, row in its table) for each scene shape
        self._balls_given = False  # whether an instance record holds interior balls (refresh_balls)

        for i, s in enumerate(scene.shapes):
            mi = mat_index[s.material]
            try:
                if isinstance(s, Mesh):
                    key = asset_key(s)
                    if key not in asset_ids:
                        if key not in self.assets:
                            v, f, uv = read_mesh_file(s.file) if s.file is not None else (s.vertices, s.faces, s.uv)
                            v32, f32 = prepare_mesh(v, f, s.degenerate)
                            # leaves of one triangle: on the CPU the tree is copied for warprt's own
                            # traversal (accel.MeshTree); CUDA keeps Warp's default leaves and query
                            mesh = wp.Mesh(points=wp.array(v32, dtype=wp.vec3, device=dev),
                                           indices=wp.array(f32.reshape(-1), dtype=wp.int32, device=dev),
                                           **({"bvh_leaf_size": 1} if dev.is_cpu else {}))
                            tree = MeshTree(mesh, len(f32)) if dev.is_cpu else None
                            if tree is not None:
                                # balls, horizons, cones for shadow rays (accel.py)
                                tree.find_balls(v32, f32, self.fast_off)
                            self.assets[key] = (mesh, vertex_normals(v32, f32), tree)
                            _ASSET_EXTENT[mesh] = float(np.linalg.norm(np.ptp(
                                v32[f32.reshape(-1)].astype(np.float64), axis=0)))
                            if uv is not None:
                                _ASSET_UV[mesh] = np.asarray(uv, np.float32)
                        mesh, vn, tree = self.assets[key]
                        if tree is not None and tree.found_without != self.fast_off & accel._FOUND:
                            # (an asset another DeviceScene built with other switches: warprt.fast)
                            tree.find_balls(mesh.points.numpy(), mesh.indices.numpy().reshape(-1, 3), self.fast_off)
                        trees.append(tree)
                        asset_ids[key] = len(self.meshes)
                        self.meshes.append(mesh)
                        normals.append(vn)
                        nrm_offsets.append(n_normals)
                        n_normals += len(vn)
                        asset_uv = _ASSET_UV.get(mesh)
                        uv_offsets.append(-1 if asset_uv is None else n_uvs)
                        if asset_uv is not None:
                            uvs.append(asset_uv)
                            n_uvs += len(asset_uv)
                    a = asset_ids[key]
                    t0 = s.transform or Transform()
                    t1 = s.transform_end or t0
                    self.shape_ids.append((KIND_MESH, len(ins)))
                    self.instance_assets.append(key)
                    q0 = t0.quaternion()
                    ins.append(dict(mesh=self.meshes[a].id, pos0=t0.translate, rot0=q0, scl0=t0.scale,
                                    pos1=t1.translate, rot1=same_hemisphere(t1.quaternion(), q0), scl1=t1.scale,
                                    mat=mi, smooth=int(s.smooth), nrm_off=nrm_offsets[a], uv_off=uv_offsets[a],
                                    olo=(0.0, 0.0, 0.0), ohi=(0.0, 0.0, 0.0), lo=(0.0, 0.0, 0.0), hi=(0.0, 0.0, 0.0),
                                    **self._tree_fields(trees[a])))
                else:
                    kind = BY_CLASS[type(s)]
                    self.shape_ids.append((kind.tag, len(rows[kind.table])))
                    rows[kind.table].append(kind.row(s, mi))
            except SceneError as e:
                raise e.within(f"shapes[{i}]") from None

        # area lights: emission on a shape, appended to that shape kind's table
        alights = []
        for light in filter(is_area_light, scene.lights):
            surface = light.shape()
            kind = BY_CLASS[type(surface)]
            mats.append((Material(kd=0.0, ka=0.0), tuple(light.radiance)))
            auto = light.samples == AUTO_SAMPLES  # 1 until the renderer has chosen (warprt.splitting)
            alights.append(dict(kind=kind.tag, shape=len(rows[kind.table]), le=light.radiance,
                                samples=1 if auto else light.samples, auto=auto))
            rows[kind.table].append(kind.row(surface, len(mats) - 1))
        self.normal_offsets = dict(zip(asset_ids, nrm_offsets))
        self.area_lights = alights  # (kind, row in its shape table, radiance, samples, auto) of each area light
        # point and directional lights share one table: a directional light's ``pos`` is the unit
        # vector towards it and ``inv_sq`` is FALLOFF_DIRECTIONAL
        plights = [light for light in scene.lights if isinstance(light, (PointLight, DirectionalLight))]

        # --- copy to the device
        d = SceneData()
        for kind in KINDS:
            setattr(d, "n_" + kind.table, len(rows[kind.table]))
            setattr(d, kind.table, table(kind.record, rows[kind.table], dev))
        d.n_inst = len(ins)
        d.insts = table(InstRec, ins, dev)
        if ins:  # each instance's object and world boxes (rays that miss the box skip the mesh)
            wp.launch(instance_box_kernel(), dim=len(ins), inputs=[d.insts], device=dev)
        self.data = d
        self.refresh_balls()
        self._bins: list = []  # the camera bins' arrays the instance records point to (refresh_bins)
        self._view_renders = 0  # renders since the camera or the points last changed (rendering)
        d.normals = wp.array(np.concatenate(normals) if normals else np.zeros((1, 3), np.float32),
                             dtype=wp.vec3, device=dev)
        d.uvs = wp.array(np.concatenate(uvs) if uvs else np.zeros((1, 2), np.float32), dtype=wp.vec2, device=dev)
        self.textures = TexturePool()
        self.material_rows = [material_row(m, le, self.textures) for m, le in mats]
        d.mats = table(MatRec, self.material_rows, dev)
        d.texs, d.texels = self.textures.upload(dev)
        d.n_alights = len(alights)
        d.alights = table(AreaLightRec, alights, dev)
        self._auto_samples = 1  # what the "auto" lights' rows hold (set_auto_light_samples; 0: the map's)
        self.set_light_map(None)
        d.ambient = wp.vec3(*scene.ambient)
        d.background = wp.vec3(*scene.background)
        d.fast_off = fast.kernel_bits(self.fast_off)
        self._analytic_bvh(d, rows, [m for m, _ in mats])
        d.n_plights = len(plights)
        d.plights = table(PointLightRec, self._light_buffers(d, rows, plights), dev)
        self.data = d
        self.camera = camera_data(scene)

    def _tree_fields(self, tree: MeshTree | None) -> dict:
        """An instance record's fields for its asset's tree copy, less the mechanisms switched off
        (``warprt.fast``): without mesh_trees a ray meets the mesh through Warp's query."""
        f = dict(NO_TREE) if tree is None else tree.record()
        off = self.fast_off
        if "mesh_trees" in off:
            f.update(tree_nodes=0, tree_kids=0)
        if "wide_tree" in off:
            f.update(wide=0)
        if "mesh_shadow_packets" in off:
            f.update(shadow_packets=0)
        if "hit_prefetch" in off:
            f.update(prefetch=0)
        if "escaping_faces" in off:
            f.update(escape=0, frames=0)
        return f

    @property
    def auto_lights(self) -> int:
        """How many area lights have ``samples = "auto"``."""
        return sum(a["auto"] for a in self.area_lights)

    def set_auto_light_samples(self, n: int) -> None:
        """Give every area light with ``samples = "auto"`` n shadow rays per camera sample (the
        rows are rewritten only when n changes: every render sets it, and a copy of the table to
        the device costs a 1-spp render of a small scene a few percent)."""
        if n == self._auto_samples:
            return
        rows = self.data.alights.numpy()
        for j, a in enumerate(self.area_lights):
            if a["auto"]:
                rows["samples"][j] = n
        self.data.alights.assign(rows)
        self._auto_samples = n

    def set_light_map(self, counts: np.ndarray | None, tile: int = 0) -> None:
        """Give the "auto" lights a count of shadow rays per camera sample for each ``tile`` ×
        ``tile`` block of the image (``counts``, rows of tiles, from ``warprt.splitting``), read by
        the kernel from the pixel (their rows' samples become 0); None: no map (the rows' count)."""
        d = self.data
        if counts is None:
            d.split_n = wp.zeros(1, dtype=int, device=self.device)
            d.split_tile = 0
            d.split_tx = 0
            return
        counts = np.asarray(counts)
        cam = self.scene.camera
        if tile < 1 or counts.shape != (-(-cam.height // tile), -(-cam.width // tile)) \
                or not np.issubdtype(counts.dtype, np.integer) or counts.min() < 1 or counts.max() > 1024:
            raise RenderError(f"a light map of {tile}-pixel blocks over {cam.width} × {cam.height} pixels needs "
                              f"{-(-cam.height // tile)} × {-(-cam.width // tile)} counts of 1 to 1024, got "
                              f"{counts.dtype} {counts.shape}")
        counts = np.ascontiguousarray(counts, dtype=np.int32)
        d.split_n = wp.array(counts.reshape(-1), dtype=int, device=self.device)
        d.split_tile = int(tile)
        d.split_tx = int(counts.shape[1])
        self.set_auto_light_samples(0)

    def refresh_balls(self) -> None:
        """Give each mesh instance its asset's interior balls (``accel.interior_balls``) and normal
        cones (``accel.normal_cones``) where a shadow ray's origin cannot be inside the solid:
        while the camera's eye (with its lens and motion) and every light stay outside the
        instance's box, a shading point the camera sees is outside the solid. An asset whose
        points were moved (``set_mesh_points``) has neither."""
        d = self.data
        if d.n_inst == 0:
            return
        trees = [self.assets[key][2] for key in self.instance_assets]
        given = any(t is not None and (t.balls is not None or t.cones is not None) for t in trees)
        if not given and not self._balls_given:
            return  # (none to give, and none given)
        self._balls_given = False
        regions = _light_regions(self.scene)
        cam = self.scene.camera
        if cam.keyframes or self.scene.render.t_min > 0.0:
            # (a keyframed path: not checked; camera rays that start past the eye can start inside
            # a solid and see its inner side: no balls, no cones)
            regions = None
        elif regions is not None:
            eyes = np.array([cam.eye] + ([cam.eye_end] if cam.eye_end is not None else []), dtype=np.float64)
            pad = float(cam.aperture) + 1e-6 * (1.0 + float(np.abs(eyes).max()))
            regions.append((eyes.min(axis=0) - pad, eyes.max(axis=0) + pad))
        rows = d.insts.numpy()
        for i, tree in enumerate(trees):
            fields = dict(balls=0, n_balls=0, cones=0, wide_cones=0)
            if tree is not None and regions is not None:
                lo, hi = rows["lo"][i], rows["hi"][i]
                if not any(np.all(rlo <= hi) and np.all(lo <= rhi) for rlo, rhi in regions):
                    fields = tree.ball_fields()
                    if "interior_balls" in self.fast_off:  # (warprt.fast)
                        fields.update(balls=0, n_balls=0)
                    if "normal_cones" in self.fast_off:
                        fields.update(cones=0, wide_cones=0)
            for name in ("balls", "n_balls", "cones", "wide_cones"):
                rows[name][i] = fields[name]
            self._balls_given |= fields["n_balls"] > 0 or fields["cones"] != 0
        d.insts.assign(rows)

    def refresh_bins(self) -> None:
        """Give each large mesh instance (``accel.BINS_TRIANGLES`` triangles or more) the camera's
        screen-space bins of its triangles (``accel.camera_bins``), where every camera ray starts
        at the eye: a pinhole camera at rest, camera rays from t = 0, an instance at rest that
        neither rotates nor scales. They give the tree's hits (the same images; see ``accel``) in
        less time; a renderer builds them with the scene, and after a change of camera or points
        once the new view has been rendered ``accel.BINS_AFTER_RENDERS`` times (``rendering``): a
        camera or mesh that moves every frame never pays for them."""
        d = self.data
        self._view_renders = accel.BINS_AFTER_RENDERS + 1  # (built: not again until the view changes)
        if d.n_inst == 0 or not self.device.is_cpu or "camera_bins" in self.fast_off:
            return
        cam, rs = self.scene.camera, self.scene.render
        rows = d.insts.numpy()
        had = bool(self._bins)
        self._bins = []
        budget = accel.BINS_MAX_ENTRIES  # (the instances share one budget of memory, in instance order)
        # (bins serve rays from the eye in front of it: the pinhole's and the opencv model's, whose
        # rays beyond the pinhole's rectangle go through the tree as any ray off the grid does;
        # not the orthographic camera's, nor the fisheye's, which reach behind the eye's plane)
        still = not cam.moves and cam.aperture == 0.0 and rs.t_min == 0.0
        still = still and cam.model in ("pinhole", "opencv")
        if cam.fx is None:
            tan_y = math.tan(math.radians(cam.fov) / 2.0)
            tan_x, cell = tan_y * cam.aspect, 2.0 * tan_y / cam.height
        else:  # the view's half extents about the axis (the principal point off centre)
            fx, fy, cx, cy = cam.intrinsics()
            tan_x = max(cx + 0.5, cam.width - cx - 0.5) / fx
            tan_y = max(cy + 0.5, cam.height - cy - 0.5) / fy
            cell = 1.0 / fy
        identity = np.array([0.0, 0.0, 0.0, 1.0], np.float32)
        for i, key in enumerate(self.instance_assets):
            rows["bins"][i] = 0
            tree, r = self.assets[key][2], rows[i]
            if (not still or tree is None or not tree.usable or tree.n_faces < accel.BINS_TRIANGLES
                    or np.any(r["pos0"] != r["pos1"]) or np.any(r["rot0"] != identity) or np.any(r["rot1"] != identity)
                    or np.any(r["scl0"] != 1.0) or np.any(r["scl1"] != 1.0)):
                continue
            # the origin as the kernel computes a camera ray's in object space (trace.to_object)
            origin = np.asarray(cam.eye, np.float32) - r["pos0"]
            with fast.timed("camera_bins"):
                rec = camera_bins(tree.tris, origin, np.subtract(cam.look_at, cam.eye), cam.up, tan_x, tan_y,
                                  cell / accel.BINS_PER_PIXEL, (r["olo"], r["ohi"]), budget)
            if rec is None:
                continue
            budget -= accel.camera_bins_size(rec)
            arr = wp.array(rec, dtype=wp.float32, device=self.device)
            self._bins.append(arr)
            rows["bins"][i] = arr.ptr
        if self._bins or had:
            d.insts.assign(rows)

    def drop_bins(self) -> None:
        """The view changed (camera or points): no bins until it has been rendered
        ``accel.BINS_AFTER_RENDERS`` times (``refresh_bins``)."""
        self._view_renders = 0
        if self._bins:
            rows = self.data.insts.numpy()
            rows["bins"] = 0
            self.data.insts.assign(rows)
            self._bins = []

    def rendering(self) -> None:
        """A render starts: a changed view gets its bins before its ``BINS_AFTER_RENDERS + 1``-th."""
        self._view_renders += 1
        if self._view_renders == accel.BINS_AFTER_RENDERS + 1:
            self.refresh_bins()

    def set_mesh_points(self, shape_index: int, points) -> None:
        """Move the vertices of the mesh asset behind ``scene.shapes[shape_index]`` (every
        instance of that asset follows) and refit its BVH; smooth normals are recomputed."""
        n = len(self.shape_ids)
        if isinstance(shape_index, bool) or not isinstance(shape_index, (int, np.integer)) or not 0 <= shape_index < n:
            raise RenderError(f"shape_index must be an index into scene.shapes (0 to {n - 1}), got {shape_index!r}")
        kind, row = self.shape_ids[shape_index]
        if kind != KIND_MESH:
            raise SceneError(f"shape {shape_index} is not a mesh", f"shapes[{shape_index}]")
        key = self.instance_assets[row]
        mesh, _, tree = self.assets[key]
        p = as_points(points, mesh.points.shape[0], self.device)
        if isinstance(p, wp.array):
            wp.copy(mesh.points, p)
        else:
            mesh.points.assign(p)
        mesh.refit()
        if tree is not None:
            tree.refresh()  # same topology and root: the instance records stay valid
        wp.launch(instance_box_kernel(), dim=self.data.n_inst, inputs=[self.data.insts], device=self.device)
        self.drop_bins()  # (the triangles moved)
        if tree is not None and (tree.balls is not None or tree.escape is not None or tree.cones is not None):
            tree.balls = None  # its interior balls no longer fit it (kept so for later builds too)
            tree.escape = None  # nor its escape horizons
            tree.frames = None
            tree.cones = None  # nor its normal cones
            tree.wide_cones = None
            rows = self.data.insts.numpy()
            for i, k in enumerate(self.instance_assets):
                if k == key:
                    rows["escape"][i] = 0
                    rows["frames"][i] = 0
            self.data.insts.assign(rows)
            self.refresh_balls()
        if any(isinstance(s, Mesh) and s.smooth for s in self.scene.shapes):
            faces = mesh.indices.numpy().reshape(-1, 3)
            vn = vertex_normals(mesh.points.numpy(), faces)
            self.assets[key] = (mesh, vn, tree)
            off = self.normal_offsets[key]
            all_n = self.data.normals.numpy()
            all_n[off:off + len(vn)] = vn
            self.data.normals.assign(all_n)

    def _analytic_bvh(self, d: SceneData, rows: dict[str, list[dict]], materials: list[Material]) -> None:
        """From ANALYTIC_BVH_MIN bounded analytic shapes on, one BVH (``accel``) over their bounds
        (spheres swept over their motion), each primitive tagged (kind, row)."""
        dev = self.device
        prims = [(kind, j, kind.bounds(row)) for kind in KINDS if kind.bounds is not None
                 for j, row in enumerate(rows[kind.table])]
        self.analytic_bvh = None
        d.bvh_root = -1
        d.bvh_nodes = wp.zeros(1, dtype=BvhNode, device=dev)
        d.bvh_prims = wp.zeros(1, dtype=wp.vec2i, device=dev)
        if len(prims) < ANALYTIC_BVH_MIN or "analytic_bvh" in self.fast_off:
            return
        # opaque rectangles in pieces (shapes.rect_pieces): a transparent one stays whole, so that a
        # shadow ray counts its crossing once
        # (warprt.fast: rect_pieces switched off, every rectangle whole)
        rect_kind = BY_TAG[KIND_RECT] if "rect_pieces" not in self.fast_off else None
        prims = [(kind, j, box) for kind, j, whole in prims
                 for box in (rect_pieces(rows[kind.table][j]) if kind is rect_kind and not any(
                     materials[rows[kind.table][j]["mat"]].transparency) else [whole])]
        with fast.timed("analytic_bvh"):
            tree = build_tree(*_padded([b for _, _, b in prims]))
        self.analytic_bvh = tree
        d.bvh_root = 0
        d.bvh_nodes = forest_nodes([tree], dev)
        tags = np.array([(kind.tag, j) for kind, j, _ in prims], dtype=np.int32)
        d.bvh_prims = wp.array(tags[tree[0]], dtype=wp.vec2i, device=dev)
        self._bvh_leaves = tags[tree[0]]

    def _light_buffers(self, d: SceneData, rows: dict[str, list[dict]], plights: list) -> list[dict]:
        """The point and directional lights' rows, with a light buffer (``accel.light_buffer``) for
        each point light of a CPU scene with an analytic BVH and no secondary rays (and
        ``light_buffers``) where one is worth it, while the scene's buffers hold at most
        ``accel.LB_MAX_ITEMS`` cells and entries; their arrays into ``d.lb_cells`` and
        ``d.lb_items``. A buffer boxes every shape of the BVH, a rectangle in pieces about as long
        as it is wide (a long bar's one box fills cells far beyond it), each box tagged with the
        shape's first primitive in ``bvh_prims``."""
        out = [dict(point_light_row(l), lb_cell0=-1, lb_res=0, lb_reach=0.0) for l in plights]
        cells, items = [], []
        room = accel.LB_MAX_ITEMS
        # (only camera packets' shading uses them: none in kernels with secondary rays)
        if (self.light_buffers and not self.features.secondary and wp.get_device(self.device).is_cpu
                and self.analytic_bvh is not None and any(isinstance(l, PointLight) for l in plights)):
            first = {}
            for j, (tag, row) in enumerate(self._bvh_leaves):
                first.setdefault((int(tag), int(row)), j)
            pieces = lambda kind, row: (rect_pieces(row, accel.LB_RECT_PIECES) if kind is BY_TAG[KIND_RECT]
                                        else [kind.bounds(row)])
            boxes = [(first[kind.tag, j], box) for kind in KINDS if kind.bounds is not None
                     for j, row in enumerate(rows[kind.table]) for box in pieces(kind, row)]
            lo, hi = _padded([b for _, b in boxes])
            ids = np.array([j for j, _ in boxes], dtype=np.int64)
            for rec, light in zip(out, plights):
                if not isinstance(light, PointLight):
                    continue
                with fast.timed("light_buffers"):
                    lb = light_buffer(light.position, lo, hi, ids, accel.LB_RES, room)
                if lb is not None:
                    c, it, reach = lb
                    rec.update(lb_cell0=sum(map(len, cells)), lb_res=accel.LB_RES, lb_reach=reach)
                    cells.append(c + sum(map(len, items)))
                    items.append(it)
                    room -= c.size + it.size
        for name, parts in (("lb_cells", cells), ("lb_items", items)):
            setattr(d, name, wp.array(np.concatenate(parts) if parts else np.zeros(1, np.int32), dtype=int,
                                      device=self.device))
        return out


def material_row(m: Material, emit, pool: TexturePool) -> dict:
    """A material's MatRec fields, its textures given rows of ``pool``."""
    return dict(ka=m.ka, kd=m.kd, ks=m.ks, p=m.p, km=m.mirror, kt=m.transparency, ior=m.ior,
                fresnel=FRESNEL_IDS[m.fresnel], gloss=m.glossy_exponent, frost=m.frosted_exponent, emit=emit,
                tex=pool.add(m.texture), tex_s=pool.add(m.specular_texture), tex_m=pool.add(m.mirror_texture))


def _padded(boxes: list) -> tuple[np.ndarray, np.ndarray]:
    """Boxes (lo, hi) as two float64 arrays, each widened by a relative margin: the float32
    rounding of the bounds must not cut off a hit."""
    lo = np.array([b[0] for b in boxes], dtype=np.float64)
    hi = np.array([b[1] for b in boxes], dtype=np.float64)
    pad = (hi - lo).max(axis=1, keepdims=True) * 1e-6 + np.maximum(np.abs(lo), np.abs(hi)).max(axis=1, keepdims=True) * 1e-6
    return lo - pad, hi + pad


def _light_regions(scene: Scene) -> list | None:
    """The boxes (lo, hi) holding every light's emitting points (area lights over their
    motion); None when one is unbounded (a light that no box holds). Directional lights have no
    point in the scene."""
    regions = []
    for light in scene.lights:
        if isinstance(light, DirectionalLight):
            continue
        if isinstance(light, PointLight):
            p = np.asarray(light.position, dtype=np.float64)
            regions.append((p, p))
            continue
        if not is_area_light(light):
            return None
        surface = light.shape()
        kind = BY_CLASS[type(surface)]
        if kind.bounds is None:
            return None
        lo, hi = kind.bounds(kind.row(surface, 0))
        regions.append((np.asarray(lo, dtype=np.float64), np.asarray(hi, dtype=np.float64)))
    return regions


def point_light_row(light) -> dict:
    """The PointLightRec fields of a point or directional light."""
    if isinstance(light, DirectionalLight):
        return dict(pos=tuple(-x for x in light.direction), intensity=light.intensity, inv_sq=FALLOFF_DIRECTIONAL)
    return dict(pos=light.position, intensity=light.intensity, inv_sq=int(light.falloff == "inverse_square"))


def render_params(scene: Scene, spp: int, seed: int, features: Features | None = None) -> RenderParams:
    """The render settings as the device record (``features``: the kernel's, for runtime guards)."""
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
    p.light_sampling = LIGHT_SAMPLING.index(s.light_sampling)
    p.aovs = 0  # (set by a render that asks for AOVs)
    return p
