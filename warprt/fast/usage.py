"""Which speed mechanisms a renderer's renders use (``in_use``): the rules the code applies,
read from the renderer's kernel choice and its scene records."""

from __future__ import annotations

import numpy as np

from . import MECHANISMS
from ..accel import HIT_PREFETCH_TRIANGLES
from ..records import KIND_RECT
from ..sampling import SAMPLER_IDS


def in_use(renderer) -> dict[str, bool]:
    """For every mechanism, whether ``renderer``'s renders run it, by the rules of
    ``Mechanism.applies``, from the records the build wrote (a table built, a field set) and the
    kernel chosen; a kernel-, render- or import-stage mechanism switched off for the renderer is
    not in use. Mechanisms whose work depends on the rays (a lane count reached, a lane in a box)
    count as used where the scene gives them that work to do."""
    built, F, scene = renderer.built, renderer.features, renderer.scene
    d = built.data
    cpu = renderer.device.is_cpu
    insts = d.insts.numpy() if d.n_inst else None
    any_inst = (lambda field: bool(insts is not None and np.any(insts[field] != 0)))
    alights = d.alights.numpy() if d.n_alights else None
    rect_lights = bool(alights is not None and np.any(alights["kind"] == KIND_RECT))
    packets = renderer.packets
    meshes = F.meshes and d.n_inst > 0
    shading = packets and not F.secondary
    shadow = shading and (d.n_plights > 0 or rect_lights)
    sobol = packets and SAMPLER_IDS[scene.render.sampler] == SAMPLER_IDS["sobol"]
    cam = scene.camera
    # (a camera at rest: the kernel's time is fixed unless the scene itself moves, whatever the kernel)
    still = not built.features.motion or (cam.shutter[1] <= cam.shutter[0] and cam.rolling_shutter == 0.0)
    mesh_packets = packets and meshes
    faces = [built.assets[key][2].n_faces if built.assets[key][2] is not None else 0 for key in built.instance_assets]
    prims = d.bvh_prims.numpy() if d.bvh_root >= 0 else np.zeros((0, 2), np.int32)
    use = {
        "camera_packets": packets,
        "analytic_packets": packets and (d.bvh_root >= 0 or (d.n_disks == 0 and not F.solids
                                                             and d.n_spheres + d.n_planes + d.n_rects > 0)),
        "mesh_packets": mesh_packets,
        "shading_packets": shading,
        "shadow_packets": shadow,
        "sobol_packets": sobol,
        "camera_packet_rays": sobol and still and cam.model == "pinhole",
        "column_blocks": cpu and meshes and cam.height >= 4,
        "analytic_bvh": d.bvh_root >= 0,
        "rect_pieces": len(prims) > len({(int(k), int(i)) for k, i in prims}),
        "light_buffers": bool(d.n_plights and np.any(d.plights.numpy()["lb_cell0"] >= 0)),
        "mesh_trees": any_inst("tree_nodes"),
        "wide_tree": any_inst("wide") and (mesh_packets or (shadow and any_inst("shadow_packets"))),
        "mesh_shadow_packets": shadow and any_inst("shadow_packets") and any_inst("wide"),
        "camera_bins": any_inst("bins"),
        "interior_balls": any_inst("n_balls") and (d.n_plights > 0 or d.n_alights > 0),
        "normal_cones": any_inst("cones") and (d.n_plights > 0 or d.n_alights > 0),
        "escaping_faces": shadow and any_inst("escape"),
        "escape_horizons": shadow and any_inst("frames"),
        "hit_prefetch": mesh_packets and insts is not None and bool(np.any(
            (insts["prefetch"] != 0) & ((insts["bins"] != 0) | ((insts["wide"] != 0) & (np.asarray(faces) >= HIT_PREFETCH_TRIANGLES))))),
        "node_prefetch": any_inst("tree_nodes"),
        "row_claims": cpu,
        "row_blocks": cpu and cam.height > 1,
        "row_threads": cpu,
    }
    assert set(use) == set(MECHANISMS)
    # (build switches show in the records, camera packets in the kernel chosen; the others are read
    # in the kernel or per render: switched off, they are not used)
    blind = {name for name, m in MECHANISMS.items() if m.stage in ("kernel", "render", "import")}
    return {name: bool(v) and not (name in blind and name in renderer.fast_off) for name, v in use.items()}
