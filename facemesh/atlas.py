"""Repack a face mesh's texture into a compact atlas with xatlas (``facemesh build --atlas``).

The cropped photo wastes texels on the background around the face and packs
the face's sides (seen at a slant) into few pixels. xatlas cuts the surface
into charts, unfolds them with little distortion and packs them tightly at the
face's own texel density (the median texture pixels per mm of the source);
each chart is then baked from the photo, triangle by triangle (an affine
warp per triangle, bilinear), and the gutters between charts are filled
from the charts' borders so that bilinear sampling does not bleed.

Vertex order is kept: vertex i (i < N) is still landmark i. A vertex on a
chart seam needs a second uv, so a copy of it is appended after the N
originals; ``mesh.extras["atlas"]["duplicate_of"]`` lists, for each appended
vertex, the landmark it copies.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import numpy as np

from .conventions import uv_to_pixels
from .types import FaceMesh, InputError

__all__ = ["atlas_mesh", "texel_density"]


def _import_xatlas() -> Any:
    try:
        import xatlas  # noqa: PLC0415
    except ImportError as exc:
        raise ImportError(f"the texture atlas needs xatlas: pip install xatlas ({exc})") from exc
    return xatlas


def texel_density(mesh: FaceMesh) -> float:
    """Median texture pixels per millimetre over the mesh's triangles."""
    th, tw = mesh.texture.shape[:2]
    px = uv_to_pixels(mesh.uv, (tw, th))[mesh.triangles]
    mm = np.asarray(mesh.vertices_mm)[mesh.triangles]
    a_px = 0.5 * np.abs(np.cross(px[:, 1] - px[:, 0], px[:, 2] - px[:, 0]))
    a_mm = 0.5 * np.linalg.norm(np.cross(mm[:, 1] - mm[:, 0], mm[:, 2] - mm[:, 0]), axis=1)
    ok = (a_mm > 1e-6) & (a_px > 1e-6)
    if not ok.any():
        raise InputError("atlas: the mesh has no triangle with an area")
    return float(np.median(np.sqrt(a_px[ok] / a_mm[ok])))


def atlas_mesh(mesh: FaceMesh, *, padding_px: int = 2) -> FaceMesh:
    """The same mesh with its texture repacked into an xatlas atlas (see the module docstring).

    Args:
        mesh: a face mesh (vertex i = landmark i).
        padding_px: gutter between charts, pixels.

    Returns:
        A new :class:`FaceMesh`: N + D vertices (D seam copies appended), the
        same triangles in the same order (indices into the new vertices), the
        atlas as texture (``texture_origin_px`` (0, 0)), and
        ``extras["atlas"] = {"size": [W, H], "duplicate_of": [...], "texels_per_mm": d,
        "source_texture_size": [w, h]}``.
    """
    import cv2

    xatlas = _import_xatlas()
    if mesh.num_triangles == 0:
        raise InputError("atlas: the mesh has no triangles")
    n = mesh.num_vertices
    density = texel_density(mesh)
    atlas = xatlas.Atlas()
    atlas.add_mesh(np.asarray(mesh.vertices_mm, dtype=np.float32), np.asarray(mesh.triangles, dtype=np.uint32))
    pack = xatlas.PackOptions()
    pack.texels_per_unit = density
    pack.padding = int(padding_px)
    pack.bilinear = True
    atlas.generate(pack_options=pack)
    vmap, idx, uvs = atlas.get_mesh(0)
    aw, ah = int(atlas.width), int(atlas.height)
    if len(idx) != mesh.num_triangles:
        raise InputError(f"atlas: xatlas returned {len(idx)} triangles for {mesh.num_triangles}")
    # keep vertex i = landmark i: the first copy of each original takes its index, others go after N
    vmap = np.asarray(vmap, dtype=np.int64)
    final = np.empty(len(vmap), dtype=np.int64)
    taken = np.zeros(n, dtype=bool)
    dup_of: list[int] = []
    for j, src in enumerate(vmap):
        if not taken[src]:
            final[j] = src
            taken[src] = True
        else:
            final[j] = n + len(dup_of)
            dup_of.append(int(src))
    if not taken.all():
        raise InputError(f"atlas: {int((~taken).sum())} vertices are in no triangle")
    order = np.argsort(final)
    uv_new = np.asarray(uvs, dtype=np.float64)[order]  # xatlas: normalized [0, 1] texture coordinates
    vertices = np.concatenate([np.asarray(mesh.vertices_mm), np.asarray(mesh.vertices_mm)[dup_of]])
    triangles = final[np.asarray(idx, dtype=np.int64)]
    # xatlas keeps the input triangles' order and corner order: check it (mapped back to landmarks)
    back = np.concatenate([np.arange(n), np.asarray(dup_of, dtype=np.int64)])
    if not np.array_equal(back[triangles], np.asarray(mesh.triangles)):
        raise InputError("atlas: xatlas reordered the triangles or their corners")
    # bake: each atlas triangle from its source triangle in the photo crop
    th, tw = mesh.texture.shape[:2]
    src_px = uv_to_pixels(mesh.uv, (tw, th))[np.asarray(mesh.triangles)].astype(np.float32)
    dst_px = uv_to_pixels(uv_new, (aw, ah))[triangles].astype(np.float32)
    out = np.zeros((ah, aw, 3), dtype=np.uint8)
    filled = np.zeros((ah, aw), dtype=np.uint8)
    tex = np.ascontiguousarray(mesh.texture)
    for s, d in zip(src_px, dst_px):
        x0, y0 = np.floor(d.min(axis=0)).astype(int) - 1
        x1, y1 = np.ceil(d.max(axis=0)).astype(int) + 2
        x0, y0, x1, y1 = max(x0, 0), max(y0, 0), min(x1, aw), min(y1, ah)
        if x1 <= x0 or y1 <= y0:
            continue
        local = d - np.array([x0, y0], dtype=np.float32)
        m = cv2.getAffineTransform(local, s)  # atlas ROI pixel -> source pixel
        patch = cv2.warpAffine(
            tex, m, (x1 - x0, y1 - y0), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP, borderMode=cv2.BORDER_REPLICATE
        )
        mask = np.zeros((y1 - y0, x1 - x0), dtype=np.uint8)
        cv2.fillConvexPoly(mask, np.round(local * 16).astype(np.int32), (1,), lineType=cv2.LINE_AA, shift=4)
        cv2.fillConvexPoly(mask, np.round(local).astype(np.int32), (1,))
        roi = out[y0:y1, x0:x1]
        sel = mask > 0
        roi[sel] = patch[sel]
        filled[y0:y1, x0:x1] |= mask
    # fill the gutters from the charts' borders (dilation), so bilinear reads near edges stay on the face
    known = filled > 0
    for _ in range(max(2, padding_px + 1)):
        grown = cv2.dilate(out, np.ones((3, 3), np.uint8))
        grown_mask = cv2.dilate(known.astype(np.uint8), np.ones((3, 3), np.uint8)) > 0
        new = grown_mask & ~known
        out[new] = grown[new]
        known = grown_mask
    extras = dict(mesh.extras)
    extras["atlas"] = {
        "size": [aw, ah],
        "duplicate_of": dup_of,
        "texels_per_mm": density,
        "source_texture_size": [tw, th],
    }
    return replace(
        mesh, vertices_mm=vertices, triangles=triangles, uv=uv_new, texture=out, texture_origin_px=(0, 0), extras=extras
    )
