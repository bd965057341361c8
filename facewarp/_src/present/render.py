"""Headless software renderer for PNG previews and heat maps.

A small Warp ray caster: the triangles of the scene go into one ``wp.Mesh`` BVH, an
orthographic camera shoots one ray per pixel of a 2x supersampled image
(:func:`facewarp._src.kernels_render._cast_rays`), points and polylines are stamped on
top with a depth test, and the image is box-filtered down to the requested size.

Conventions (SI units): y is up, +z is the face's forward direction, +x is the subject's
left. A view is an (azimuth, elevation) pair in degrees: the camera sits in direction
``(sin az cos el, sin el, cos az cos el)`` from the scene centre and looks back at it, with
world y as the image's up.

- ``"front"`` = (0, 0): the camera is in front of the face and looks along -z. As when you
  look at a person, the subject's left (+x) appears on the image's right; nothing is mirrored.
- ``"side"`` = (90, 0): the camera is at the subject's left (+x) and looks along -x; the
  profile faces the image's left (+z is drawn to the left). Use ``(-90, 0)`` for the other
  side, whose profile faces right.
- ``"three_quarter"`` = (35, 10): between the two, from slightly above.

Light: a key light from the upper front (fixed relative to the camera, from the viewer's
upper left) plus ambient, two-sided Lambert, smooth normals interpolated from area-weighted
vertex normals with the hit's barycentric coordinates.
"""

from __future__ import annotations

import contextlib
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from ..core.warp import get_warp
from ..core.errors import InputError
from ..core.fileio import atomic_write
from ..geometry.surface import vertex_normals

VIEWS: dict[str, tuple[float, float]] = {
    "front": (0.0, 0.0),
    "side": (90.0, 0.0),
    "three_quarter": (35.0, 10.0),
}
"""Named views: (azimuth, elevation) in degrees; see the module docstring."""

SKIN_COLOR = (0.85, 0.72, 0.62)
"""Default surface colour, linear RGB in [0, 1]."""

_SUPERSAMPLE = 2  # render at 2x per axis, box-filter down (2x2 supersampling)
_AMBIENT = 0.35
_DIFFUSE = 0.65
_LIGHT_CAMERA = (-0.3, 0.5, 1.0)  # key light direction in (right, up, toward camera)
_NAN_GREY = (0.5, 0.5, 0.5)


# ---------------------------------------------------------------------------------------
# Input checks
# ---------------------------------------------------------------------------------------


def _as_points(P, name: str) -> np.ndarray:
    P = np.asarray(P, dtype=np.float64)
    if P.ndim != 2 or P.shape[1] != 3:
        raise InputError(f"{name} must have shape (n, 3), got {P.shape}")
    if not np.all(np.isfinite(P)):
        raise InputError(f"{name} contains NaN or infinite coordinates")
    return P


def _as_faces(F, vertex_count: int, name: str) -> np.ndarray:
    F = np.asarray(F)
    if F.ndim != 2 or F.shape[1] != 3:
        raise InputError(f"{name} must have shape (m, 3), got {F.shape}")
    if F.shape[0] == 0:
        raise InputError(f"{name} has no triangles")
    if not np.issubdtype(F.dtype, np.integer):
        raise InputError(f"{name} must hold integers, got dtype {F.dtype}")
    if F.min() < 0 or F.max() >= vertex_count:
        raise InputError(f"{name} indexes vertices in [{F.min()}, {F.max()}], expected [0, {vertex_count - 1}]")
    return F.astype(np.int64)


def _as_color(c, name: str) -> np.ndarray:
    c = np.asarray(c, dtype=np.float64)
    if c.shape != (3,):
        raise InputError(f"{name} must be an RGB triple in [0, 1], got shape {c.shape}")
    return np.clip(c, 0.0, 1.0)


def _as_colors(C, count: int, name: str) -> np.ndarray:
    C = np.asarray(C, dtype=np.float64)
    if C.shape != (count, 3):
        raise InputError(f"{name} must have shape ({count}, 3), got {C.shape}")
    return np.clip(np.nan_to_num(C, nan=_NAN_GREY[0]), 0.0, 1.0)


# ---------------------------------------------------------------------------------------
# Geometry helpers
# ---------------------------------------------------------------------------------------




def _view_angles(view) -> tuple[float, float]:
    if isinstance(view, str):
        if view not in VIEWS:
            raise InputError(f"view must be one of {sorted(VIEWS)} or (azimuth, elevation), got {view!r}")
        return VIEWS[view]
    try:
        azimuth, elevation = (float(a) for a in view)
    except (TypeError, ValueError):
        raise InputError(f"view must be a name or (azimuth_deg, elevation_deg), got {view!r}") from None
    if not abs(elevation) < 90.0:
        raise InputError(f"view elevation must lie in (-90, 90) degrees, got {elevation}")
    return azimuth, elevation


def view_axes(view) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The camera's unit axes of a view: image right, image up and viewing direction, each (3,) float64.

    Args:
        view: A name of :data:`VIEWS` or ``(azimuth_deg, elevation_deg)`` (module docstring).
    """
    az, el = np.radians(_view_angles(view))
    forward = -np.array([np.sin(az) * np.cos(el), np.sin(el), np.cos(az) * np.cos(el)])
    right = np.cross(forward, [0.0, 1.0, 0.0])
    right /= np.linalg.norm(right)
    return right, np.cross(right, forward), forward


@dataclass(frozen=True)
class _Camera:
    """Orthographic camera over a supersampled pixel grid.

    Pixel (row i, column j) has its centre at ``origin + j * pixel * right - i * pixel * up``
    on the image plane; rays leave the plane along ``forward``, so a ray's ``t`` is the depth
    [m] below the plane.
    """

    origin: np.ndarray  # centre of pixel (0, 0) on the image plane [m], (3,)
    right: np.ndarray  # unit image-right direction, (3,)
    up: np.ndarray  # unit image-up direction, (3,)
    forward: np.ndarray  # unit viewing direction, (3,)
    pixel: float  # pixel size at the supersampled resolution [m]
    max_depth: float  # depth of the far plane [m]
    rows: int
    cols: int

    def project(self, P: np.ndarray) -> np.ndarray:
        """World points (k, 3) [m] -> (k, 3) of (column, row, depth): pixel units, metres."""
        d = P - self.origin
        return np.stack([d @ self.right / self.pixel, -(d @ self.up) / self.pixel, d @ self.forward], axis=1)


def _make_camera(
    P: np.ndarray, azimuth: float, elevation: float, width: int, height: int, margin: float,
    supersample: int = _SUPERSAMPLE,
) -> _Camera:
    """Frame the points P (k, 3) [m] seen from (azimuth, elevation) degrees.

    The projected bounding box fills the image's tighter axis except for ``margin`` (a fraction
    of the box's extent) on each side.
    """
    right, up, forward = view_axes((azimuth, elevation))
    x, y, z = P @ right, P @ up, P @ forward
    extent_x, extent_y = np.ptp(x), np.ptp(y)
    diagonal = float(np.linalg.norm(np.ptp(P, axis=0)))
    scale = 1.0 + 2.0 * margin
    size = max(extent_x / width, extent_y / height) * scale  # metres per output pixel
    if size <= 0.0:
        size = max(diagonal, 1.0) / max(width, height)
    rows, cols = height * supersample, width * supersample
    pixel = size / supersample
    pad = 0.05 * max(diagonal, 1e-6)
    centre = 0.5 * (x.min() + x.max()) * right + 0.5 * (y.min() + y.max()) * up
    origin = (
        centre
        + (z.min() - pad) * forward
        - 0.5 * (cols - 1) * pixel * right
        + 0.5 * (rows - 1) * pixel * up
    )
    return _Camera(origin, right, up, forward, pixel, float(np.ptp(z) + 2.0 * pad), rows, cols)


_SHARED_HITS: list[dict] = []


@contextlib.contextmanager
def shared_hits():
    """Context: :func:`render_mesh` calls of one scene from one camera (the same geometry, view,
    size, lighting; no texture, no inside colour) cast their rays once and only colour them
    per picture (the same pixels as separate renders), e.g. heat maps of several values on one
    head. The hits are kept until the context ends. The ``adapt`` job's two 400 px heat maps
    save one ray cast this way (~0.05 s on one core)."""
    _SHARED_HITS.append({})
    try:
        yield
    finally:
        _SHARED_HITS.pop()


def _window(pixel_of: np.ndarray, count: int) -> tuple[int, int]:
    """[first, last + 1) of the pixels (rows or columns) within 2 pixels of the projected
    points' span (``pixel_of``: fractional pixel index of each point), clipped to [0, count)."""
    if not len(pixel_of) or not np.isfinite(pixel_of).all():
        return 0, count
    first = int(np.clip(np.floor(pixel_of.min()) - 2, 0, count))
    last = int(np.clip(np.ceil(pixel_of.max()) + 3, first, count))
    return first, last


def _stamp(
    color: np.ndarray, depth: np.ndarray, samples: np.ndarray, sample_colors: np.ndarray, radius: float, tol: float
) -> None:
    """Paint discs of ``radius`` pixels at projected samples (k, 3) that pass the depth test.

    A sample is drawn when its depth is at most the surface depth at its centre pixel plus
    ``tol`` [m]; its disc covers the pixels whose centres lie within ``radius``. Later samples
    paint over earlier ones.
    """
    rows, cols = depth.shape
    ci = np.rint(samples[:, 0]).astype(np.int64)
    ri = np.rint(samples[:, 1]).astype(np.int64)
    keep = (ci >= 0) & (ci < cols) & (ri >= 0) & (ri < rows)
    keep[keep] &= samples[keep, 2] <= depth[ri[keep], ci[keep]] + tol
    if not np.any(keep):
        return
    samples, sample_colors, ci, ri = samples[keep], sample_colors[keep], ci[keep], ri[keep]
    reach = int(np.ceil(radius))
    dr, dc = np.mgrid[-reach : reach + 1, -reach : reach + 1]
    rr = ri[:, None] + dr.ravel()[None, :]
    cc = ci[:, None] + dc.ravel()[None, :]
    inside = (rr - samples[:, 1:2]) ** 2 + (cc - samples[:, 0:1]) ** 2 <= radius**2
    inside &= (rr >= 0) & (rr < rows) & (cc >= 0) & (cc < cols)
    which = np.nonzero(inside)
    color[rr[which], cc[which]] = sample_colors[which[0]]


def _polyline_samples(Q: np.ndarray) -> np.ndarray:
    """Projected polyline vertices (p, 3) -> samples at most half a pixel apart (s, 3)."""
    if Q.shape[0] == 1:
        return Q
    a, b = Q[:-1], Q[1:]
    counts = np.ceil(np.hypot(*(b - a)[:, :2].T) / 0.5).astype(np.int64) + 1
    segment = np.repeat(np.arange(a.shape[0]), counts)
    local = np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts, counts)
    t = local / np.maximum(counts - 1, 1)[segment]
    return a[segment] + t[:, None] * (b - a)[segment]


# ---------------------------------------------------------------------------------------
# Public functions
# ---------------------------------------------------------------------------------------


def _as_texture(texture, face_count: int) -> tuple[np.ndarray, np.ndarray]:
    """(image (h, w, 3) float32 in [0, 1], corner UVs (m, 3, 2) float32) of ``texture``; a 1x1
    placeholder and one zero UV when None."""
    if texture is None:
        return np.zeros((1, 1, 3), np.float32), np.zeros((1, 2), np.float32)
    try:
        img, cuv = texture
    except (TypeError, ValueError):
        raise InputError("texture must be an (image, corner_uv) pair") from None
    img = np.asarray(img)
    if img.ndim != 3 or img.shape[2] < 3 or img.shape[0] < 1 or img.shape[1] < 1:
        raise InputError(f"texture image must have shape (h, w, 3), got {img.shape}")
    img = img[..., :3].astype(np.float32) / (255.0 if np.issubdtype(img.dtype, np.integer) else 1.0)
    cuv = np.asarray(cuv, dtype=np.float32)
    if cuv.shape != (face_count, 3, 2) or not np.isfinite(cuv).all():
        raise InputError(f"texture corner_uv must have shape ({face_count}, 3, 2) and be finite, got {cuv.shape}")
    return np.ascontiguousarray(img), cuv


def render_mesh(
    V,
    F,
    *,
    view="front",
    width: int = 800,
    height: int = 800,
    vertex_colors=None,
    face_colors=None,
    base_color=SKIN_COLOR,
    background=(1.0, 1.0, 1.0),
    margin: float = 0.06,
    extra_meshes: Sequence = (),
    points=None,
    point_color=(0.85, 0.1, 0.1),
    point_radius: float | None = None,
    polylines: Sequence | None = None,
    polyline_color=(0.1, 0.2, 0.8),
    line_width: float | None = None,
    depth_tolerance: float | None = None,
    inside_color=None,
    supersample: int = _SUPERSAMPLE,
    device="cpu",
    texture=None,
    frame_points=None,
    unlit: bool = False,
) -> np.ndarray:
    """Ray cast a triangle mesh (plus extras) into an RGB image.

    The orthographic camera frames the bounding box of all geometry (meshes, points,
    polylines) with a small margin. Triangles are visible from both sides.

    Args:
        V: Vertex positions [m], shape (n, 3), float.
        F: Triangles, shape (m, 3), int, indices into V.
        view: ``"front"``, ``"side"``, ``"three_quarter"`` or ``(azimuth_deg, elevation_deg)``;
            see the module docstring for the conventions.
        width, height: Output size in pixels.
        vertex_colors: Per-vertex RGB in [0, 1], shape (n, 3), interpolated across triangles
            (e.g. :func:`colormap` of a per-vertex scalar). NaN is drawn grey.
        face_colors: Per-triangle RGB in [0, 1], shape (m, 3). Not together with vertex_colors.
        base_color: RGB used when neither colour array is given (default: a skin tone).
        background: RGB of pixels that hit nothing.
        margin: Empty border on each side, as a fraction of the framed extent.
        extra_meshes: ``[(V, F, color), ...]`` rendered in the same scene (eyeballs, skull);
            color is an RGB triple or per-vertex RGB of shape (len(V), 3).
        points: Dots [m], shape (k, 3), drawn where not hidden by a surface (see
            depth_tolerance), e.g. landmarks on the skin.
        point_color: RGB triple, or per-point RGB of shape (k, 3).
        point_radius: Dot radius in output pixels (default: 0.6 % of the smaller image side,
            at least 1.5).
        polylines: Curves drawn on top with a depth test, each a (p, 3) array [m] or a pair
            ``(P, color)``, e.g. muscle fibres.
        polyline_color: RGB of polylines given without a colour.
        line_width: Line width in output pixels (default: 0.3 % of the smaller side, at
            least 1).
        depth_tolerance: How far [m] a point or line sample may lie behind the visible
            surface and still be drawn (default: 1 % of the scene's bounding-box diagonal);
            ``float("inf")`` draws them on top of everything (muscles under the skin).
        inside_color: Optional RGB for the back side of the triangles F (not of the extra
            meshes), drawn flat: the inside of a head seen through its mouth reads as a cavity.
            Default: both sides shaded alike.
        supersample: Rays per pixel along each axis (1-4), box-filtered down: 2 (default)
            smooths the edges; 1 is four times faster (e.g. the frames of a GIF).
        device: Warp device to ray cast on, e.g. ``"cpu"`` or ``"cuda:0"``.
        texture: Optional ``(image, corner_uv)`` colouring ``F``: the image (h, w, 3), uint8 or
            float in [0, 1] (row 0 at v = 1), and each triangle corner's UV, shape (m, 3, 2)
            (e.g. ``uv[face_uv]`` of a :class:`~facewarp.Template`); sampled bilinearly, it
            replaces the colour arrays on ``F``.
        frame_points: Optional points [m], shape (k, 3), that the camera frames instead of the
            scene's geometry (the same camera for two renders of different meshes).
        unlit: Draw the albedo alone (ambient 1, no key light): colours as stored, for comparing
            surface colour without shading.

    Returns:
        The image, shape (height, width, 3), uint8.
    """
    width, height = int(width), int(height)
    if width < 1 or height < 1:
        raise InputError(f"width and height must be positive, got {width} x {height}")
    azimuth, elevation = _view_angles(view)
    margin = float(margin)
    if not 0.0 <= margin < 10.0:
        raise InputError(f"margin must lie in [0, 10), got {margin}")
    V = _as_points(V, "V")
    F = _as_faces(F, V.shape[0], "F")
    if vertex_colors is not None and face_colors is not None:
        raise InputError("give vertex_colors or face_colors, not both")
    if vertex_colors is not None:
        corners = _as_colors(vertex_colors, V.shape[0], "vertex_colors")[F]
    elif face_colors is not None:
        corners = np.repeat(_as_colors(face_colors, F.shape[0], "face_colors")[:, None, :], 3, axis=1)
    else:
        corners = np.broadcast_to(_as_color(base_color, "base_color"), F.shape + (3,))
    background = _as_color(background, "background")
    inside = (0.0, 0.0, 0.0) if inside_color is None else _as_color(inside_color, "inside_color")

    # Scene: all triangles in one mesh, colours per triangle corner.
    scene_V, scene_F, scene_N, scene_C = [V], [F], [vertex_normals(V, F)], [corners]
    offset = V.shape[0]
    for index, extra in enumerate(extra_meshes):
        try:
            EV, EF, ec = extra
        except (TypeError, ValueError):
            raise InputError(f"extra_meshes[{index}] must be a (V, F, color) triple") from None
        EV = _as_points(EV, f"extra_meshes[{index}] V")
        EF = _as_faces(EF, EV.shape[0], f"extra_meshes[{index}] F")
        if np.shape(ec) == (3,):
            ecorners = np.broadcast_to(_as_color(ec, f"extra_meshes[{index}] color"), EF.shape + (3,))
        else:
            ecorners = _as_colors(ec, EV.shape[0], f"extra_meshes[{index}] color")[EF]
        scene_V.append(EV)
        scene_F.append(EF + offset)
        scene_N.append(vertex_normals(EV, EF))
        scene_C.append(ecorners)
        offset += EV.shape[0]

    framed = list(scene_V)
    if points is not None:
        points = _as_points(points, "points")
        framed.append(points)
    lines = []
    for index, item in enumerate(polylines or ()):
        if isinstance(item, tuple) and len(item) == 2:
            P, c = item
        else:
            P, c = item, polyline_color
        P = _as_points(P, f"polylines[{index}]")
        if P.shape[0] > 0:
            lines.append((P, _as_color(c, f"polylines[{index}] color")))
            framed.append(P)

    if frame_points is not None:
        framed = [_as_points(frame_points, "frame_points")]
    tex_img, tex_uv = _as_texture(texture, F.shape[0])
    all_V = np.concatenate(scene_V)
    if supersample not in (1, 2, 3, 4):
        raise InputError(f"supersample must be 1, 2, 3 or 4, got {supersample!r}")
    camera = _make_camera(np.concatenate(framed), azimuth, elevation, width, height, margin, supersample)
    if depth_tolerance is None:
        depth_tolerance = 0.01 * float(np.linalg.norm(np.ptp(np.concatenate(framed), axis=0)))

    light = _LIGHT_CAMERA[0] * camera.right + _LIGHT_CAMERA[1] * camera.up - _LIGHT_CAMERA[2] * camera.forward
    light /= np.linalg.norm(light)

    wp = get_warp()
    from .kernels_render import _cast_rays  # noqa: PLC0415

    try:
        device = wp.get_device(device)
    except (RuntimeError, ValueError) as error:
        raise InputError(f"device {device!r} is not available: {error}") from None
    wp_points = wp.array(all_V, dtype=wp.vec3, device=device)
    wp_indices = wp.array(np.concatenate(scene_F).ravel(), dtype=wp.int32, device=device)
    mesh = wp.Mesh(points=wp_points, indices=wp_indices)
    normals = wp.array(np.concatenate(scene_N), dtype=wp.vec3, device=device)
    corner_colors = wp.array(np.concatenate(scene_C).reshape(-1, 3), dtype=wp.vec3, device=device)
    corner_uvs = wp.array(tex_uv.reshape(-1, 2), dtype=wp.vec2, device=device)
    tex = wp.array(tex_img, dtype=wp.vec3, device=device)
    # Rays are cast only in the window of the scene's projected bounding box plus 2 pixels: a ray
    # outside it misses every triangle (the rays are parallel), and its pixel is the background
    # the kernel would write (the same float32 values). ~1/2 of the rays of a head seen from the
    # front; the picture is unchanged.
    col_of = (all_V @ camera.right - float(camera.origin @ camera.right)) / camera.pixel - 0.5
    row_of = (float(camera.origin @ camera.up) - all_V @ camera.up) / camera.pixel - 0.5
    r0, r1 = _window(row_of, camera.rows)
    c0, c1 = _window(col_of, camera.cols)
    color_np = np.empty((camera.rows, camera.cols, 3), dtype=np.float32)
    color_np[...] = np.asarray(background, dtype=np.float32)
    color_out = wp.array(color_np, dtype=wp.vec3, device=device)
    step_right, step_down = camera.pixel * camera.right, -camera.pixel * camera.up
    shared = _SHARED_HITS[-1] if _SHARED_HITS and texture is None and inside_color is None else None
    if shared is not None:  # a picture of the same scene from the same camera was taken: its hits are kept
        from .kernels_render import _cast_hits, _shade_hits  # noqa: PLC0415

        key = (all_V.tobytes(), wp_indices.numpy().tobytes(), np.concatenate(scene_N).tobytes(), str(device),
               tuple(float(x) for x in (*camera.origin, *step_right, *step_down, *camera.forward, camera.max_depth,
                                        *light)), camera.rows, camera.cols, r0, r1, c0, c1, bool(unlit))
        if key not in shared:
            shape = (camera.rows, camera.cols)
            hits = (wp.full(shape, -1, dtype=wp.int32, device=device), wp.zeros(shape, dtype=float, device=device),
                    wp.zeros(shape, dtype=float, device=device), wp.zeros(shape, dtype=float, device=device),
                    wp.full(shape, camera.max_depth, dtype=float, device=device))
            wp.launch(_cast_hits, dim=(r1 - r0, c1 - c0),
                      inputs=[mesh.id, wp_indices, normals, r0, c0, wp.vec3(*camera.origin), wp.vec3(*step_right),
                              wp.vec3(*step_down), wp.vec3(*camera.forward), camera.max_depth, wp.vec3(*light),
                              1.0 if unlit else _AMBIENT, 0.0 if unlit else _DIFFUSE],
                      outputs=list(hits), device=device)
            shared[key] = (hits, mesh)
        (face_hit, u_hit, v_hit, shade_hit, depth_out), _ = shared[key]
        wp.launch(_shade_hits, dim=(camera.rows, camera.cols),
                  inputs=[face_hit, u_hit, v_hit, shade_hit, corner_colors, wp.vec3(*background)],
                  outputs=[color_out], device=device)
    else:
        depth_out = wp.full((camera.rows, camera.cols), camera.max_depth, dtype=float, device=device)
        wp.launch(
            _cast_rays,
            dim=(r1 - r0, c1 - c0),
            inputs=[
                mesh.id,
                wp_indices,
                normals,
                corner_colors,
                corner_uvs,
                tex,
                F.shape[0] if texture is not None else 0,
                F.shape[0] if inside_color is not None else 0,
                wp.vec3(*inside),
                r0,
                c0,
                wp.vec3(*camera.origin),
                wp.vec3(*step_right),
                wp.vec3(*step_down),
                wp.vec3(*camera.forward),
                camera.max_depth,
                wp.vec3(*light),
                1.0 if unlit else _AMBIENT,
                0.0 if unlit else _DIFFUSE,
                wp.vec3(*background),
            ],
            outputs=[color_out, depth_out],
            device=device,
        )
    color = color_out.numpy()  # float32; overlays and the box filter stay in float32
    depth = depth_out.numpy()
    miss = depth >= np.float32(camera.max_depth)
    depth = np.where(miss, np.inf, depth.astype(np.float64))

    # Overlays at the supersampled resolution, so they are antialiased by the downsampling.
    short_side = min(width, height)
    if line_width is None:
        line_width = max(1.0, 0.003 * short_side)
    for P, c in lines:
        samples = _polyline_samples(camera.project(P))
        radius = 0.5 * line_width * supersample
        _stamp(color, depth, samples, np.broadcast_to(c, samples.shape), radius, depth_tolerance)
    if points is not None and points.shape[0] > 0:
        if point_radius is None:
            point_radius = max(1.5, 0.006 * short_side)
        if np.shape(point_color) == (3,):
            pc = np.broadcast_to(_as_color(point_color, "point_color"), points.shape)
        else:
            pc = _as_colors(point_color, points.shape[0], "point_color")
        _stamp(color, depth, camera.project(points), pc, point_radius * supersample, depth_tolerance)

    s = supersample
    image = sum(color[i::s, j::s] for i in range(s) for j in range(s)) * np.float32(255.0 / (s * s))
    return np.clip(np.rint(image), 0, 255).astype(np.uint8)


# Turbo (Mikhailov 2019), polynomial fit by R. Du: c(x) = sum_k a_k x^k, k = 0..5.
_TURBO = np.array(
    [
        [0.13572138, 0.09140261, 0.10667330],
        [4.61539260, 2.19418839, 12.64194608],
        [-42.66032258, 4.84296658, -60.58204836],
        [132.13108234, -14.18503333, 110.36276771],
        [-152.94239396, 4.27729857, -89.90310912],
        [59.28637943, 2.82956604, 27.34824973],
    ]
)
# Viridis (van der Walt & Smith 2015) at x = 0, 1/8, ..., 1, interpolated linearly.
_VIRIDIS = (
    np.array(
        [
            [68, 1, 84],
            [71, 44, 122],
            [59, 81, 139],
            [44, 113, 142],
            [33, 144, 141],
            [39, 173, 129],
            [92, 200, 99],
            [170, 220, 50],
            [253, 231, 37],
        ]
    )
    / 255.0
)


def colormap(values, vmin: float, vmax: float, name: str = "turbo") -> np.ndarray:
    """Map scalars to RGB for heat maps (no matplotlib needed).

    Args:
        values: Scalars, shape (n,), float. NaN maps to grey.
        vmin, vmax: Values mapped to the two ends of the map; values outside are clamped.
        name: ``"turbo"`` (polynomial approximation) or ``"viridis"``.

    Returns:
        RGB in [0, 1], shape (n, 3), float64.
    """
    from ..core.checks import check_array, check_number

    check_array("values", values, shape=(None,) * np.ndim(values), finite=False)
    check_number("vmin", vmin)
    check_number("vmax", vmax)
    values = np.asarray(values, dtype=np.float64)
    if values.ndim != 1:
        raise InputError(f"values must have shape (n,), got {values.shape}")
    vmin, vmax = float(vmin), float(vmax)
    if not (np.isfinite(vmin) and np.isfinite(vmax)) or vmax < vmin:
        raise InputError(f"colormap range must be finite with vmin <= vmax, got [{vmin}, {vmax}]")
    nan = np.isnan(values)
    if vmax > vmin:
        x = np.clip((np.where(nan, vmin, values) - vmin) / (vmax - vmin), 0.0, 1.0)
    else:
        x = np.full(values.shape, 0.5)
    if name == "turbo":
        rgb = np.vander(x, _TURBO.shape[0], increasing=True) @ _TURBO
    elif name == "viridis":
        stops = np.linspace(0.0, 1.0, _VIRIDIS.shape[0])
        rgb = np.stack([np.interp(x, stops, _VIRIDIS[:, k]) for k in range(3)], axis=1)
    else:
        raise InputError(f"colormap name must be 'turbo' or 'viridis', got {name!r}")
    rgb = np.clip(rgb, 0.0, 1.0)
    rgb[nan] = _NAN_GREY
    return rgb


def _font(size: int):
    from PIL import ImageFont  # noqa: PLC0415

    try:
        return ImageFont.load_default(size=size)
    except TypeError:  # Pillow < 10.1: fixed-size bitmap font
        return ImageFont.load_default()


def _draw_centred(draw, x: float, y: float, text: str, font) -> None:
    """Black text whose top edge is at y and whose centre is at x (any Pillow font)."""
    draw.text((round(x - draw.textlength(text, font=font) / 2), round(y)), text, fill=(0, 0, 0), font=font)


def _format_value(v: float) -> str:
    return f"{v:.3g}"


def save_png(path, image, *, title: str | None = None, colorbar=None, font_size: int | None = None) -> str:
    """Write an RGB image as PNG, atomically, with an optional title and colour bar.

    The file is written to a temporary name in the destination folder and then moved over
    ``path`` with ``os.replace`` (:func:`facewarp._src.fileio.atomic_write`), so readers never
    see a half-written file.

    Args:
        path: Destination file.
        image: RGB image, shape (h, w, 3), uint8 (or float in [0, 1]).
        title: Text drawn in a band above the image.
        colorbar: ``(vmin, vmax, label)`` or ``(vmin, vmax, label, name)``: a horizontal bar of
            the colour map ``name`` (default ``"turbo"``) below the image, with the min / max
            values at its ends and the label in the middle.
        font_size: Text height [px] of the title and colour bar; default from the image width
            (at most 37 px).

    Returns:
        The path written, as a string.

    Raises:
        InputError: Bad image shape or colour bar; the destination folder does not exist.
    """
    from PIL import Image, ImageDraw  # noqa: PLC0415

    image = np.asarray(image)
    if image.ndim != 3 or image.shape[2] != 3:
        raise InputError(f"image must have shape (h, w, 3), got {image.shape}")
    if image.dtype != np.uint8:
        image = np.clip(np.rint(np.asarray(image, dtype=np.float64) * 255.0), 0, 255).astype(np.uint8)
    h, w = image.shape[:2]
    if font_size is None:
        font_size = max(12, min(w, 1200) // 32)
    elif not (isinstance(font_size, (int, np.integer)) and 6 <= font_size <= 512):
        raise InputError(f"font_size: expected a whole number of pixels in [6, 512], got {font_size!r}")
    font_size = int(font_size)
    font = _font(font_size)
    pad = font_size // 2

    title_height = font_size + 2 * pad if title else 0
    bar_height = 0
    if colorbar is not None:
        if len(colorbar) not in (3, 4):
            raise InputError(f"colorbar must be (vmin, vmax, label[, name]), got {colorbar!r}")
        vmin, vmax, label = float(colorbar[0]), float(colorbar[1]), str(colorbar[2])
        name = colorbar[3] if len(colorbar) == 4 else "turbo"
        bar_thickness = max(6, font_size)
        bar_height = pad + bar_thickness + pad + font_size + pad

    canvas = Image.new("RGB", (w, title_height + h + bar_height), (255, 255, 255))
    canvas.paste(Image.fromarray(image, mode="RGB"), (0, title_height))
    draw = ImageDraw.Draw(canvas)
    if title:
        _draw_centred(draw, w / 2, pad, title, font)
    if colorbar is not None:
        x0, x1 = w // 10, w - w // 10
        y0 = title_height + h + pad
        ramp = colormap(np.linspace(vmin, vmax, max(x1 - x0, 2)), vmin, vmax, name)
        bar = np.broadcast_to((ramp * 255.0).round().astype(np.uint8)[None], (bar_thickness,) + ramp.shape)
        canvas.paste(Image.fromarray(np.ascontiguousarray(bar), mode="RGB"), (x0, y0))
        draw.rectangle((x0 - 1, y0 - 1, x0 + bar.shape[1], y0 + bar_thickness), outline=(0, 0, 0))
        y_text = y0 + bar_thickness + pad // 2
        _draw_centred(draw, x0, y_text, _format_value(vmin), font)
        _draw_centred(draw, x0 + bar.shape[1], y_text, _format_value(vmax), font)
        _draw_centred(draw, w / 2, y_text, label, font)

    with atomic_write(path, "wb") as f:
        canvas.save(f, format="PNG")
    return str(path)


def render_views(
    V, F, path_prefix, *, views=("front", "side"), title: str | None = None, colorbar=None, **render_kwargs
) -> list[str]:
    """Render several views and write ``<path_prefix>_<view>.png`` for each.

    Args:
        V, F: The mesh, as in :func:`render_mesh`.
        path_prefix: Path without the ``_<view>.png`` suffix.
        views: View names (keys of :data:`VIEWS`).
        title, colorbar: Passed to :func:`save_png` for every view.
        **render_kwargs: Passed to :func:`render_mesh`.

    Returns:
        The paths written, in the order of ``views``.
    """
    paths = []
    for view in views:
        if not isinstance(view, str):
            raise InputError(f"render_views needs view names, got {view!r}")
        image = render_mesh(V, F, view=view, **render_kwargs)
        paths.append(save_png(f"{path_prefix}_{view}.png", image, title=title, colorbar=colorbar))
    return paths
