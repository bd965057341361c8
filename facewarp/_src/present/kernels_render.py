"""Warp kernels of the preview renderer (:mod:`facewarp._src.render`).

One kernel: an orthographic ray cast, one ray per (supersampled) pixel of a window of the
image (the caller fills the rest, which no ray can hit, with the background), against a
``wp.Mesh`` BVH, shaded with two-sided Lambert plus ambient light; the albedo is the corner
colours interpolated, or for the first ``textured_count`` triangles a bilinear texture sample
at the interpolated corner UVs.
"""

from __future__ import annotations

import warp as wp


# Shading of one hit (two-sided Lambert, smooth normals):
#   n_s = u n_a + v n_b + (1 - u - v) n_c            (Warp's barycentric convention)
#   n_s <- -n_s  if the ray hits the back of the triangle (n_g . d > 0), so a
#                surface seen through a hole (eyes, mouth) is lit like its front
#   c   = albedo * (ambient + diffuse * max(0, n_s . l))
# The flip follows the geometric normal n_g, not n_s: near a silhouette an interpolated
# normal may point slightly away from the viewer and must stay unlit rather than flip.
# Inside: the back of one of the first ``inside_count`` triangles (a closed-ish surface seen
# from within, e.g. the head through an open mouth) is drawn flat in ``inside_color``.
# Texture lookup: st in [0, 1]^2 with v up; row 0 of the texture is v = 1. Bilinear between the
# four texel centres around (x, y) = (s w - 1/2, (1 - t) h - 1/2), clamped at the borders.
@wp.func
def _bilinear(texture: wp.array2d(dtype=wp.vec3), st: wp.vec2):
    h = texture.shape[0]
    w = texture.shape[1]
    x = wp.clamp(st[0], 0.0, 1.0) * float(w) - 0.5
    y = (1.0 - wp.clamp(st[1], 0.0, 1.0)) * float(h) - 0.5
    x0 = int(wp.floor(x))
    y0 = int(wp.floor(y))
    fx = x - float(x0)
    fy = y - float(y0)
    xa = wp.clamp(x0, 0, w - 1)
    xb = wp.clamp(x0 + 1, 0, w - 1)
    ya = wp.clamp(y0, 0, h - 1)
    yb = wp.clamp(y0 + 1, 0, h - 1)
    top = texture[ya, xa] * (1.0 - fx) + texture[ya, xb] * fx
    bottom = texture[yb, xa] * (1.0 - fx) + texture[yb, xb] * fx
    return top * (1.0 - fy) + bottom * fy


@wp.func
def _smooth_normal(indices: wp.array(dtype=wp.int32), vertex_normals: wp.array(dtype=wp.vec3), f: int, u: float,
                   v: float, geometric: wp.vec3):
    """The hit's interpolated vertex normal n_s (unit; the geometric normal where it vanishes), not yet flipped."""
    a = indices[3 * f + 0]
    b = indices[3 * f + 1]
    c = indices[3 * f + 2]
    n = u * vertex_normals[a] + v * vertex_normals[b] + (1.0 - u - v) * vertex_normals[c]
    n_len = wp.length(n)
    if n_len > 1.0e-12:
        return n / n_len
    return geometric


@wp.kernel
def _cast_rays(
    # Scene:
    mesh: wp.uint64,
    indices: wp.array(dtype=wp.int32),
    vertex_normals: wp.array(dtype=wp.vec3),
    corner_colors: wp.array(dtype=wp.vec3),
    corner_uvs: wp.array(dtype=wp.vec2),
    texture: wp.array2d(dtype=wp.vec3),
    textured_count: int,
    inside_count: int,
    inside_color: wp.vec3,
    # Camera (the launch covers rows row0.., columns col0.. of the image):
    row0: int,
    col0: int,
    origin: wp.vec3,
    step_right: wp.vec3,
    step_down: wp.vec3,
    forward: wp.vec3,
    max_depth: float,
    # Lights:
    light_dir: wp.vec3,
    ambient: float,
    diffuse: float,
    background: wp.vec3,
    # Image out:
    color_out: wp.array2d(dtype=wp.vec3),
    depth_out: wp.array2d(dtype=float),
):
    i, j = wp.tid()
    i = i + row0
    j = j + col0
    start = origin + (float(j) + 0.5) * step_right + (float(i) + 0.5) * step_down
    hit = wp.mesh_query_ray(mesh, start, forward, max_depth)
    if not hit.result:
        color_out[i, j] = background
        depth_out[i, j] = max_depth
        return

    f = hit.face
    u = hit.u
    v = hit.v
    w = 1.0 - u - v
    n = _smooth_normal(indices, vertex_normals, f, u, v, hit.normal)
    if wp.dot(hit.normal, forward) > 0.0:
        if f < inside_count:
            color_out[i, j] = inside_color
            depth_out[i, j] = hit.t
            return
        n = -n

    albedo = u * corner_colors[3 * f + 0] + v * corner_colors[3 * f + 1] + w * corner_colors[3 * f + 2]
    if f < textured_count:
        st = u * corner_uvs[3 * f + 0] + v * corner_uvs[3 * f + 1] + w * corner_uvs[3 * f + 2]
        albedo = _bilinear(texture, st)
    shade = ambient + diffuse * wp.max(wp.dot(n, light_dir), 0.0)
    color_out[i, j] = albedo * shade
    depth_out[i, j] = hit.t


# The same ray cast in two steps, for several pictures of one scene from one camera that differ
# only in the corner colours (heat maps of different values on one head): ``_cast_hits`` once
# (the hit triangle, its barycentric u, v, the shading factor, the depth), then ``_shade_hits``
# per colour set. Each value is computed by the same expressions as in ``_cast_rays``
# (no texture, no inside colour), so the pixels are the same (a test compares them).
@wp.kernel
def _cast_hits(
    mesh: wp.uint64,
    indices: wp.array(dtype=wp.int32),
    vertex_normals: wp.array(dtype=wp.vec3),
    row0: int,
    col0: int,
    origin: wp.vec3,
    step_right: wp.vec3,
    step_down: wp.vec3,
    forward: wp.vec3,
    max_depth: float,
    light_dir: wp.vec3,
    ambient: float,
    diffuse: float,
    face_out: wp.array2d(dtype=wp.int32),
    u_out: wp.array2d(dtype=float),
    v_out: wp.array2d(dtype=float),
    shade_out: wp.array2d(dtype=float),
    depth_out: wp.array2d(dtype=float),
):
    i, j = wp.tid()
    i = i + row0
    j = j + col0
    start = origin + (float(j) + 0.5) * step_right + (float(i) + 0.5) * step_down
    hit = wp.mesh_query_ray(mesh, start, forward, max_depth)
    if not hit.result:
        face_out[i, j] = -1
        depth_out[i, j] = max_depth
        return

    f = hit.face
    u = hit.u
    v = hit.v
    n = _smooth_normal(indices, vertex_normals, f, u, v, hit.normal)
    if wp.dot(hit.normal, forward) > 0.0:
        n = -n
    face_out[i, j] = f
    u_out[i, j] = u
    v_out[i, j] = v
    shade_out[i, j] = ambient + diffuse * wp.max(wp.dot(n, light_dir), 0.0)
    depth_out[i, j] = hit.t


@wp.kernel
def _shade_hits(
    face: wp.array2d(dtype=wp.int32),
    u_in: wp.array2d(dtype=float),
    v_in: wp.array2d(dtype=float),
    shade_in: wp.array2d(dtype=float),
    corner_colors: wp.array(dtype=wp.vec3),
    background: wp.vec3,
    color_out: wp.array2d(dtype=wp.vec3),
):
    i, j = wp.tid()
    f = face[i, j]
    if f < 0:
        color_out[i, j] = background
        return
    u = u_in[i, j]
    v = v_in[i, j]
    w = 1.0 - u - v
    albedo = u * corner_colors[3 * f + 0] + v * corner_colors[3 * f + 1] + w * corner_colors[3 * f + 2]
    shade = shade_in[i, j]
    color_out[i, j] = albedo * shade
