"""Scenes of several objects (glTF/GLB files, ``trimesh.Scene``): one warprt mesh shape per node.

``Mesh(file="x.glb")`` flattens a file into one mesh with one material. :func:`load_assets` keeps
its structure: every node that holds a triangle mesh becomes a :class:`warprt.Mesh` with that
node's world transform (taken apart by :meth:`Transform.from_matrix`) and a warprt material
made from the node's glTF material. Nodes that show the same glTF mesh get the same vertex and
face arrays, so the builder makes one ``wp.Mesh`` (one BVH) for them and instances it.

glTF PBR metallic-roughness → warprt's Phong/mirror/glossy material (base colour b, metallic m,
roughness r; glTF colours are linear, as warprt's are):

* b = ``baseColorFactor`` (RGB; alpha is ignored), B(uv) the base-colour texture (its texels
  decoded from sRGB to linear once, at load; 1 where there is none), M(uv) the metallic map (the
  blue channel of ``metallicRoughnessTexture``, linear data; 1 where there is none), m =
  ``metallicFactor``;
* ``kd`` = b·(1 − m) (and ``ka`` = kd), times ``texture`` = B: the dielectric part is Lambertian;
* ``mirror`` = b·m, times ``mirror_texture`` = B: the metallic part reflects, tinted by the base
  colour (the same texture as kd's: one texture in the renderer's pool);
* with a metallic map the split varies over the surface: ``kd`` = b and ``mirror`` = b with the
  textures B·(1 − m·M) and B·m·M, baked at load at the base texture's resolution (the metallic
  map resampled bilinearly to it where the two differ);
* the mesh's UVs come from the file through trimesh (TEXCOORD_0, flipped by trimesh from glTF's
  top-left origin to OBJ's bottom-left one, warprt's convention);
* ``glossy_exponent``: with α = r², Walter et al.'s Blinn-Phong exponent 2/α² − 2 is a lobe about
  the half vector; about the mirror direction (angles twice as large) it is n = (2/α² − 2)/4,
  clamped to n ≥ 1; r = 0 or n ≥ 1e5 (a lobe narrower than 0.3°) is a perfect mirror (0);
* ``ks`` = 0: the dielectric's 4 % Fresnel highlight is not mapped, and a metal's highlight comes
  from its reflection (area lights are seen in reflections, point lights are not);
* an OBJ/MTL material (trimesh's ``SimpleMaterial``): ``Kd`` and ``map_Kd`` are the base colour,
  metallic 0;
* ``emissiveFactor`` ≠ 0: warprt has no emissive surfaces (an area light is a light, not a
  material), so it is ignored with a warning; add an area light where the glTF glows;
* vertex colours, the roughness map (the factor is used), normal/occlusion maps, alpha and
  transmission are not read; a texture on a mesh without UVs is dropped with a warning (its mean
  colour multiplies the factor instead).
"""

from __future__ import annotations

import os
import warnings
from dataclasses import replace
from typing import Any

import numpy as np

from ..colour import srgb_to_linear
from ..errors import SceneError
from .description import DEFAULT_MATERIAL, Material, Mesh
from .texture import Texture
from .transform import Transform, as_transform

GLOSSY_LIMIT = 1e5  # Phong exponents at least this large are a perfect mirror (glossy_exponent 0)


def pbr_material(base, metallic: float, roughness: float) -> Material:
    """The warprt material of a glTF metallic-roughness material (see the module docstring)."""
    b = np.clip(np.asarray(base, dtype=np.float64)[:3], 0.0, None)
    m = min(max(float(metallic), 0.0), 1.0)
    r = min(max(float(roughness), 0.0), 1.0)
    alpha = r * r
    n = 0.0 if alpha == 0.0 else max(1.0, (2.0 / (alpha * alpha) - 2.0) / 4.0)
    if n >= GLOSSY_LIMIT:
        n = 0.0
    return Material(kd=tuple(b * (1.0 - m)), ks=0.0, mirror=tuple(b * m), glossy_exponent=n)


def _texels(image: Any, srgb: bool) -> np.ndarray:
    """A PIL image's RGB texels as linear float values (H, W, 3), row 0 the top."""
    a = np.asarray(image.convert("RGB"), dtype=np.float64) / 255.0
    return srgb_to_linear(a) if srgb else a


def base_colour(mat: Any) -> np.ndarray:
    """glTF base colour factor (linear RGB)."""
    factor = getattr(mat, "baseColorFactor", None)
    b = np.ones(3) if factor is None else np.asarray(factor, dtype=np.float64)[:3]
    if factor is not None and np.asarray(factor).dtype.kind in "ui":  # trimesh keeps it as uint8
        b = b / 255.0
    return b


def _material_of(geom: Any, where: str, has_uv: bool) -> Material | None:
    mat = getattr(getattr(geom, "visual", None), "material", None)
    if mat is None:
        return None
    simple = not hasattr(mat, "metallicFactor") and hasattr(mat, "to_pbr")
    if simple:
        mat = mat.to_pbr()  # an OBJ/MTL SimpleMaterial: its Kd (and map_Kd) as the base colour
    emissive = getattr(mat, "emissiveFactor", None)
    if emissive is not None and np.any(np.asarray(emissive, dtype=np.float64) > 0):
        warnings.warn(f"{where}: material {getattr(mat, 'name', None)!r} is emissive; warprt surfaces do not "
                      "emit (use an area light), the emission is ignored", stacklevel=4)
    metallic = getattr(mat, "metallicFactor", None)
    roughness = getattr(mat, "roughnessFactor", None)
    # glTF's defaults when a factor is absent: metallic 1, roughness 1
    # (an OBJ/MTL material is a dielectric: not metallic)
    m = (0.0 if simple else 1.0) if metallic is None else min(max(float(metallic), 0.0), 1.0)
    r = 1.0 if roughness is None else roughness
    b = base_colour(mat)
    base_tex = getattr(mat, "baseColorTexture", None)
    mr_tex = getattr(mat, "metallicRoughnessTexture", None)
    if (base_tex is not None or mr_tex is not None) and not has_uv:
        warnings.warn(f"{where}: material {getattr(mat, 'name', None)!r} has textures but the mesh has no UVs; "
                      "the base colour texture's mean colour is used", stacklevel=4)
        if base_tex is not None:
            b = b * _texels(base_tex, True).reshape(-1, 3).mean(axis=0)
        base_tex = mr_tex = None
    out = pbr_material(b, m, r)
    if mr_tex is not None:
        metal = _texels(mr_tex, False)[..., 2:3]
        base = np.ones_like(metal) if base_tex is None else _texels(base_tex, True)
        if base_tex is not None and metal.shape[:2] != base.shape[:2]:
            from PIL import Image

            metal = np.asarray(mr_tex.convert("RGB").resize(base_tex.size, Image.BILINEAR),
                               dtype=np.float64)[..., 2:3] / 255.0
        mm = m * metal
        return replace(out, kd=tuple(b), ka=tuple(b), mirror=tuple(b), texture=Texture(image=base * (1.0 - mm)),
                       mirror_texture=Texture(image=base * mm))
    if base_tex is not None:
        tex = Texture(image=_texels(base_tex, True))
        return replace(out, texture=tex, mirror_texture=tex if m > 0.0 else None)
    return out


def _node_transform(matrix: np.ndarray, where: str) -> Transform | None:
    """The node's world matrix as a Transform, or None when it shears (then the vertices are
    transformed on the host)."""
    try:
        return Transform.from_matrix(matrix, where, allow_mirror=True)
    except SceneError as e:
        if "shear" in e.problem:
            return None
        raise


def load_assets(source: Any, transform: Any = None, *, smooth: bool = False, material: str | None = None,
                prefix: str = "", degenerate: str = "error",
                unsupported: str = "error") -> tuple[list[Mesh], dict[str, Material]]:
    """Load a glTF/GLB file (or any file trimesh reads as a scene, or a ``trimesh.Scene``) as
    warprt shapes: ``(meshes, materials)``, one :class:`warprt.Mesh` per node holding a triangle
    mesh, in the order of trimesh's node list, and the materials they name.

    ``transform`` (a :class:`Transform` or a table) is applied to the whole asset, after each
    node's own transform. ``material`` gives every node that material name instead of its own
    (then no materials are returned). Material names are ``prefix`` + the glTF material's name (a
    clash of two different materials adds ``_2``, ``_3``...); a node without a material uses
    warprt's ``"default"``. ``smooth`` and ``degenerate`` are passed to every mesh. A node with
    points or lines raises SceneError, or with ``unsupported="skip"`` is left out with a
    warning. A node whose world matrix shears (non-uniform scale under a rotated parent) cannot
    be an instance pose: its vertices are transformed on the host into an asset of its own.
    """
    import trimesh

    if unsupported not in ("error", "skip"):
        raise SceneError(f"must be 'error' or 'skip', got {unsupported!r}", "unsupported")
    if not isinstance(prefix, str):
        raise SceneError(f"expected a string, got {prefix!r}", "prefix")
    if material is not None and (not isinstance(material, str) or not material):
        raise SceneError(f"expected a material name, got {material!r}", "material")
    outer = as_transform(transform, "transform")
    if isinstance(source, (str, os.PathLike)):
        path = os.fspath(source)
        if not os.path.isfile(path):
            raise SceneError(f"asset file not found: {path!r}", "file")
        try:
            scene = trimesh.load(path, force="scene", process=False)
        except Exception as e:  # trimesh raises many types for unreadable files
            raise SceneError(f"cannot read asset file {os.path.basename(path)!r}: {e}", "file") from None
    elif isinstance(source, trimesh.Scene):
        scene = source
    elif isinstance(source, trimesh.Trimesh):
        scene = trimesh.Scene(source)
    else:
        raise SceneError(f"expected a file path or a trimesh.Scene, got {type(source).__name__}", "file")

    outer_m = np.eye(4) if outer is None else outer.matrix()
    arrays: dict[str, tuple[np.ndarray, np.ndarray]] = {}  # per glTF mesh: shared by its nodes
    mats: dict[str, Material] = {}
    mat_names: dict[int, str] = {}
    shapes: list[Mesh] = []
    for node in scene.graph.nodes_geometry:
        matrix, gname = scene.graph[node]
        geom = scene.geometry[gname]
        where = f"node {node!r}"
        if not isinstance(geom, trimesh.Trimesh):
            kind = {"PointCloud": "points", "Path3D": "lines", "Path2D": "lines"}.get(type(geom).__name__,
                                                                                   type(geom).__name__)
            if unsupported == "skip":
                warnings.warn(f"{where}: skipping {kind} ({type(geom).__name__}); only triangle meshes render",
                              stacklevel=2)
                continue
            raise SceneError(f"{where} holds {kind} ({type(geom).__name__}), not triangles; warprt renders "
                             "triangle meshes only (unsupported=\"skip\" leaves such nodes out)", "file")
        if len(geom.faces) == 0:
            continue
        if gname not in arrays:
            uv = getattr(geom.visual, "uv", None)
            uv = None if uv is None or len(uv) != len(geom.vertices) else np.asarray(uv, dtype=np.float64)
            arrays[gname] = (np.asarray(geom.vertices, dtype=np.float64), np.asarray(geom.faces, dtype=np.int64), uv)
        v, f, uv = arrays[gname]
        world = outer_m @ np.asarray(matrix, dtype=np.float64)
        pose = _node_transform(world, where)
        if pose is None:
            warnings.warn(f"{where}: its world matrix shears; its vertices are transformed on the host "
                          f"(an asset of its own)", stacklevel=2)
            v = v @ world[:3, :3].T + world[:3, 3]
        # which material: the override, the node's own (named after it), or warprt's default
        name = material
        if name is None:
            key = id(getattr(geom.visual, "material", None))
            if key in mat_names:
                name = mat_names[key]
            else:
                warp_mat = _material_of(geom, where, uv is not None)
                if warp_mat is None:
                    name = DEFAULT_MATERIAL
                else:
                    base = prefix + (getattr(geom.visual.material, "name", None) or "material")
                    name, k = base, 1
                    while name in mats and mats[name] != warp_mat:
                        k += 1
                        name = f"{base}_{k}"
                    mats[name] = warp_mat
                mat_names[key] = name
        try:
            shapes.append(Mesh(vertices=v, faces=f, material=name, transform=pose, smooth=smooth,
                               degenerate=degenerate, uv=uv))
        except SceneError as e:
            raise SceneError(f"{where}: {e.problem}", e.field) from None
    if not shapes:
        raise SceneError("the asset holds no triangle meshes", "file")
    return shapes, mats


__all__ = ["GLOSSY_LIMIT", "base_colour", "load_assets", "pbr_material"]
