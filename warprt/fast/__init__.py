"""The registry of the CPU's speed mechanisms: what each one does, when it applies, and its off switch.

Every mechanism listed here only saves time: with it switched off the renderer takes another
path to the same numbers, and the image is bit-identical (``tests/test_fast_switches.py`` checks
each one; ``python -m benchmarks.ablation`` measures what each saves, switched off with everything
else on). The mechanisms' code stays where it is (``accel``, ``trace``, ``lights``,
``integrator``, ``build``, ``film``, ``render``); each reads its switch at the one place that
decides whether it runs.

Switching mechanisms off::

    with warprt.fast.disabled("light_buffers", "camera_bins"):
        r = warprt.Renderer(scene)                 # built without them
    r = warprt.Renderer(scene, fast_off=["light_buffers"])

or, for benchmarks and the command line, ``WARPRT_FAST_OFF=light_buffers,camera_bins``. A
``Renderer`` takes the switches in force when it is made (the environment's, every enclosing
``disabled``, and its ``fast_off``) and keeps them for its life. An unknown name is an error.

When a switch is read (``Mechanism.stage``):

* ``build``: by ``build.DeviceScene`` on the host (a table not built, a record field left 0);
* ``kernel``: in the render kernel, from one bit of ``SceneData.fast_off`` that the build sets
  (the kernel variant is the same, switched on or off);
* ``variant``: picks another render-kernel variant (camera packets: the one-by-one kernel CUDA
  runs);
* ``render``: by ``render.Renderer`` on the host, per render;
* ``import``: compiled in when ``warprt`` is imported (native snippets, or code that a run-time
  test would slow down), so only the environment variable switches it (set before Python starts).
"""

from __future__ import annotations

import contextlib
import contextvars
import os
import time
from dataclasses import dataclass

from ..errors import RenderError

ENV = "WARPRT_FAST_OFF"  # a comma-separated list of mechanisms to switch off

# bits of ``SceneData.fast_off``, the kernel-stage switches (1: switched off)
FAST_ANALYTIC_PACKETS = 1 << 0
FAST_MESH_PACKETS = 1 << 1
FAST_SHADING_PACKETS = 1 << 2
FAST_SOBOL_PACKETS = 1 << 3
FAST_CAMERA_PACKET_RAYS = 1 << 4
FAST_COLUMN_BLOCKS = 1 << 5


@dataclass(frozen=True)
class Mechanism:
    name: str
    description: str  # what it does, in a line
    applies: str  # when it runs: the rule today's code uses (device, counts, thresholds, features)
    switch: str  # where its switch is read
    stage: str  # when: "build", "kernel", "variant", "render" or "import" (see the module docstring)
    bit: int = 0  # its SceneData.fast_off bit (kernel stage)
    requires: tuple[str, ...] = ()  # mechanisms it runs inside: switched off, they take it with them


_LIST = (
    Mechanism("camera_packets", "camera rays 8 at a time (a pixel's, or the next pixels' too) in the packet kernel; "
              "off: the kernel that takes them one by one (CUDA's)",
              "CPU renders (integrator.packets_for); Renderer(packets=...) overrides it",
              "render.Renderer (packets_for)", "variant"),
    Mechanism("analytic_packets", "a camera packet's rays through the analytic BVH (or, without it, the spheres', "
              "planes' and rectangles' loops) together, 8 lanes a node (trace.trace_packet, accel.packet_node)",
              "camera packets of PACKET_MIN (3) rays or more; without a BVH only where the scene has no disks or solids",
              "trace.trace_packet", "kernel", FAST_ANALYTIC_PACKETS, ("camera_packets",)),
    Mechanism("mesh_packets", "a camera packet's rays through each mesh instance's bins or wide tree together "
              "(trace.mesh_packet: accel.mesh_bins_packet, mesh_tree_packet)",
              "camera packets of MESH_PACKET_MIN (5) rays or more in kernels with meshes",
              "integrator.render_pixels (mesh_packed)", "kernel", FAST_MESH_PACKETS, ("camera_packets",)),
    Mechanism("shading_packets", "a camera packet's shading points lit together: point_light_packet, "
              "rect_setup_packet / rect_draw_packet, diffuse_lanes, the sums (lights.point_lights_packet, "
              "area_lights_packet, film.packet_samples)",
              "camera packets in kernels without secondary rays",
              "integrator.render_pixels (shaded)", "kernel", FAST_SHADING_PACKETS, ("camera_packets",)),
    Mechanism("shadow_packets", "a shaded packet's shadow rays tested together (trace.occluded_packet); off: each "
              "lane's alone through trace.transmittance (trace.lanes_occluded)",
              "shading packets: point lights, and rectangle lights' lanes drawn by area (other emitters go alone)",
              "trace.occluded_packet (compiled in: a run-time test there slows the packets with everything on)",
              "import", requires=("shading_packets",)),
    Mechanism("sobol_packets", "a packet's Sobol points drawn for its 8 lanes at once (sampling.sobol_packet, "
              "sobol_split_setup / sobol_split_draw)",
              "camera packets with the sobol sampler (camera samples; area-light samples of shaded packets)",
              "integrator.render_pixels (sobol), lights.area_lights_packet", "kernel", FAST_SOBOL_PACKETS,
              ("camera_packets",)),
    Mechanism("camera_packet_rays", "a packet's 8 camera rays made at once (camera.camera_packet, lens_packet)",
              "Sobol packets and a pinhole or thin-lens camera at rest (from a field of view or intrinsics, no "
              "rolling shutter while something moves); the opencv, fisheye and orthographic models take "
              "camera.camera_ray lane by lane",
              "integrator.render_pixels", "kernel", FAST_CAMERA_PACKET_RAYS, ("sobol_packets",)),
    Mechanism("column_blocks", "a thread takes its block of 4 rows column by column, so that packets over several "
              "pixels cover 2 x 4 patches (integrator.render_kernel's sh)",
              "CPU kernels with meshes, a thread taking a whole block of SLICE_BLOCK (4) rows",
              "integrator.render_kernel", "kernel", FAST_COLUMN_BLOCKS, ("row_blocks", "row_threads")),
    Mechanism("analytic_bvh", "one BVH over the bounded analytic shapes (accel.build_tree) instead of their loops",
              "ANALYTIC_BVH_MIN (2) or more spheres, rectangles, disks and solids (area lights' surfaces included)",
              "build.DeviceScene._analytic_bvh", "build"),
    Mechanism("rect_pieces", "an opaque rectangle longer than it is wide enters the BVH as up to 8 boxes along "
              "its length (shapes.rect_pieces)",
              "opaque rectangles in the analytic BVH, longer than wide",
              "build.DeviceScene._analytic_bvh", "build", requires=("analytic_bvh",)),
    Mechanism("light_buffers", "a point light's cube of 6 x 128^2 cells listing the shapes a shadow ray from a cell's "
              "directions may meet (accel.light_buffer; looked up by geometry.light_cells)",
              "point lights of a CPU scene with an analytic BVH and no secondary rays, while the scene's buffers "
              "fit LB_MAX_ITEMS (2M cells and entries)",
              "build.DeviceScene._light_buffers", "build", requires=("analytic_bvh", "shadow_packets")),
    Mechanism("mesh_trees", "warprt's native traversal of a CPU copy of each mesh's tree (accel.MeshTree, "
              "mesh_tree_ray, mesh_tree_occluded); off: Warp's wp.mesh_query_ray (on the same leaves of one)",
              "CPU meshes whose tree has leaves of one triangle (Warp's build of bvh_leaf_size=1)",
              "build.DeviceScene (the instance records' tree fields)", "build"),
    Mechanism("wide_tree", "the tree copy's 4-wide form, through which packets go (accel.widen: mesh_tree_packet, "
              "mesh_tree_occluded_packet); off: those lanes go one by one",
              "CPU meshes with a tree copy", "build.DeviceScene (InstRec.wide)", "build", requires=("mesh_trees",)),
    Mechanism("mesh_shadow_packets", "a shaded packet's shadow rays through a mesh's wide tree together, each lane's "
              "interior balls first (trace.mesh_lanes_occluded, accel.mesh_tree_occluded_packet)",
              "meshes of SHADOW_PACKET_TRIANGLES (1024) or more, SHADOW_PACKET_MIN (4) lanes or more in its box",
              "build.DeviceScene (InstRec.shadow_packets)", "build", requires=("wide_tree", "shadow_packets")),
    Mechanism("camera_bins", "screen-space bins of a mesh's triangles seen from the eye, nearest first "
              "(accel.camera_bins; walked by mesh_bins_packet, mesh_bins_ray)",
              "CPU meshes of BINS_TRIANGLES (1024) or more; a pinhole camera at rest, t_min 0, an instance at rest "
              "that neither turns nor scales, every triangle in front; within BINS_MAX_ENTRIES; after a change of "
              "view, once rendered BINS_AFTER_RENDERS (2) times",
              "build.DeviceScene.refresh_bins", "build"),
    Mechanism("interior_balls", "balls inside a closed mesh: a shadow segment through one is blocked "
              "(accel.interior_balls, mesh_balls_hit)",
              "closed CPU meshes of BALLS_MIN_TRIANGLES (512) or more; camera and lights outside the instance's "
              "box, t_min 0, no keyframed camera, not in a batch",
              "accel.MeshTree.find_balls, build.DeviceScene.refresh_balls", "build"),
    Mechanism("normal_cones", "per tree child a cone of its triangles' normals: shadow rays skip subtrees they can "
              "only leave (accel.normal_cones)",
              "closed, consistently wound CPU meshes with a tree copy; the same rule as the interior balls",
              "accel.MeshTree.find_balls, build.DeviceScene.refresh_balls", "build", requires=("mesh_trees",)),
    Mechanism("escaping_faces", "faces behind whose plane the whole mesh lies: a shaded packet's shadow rays leaving "
              "them skip the mesh (accel.escape_sides, horizon_escapes)",
              "CPU meshes of up to ESCAPE_MAX_TRIANGLES (500k), shadow rays of shaded packets",
              "accel.MeshTree.find_balls", "build", requires=("shadow_packets",)),
    Mechanism("escape_horizons", "per face, side and 8 azimuth sectors a bound on the elevation of the rest of the "
              "mesh, with the sectors' frames (accel.escape_horizons, escape_frames); off: the escaping faces alone",
              "CPU meshes of up to HORIZON_MAX_TRIANGLES (8192) with a tree copy",
              "accel.MeshTree.find_balls (escape_horizons' bounds)", "build", requires=("escaping_faces",)),
    Mechanism("hit_prefetch", "the hit triangles' corners prefetched for the 8 lanes at once (mesh_tree_packet on "
              "large meshes, mesh_bins_packet on any)",
              "tree packets on meshes of HIT_PREFETCH_TRIANGLES (65536) or more; every bins packet",
              "build.DeviceScene (InstRec.prefetch)", "build", requires=("mesh_packets",)),
    Mechanism("node_prefetch", "every mesh traversal prefetches a node's children's boxes (or a leaf's triangle) "
              "while it tests the node (accel._PREFETCH, the wide visit's)",
              "CPU traversals of the tree copy (rays, shadow rays, packets)",
              "accel (its snippets, when warprt is imported)", "import", requires=("mesh_trees",)),
    Mechanism("row_claims", "each worker's launch claims the next block of rows from a counter in the film "
              "(film.claim_block); off: fixed interleaved slices, SLICES_PER_WORKER a worker, from a queue",
              "CPU renders without slices=, a thread taking whole rows",
              "render.Renderer._passes", "render", requires=("row_threads",)),
    Mechanism("row_blocks", "a thread takes SLICE_BLOCK (4) consecutive rows (a block) at a time; off: one row",
              "CPU renders, a thread taking whole rows", "render.Renderer._passes", "render",
              requires=("row_threads",)),
    Mechanism("row_threads", "a CPU thread takes a whole row (render.pixels_per_thread: a launch copies its "
              "arguments once per thread); off: one pixel a thread",
              "CPU renders", "render.Renderer._passes", "render"),
)
MECHANISMS: dict[str, Mechanism] = {m.name: m for m in _LIST}

_disabled: contextvars.ContextVar[frozenset] = contextvars.ContextVar("warprt_fast_disabled", default=frozenset())
# host seconds spent building each mechanism's tables in this process (``timed``; the benchmark reads it)
build_times: dict[str, float] = {}


def names() -> list[str]:
    """Every mechanism's name, in the registry's order."""
    return list(MECHANISMS)


def check(names_, where: str = "fast_off") -> frozenset:
    """The names as a set, each a known mechanism (else a ``RenderError`` naming ``where``)."""
    if isinstance(names_, str):
        names_ = [names_]
    out = frozenset(n.strip() for n in names_ if n.strip())
    unknown = sorted(out - set(MECHANISMS))
    if unknown:
        raise RenderError(f"{where}: unknown speed mechanism{'s' if len(unknown) > 1 else ''} "
                          f"{', '.join(map(repr, unknown))}; known: {', '.join(MECHANISMS)}")
    return out


def from_environment() -> frozenset:
    """The mechanisms ``WARPRT_FAST_OFF`` switches off."""
    return check(os.environ.get(ENV, "").split(","), ENV)


def current(extra=()) -> frozenset:
    """The mechanisms switched off now: the environment's, every enclosing ``disabled``'s, and
    ``extra``'s (checked), with those that run inside them (``Mechanism.requires``)."""
    off = from_environment() | _disabled.get() | check(extra)
    import_off = from_environment()
    late = sorted(n for n in off - import_off if MECHANISMS[n].stage == "import")
    if late:
        raise RenderError(f"{', '.join(late)} is compiled in when warprt is imported: set {ENV}={','.join(late)} "
                          "before Python starts")
    return closure(off)


def closure(off) -> frozenset:
    """``off`` and every mechanism that requires one of them, recursively."""
    out = set(off)
    changed = True
    while changed:
        changed = False
        for m in _LIST:
            if m.name not in out and any(r in out for r in m.requires):
                out.add(m.name)
                changed = True
    return frozenset(out)


@contextlib.contextmanager
def disabled(*names_):
    """Switch mechanisms off for the renderers made inside the block."""
    token = _disabled.set(_disabled.get() | check(names_, "warprt.fast.disabled"))
    try:
        yield
    finally:
        _disabled.reset(token)


def import_off(name: str) -> bool:
    """Whether an import-stage mechanism is switched off (by the environment, read at import)."""
    assert MECHANISMS[name].stage == "import"
    return name in from_environment()


def kernel_bits(off) -> int:
    """``SceneData.fast_off`` for the mechanisms ``off``."""
    bits = 0
    for name in off:
        bits |= MECHANISMS[name].bit
    return bits


@contextlib.contextmanager
def timed(name: str):
    """Add the block's host seconds to ``build_times[name]``."""
    t0 = time.perf_counter()
    try:
        yield
    finally:
        build_times[name] = build_times.get(name, 0.0) + time.perf_counter() - t0
