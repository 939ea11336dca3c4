"""Single-pixel probes: find telling pixels of a scene from its geometry, and trace one pixel
many times over.

    scene = load_scene("cornell-box")
    edge = light_edge_pixel(scene, 256, 256)        # a pixel the light's outline crosses
    wall = diffuse_wall_pixel(scene, 256, 256)      # deep inside a lit diffuse wall
    ball = sphere_pixel(scene, 256, 256)            # the glass ball's centre
    shadow = shadow_boundary_pixel(scene, 256, 256)  # floor the box's shadow boundary crosses
    sheen = glossy_highlight_edge_pixel(glossy_scene, short_render)  # a glossy highlight's edge
    runs = trace_pixel_runs(runtime, tracer, make_sampler("sppp", 256), seed, edge.pixel,
                            runs=200, width=256, height=256)

Pixels are found on the host from the scene description, never hard-coded: the camera projects
points (the inverse of kernels/camera.h), a small NumPy ray caster finds what each pixel sees
and how much of the light a point sees; the glossy finders read a short render as well.
`trace_pixel_runs` draws R independent sample sets of one pixel in one launch: run r uses
redraw number first_redraw + r, and every random number depends on (seed, pixel, sample,
dimension, redraw), so runs are independent and reproducible.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from clrender.errors import ParameterError
from clrender.runtime import Runtime
from clrender.samples import SampleSets
from clrender.sampling import SamplerConfig, generate_sample_sets
from clrender.scene import Scene
from clrender.scene_device import EMITTER_SHAPES, MATERIAL_TYPES
from clrender.trace import PathTracer

NO_HIT = -1
# Sub-pixel positions (pixel-local) whose rays must agree for a pixel to count as "inside" a
# surface: the centre and four points near the corners.
PIXEL_PROBES = np.array([[0.0, 0.0], [-0.45, -0.45], [0.45, -0.45], [-0.45, 0.45], [0.45, 0.45]])
# Points per side of the grid over the light that visible_light_fraction counts.
LIGHT_GRID_CELLS = 8
# Points per batch of shadow rays in light_blockers (memory bound: a few tens of MB).
SHADOW_CHUNK = 4096


@dataclass(frozen=True)
class ProbePixel:
    """A chosen pixel: image coordinates (x, y), global index y * width + x, and why."""

    x: int
    y: int
    width: int
    what: str
    detail: dict

    @property
    def pixel(self) -> int:
        return self.y * self.width + self.x

    def as_dict(self) -> dict:
        return {"x": self.x, "y": self.y, "pixel": self.pixel, "what": self.what, **self.detail}


# ---------------------------------------------------------------------------------------------
# Camera and host ray casting


def camera_frame(scene: Scene, width: int, height: int) -> tuple[np.ndarray, ...]:
    """(origin, forward, right, up) in float64, right/up scaled as in Camera.basis."""
    basis = scene.camera.basis(width, height)
    return tuple(np.asarray(basis[key], np.float64) for key in ("origin", "forward", "right", "up"))


def project(scene: Scene, width: int, height: int, points: np.ndarray) -> np.ndarray:
    """Image positions (x, y) in pixels of world points (..., 3) (kernels/camera.h inverted:
    pixel (i, j) covers [i, i+1] x [j, j+1], y down)."""
    origin, forward, right, up = camera_frame(scene, width, height)
    v = np.asarray(points, np.float64) - origin
    depth = v @ forward
    sx = (v @ right) / (depth * (right @ right))
    sy = (v @ up) / (depth * (up @ up))
    return np.stack([(sx + 1.0) * width / 2.0, (1.0 - sy) * height / 2.0], axis=-1)


def camera_rays(
    scene: Scene, width: int, height: int, image_pos: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """(origins, unit directions) of the camera rays through image positions (..., 2)."""
    origin, forward, right, up = camera_frame(scene, width, height)
    sx = 2.0 * image_pos[..., 0] / width - 1.0
    sy = 1.0 - 2.0 * image_pos[..., 1] / height
    d = forward + sx[..., None] * right + sy[..., None] * up
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    return np.broadcast_to(origin, d.shape), d


def _quad_hits(scene: Scene, o: np.ndarray, d: np.ndarray) -> np.ndarray:
    """(..., Q) ray parameter t of each quad hit, inf where missed."""
    quads = scene.quads
    corner, e1, e2 = (quads[k].astype(np.float64) for k in ("corner", "edge1", "edge2"))
    n = np.cross(e1, e2)
    nn = np.einsum("qi,qi->q", n, n)
    u_dual, v_dual = np.cross(e2, n) / nn[:, None], np.cross(n, e1) / nn[:, None]
    denom = d @ n.T
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.einsum("qi,qi->q", n, corner)[..., :] - o @ n.T
        t = t / denom
        p = o[..., None, :] + t[..., None] * d[..., None, :] - corner
        u = np.einsum("...qi,qi->...q", p, u_dual)
        v = np.einsum("...qi,qi->...q", p, v_dual)
        ok = (np.abs(denom) > 1e-12) & (t > 1e-6) & (u >= 0) & (u <= 1) & (v >= 0) & (v <= 1)
    return np.where(ok, t, np.inf)


def _sphere_hits(scene: Scene, o: np.ndarray, d: np.ndarray) -> np.ndarray:
    """(..., S) nearest positive ray parameter of each sphere hit, inf where missed."""
    centre = scene.spheres["center"].astype(np.float64)
    radius = scene.spheres["radius"].astype(np.float64)
    oc = o[..., None, :] - centre
    b = np.einsum("...si,...i->...s", oc, d)
    c = np.einsum("...si,...si->...s", oc, oc) - radius**2
    disc = b * b - c
    root = np.sqrt(np.maximum(disc, 0.0))
    near, far = -b - root, -b + root
    t = np.where(near > 1e-6, near, far)
    return np.where((disc >= 0) & (t > 1e-6), t, np.inf)


def first_hits(scene: Scene, o: np.ndarray, d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(t, shape id) of the nearest hit: ids 0..Q-1 are quads, Q.. spheres, NO_HIT for none."""
    t_all = np.concatenate([_quad_hits(scene, o, d), _sphere_hits(scene, o, d)], axis=-1)
    shape = np.argmin(t_all, axis=-1)
    t = np.take_along_axis(t_all, shape[..., None], axis=-1)[..., 0]
    return t, np.where(np.isfinite(t), shape, NO_HIT)


def shape_materials(scene: Scene) -> np.ndarray:
    """Material index of every shape id (quads then spheres); -1 for a pure emitter."""
    return np.concatenate([scene.quads["material"], scene.spheres["material"]]).astype(int)


def glass_shapes(scene: Scene) -> np.ndarray:
    """Shape ids (quads then spheres) of dielectric material."""
    materials = shape_materials(scene)
    dielectric = scene.materials["type"][materials] == MATERIAL_TYPES["dielectric"]
    return np.flatnonzero((materials >= 0) & dielectric)


def pixel_hits(scene: Scene, width: int, height: int) -> tuple[np.ndarray, np.ndarray]:
    """(shape ids (H, W, K), hit points (H, W, K, 3)) of the K = len(PIXEL_PROBES) probe rays
    of every pixel."""
    ys, xs = np.mgrid[0:height, 0:width]
    pos = np.stack([xs, ys], -1)[:, :, None, :] + 0.5 + PIXEL_PROBES
    o, d = camera_rays(scene, width, height, pos)
    t, shape = first_hits(scene, o, d)
    return shape, o + np.where(np.isfinite(t), t, 0.0)[..., None] * d


def emitting_quad(scene: Scene, emitter: int) -> np.ndarray:
    """The QUAD_DTYPE record of emitter number `emitter`, which must be a quad."""
    record = scene.emitters[emitter]
    if record["shape"] != EMITTER_SHAPES["quad"]:
        raise ParameterError(f"{scene.name}: emitter {emitter} is not a quad")
    return scene.quads[record["index"]]


def light_points(scene: Scene, emitter: int = 0) -> np.ndarray:
    """The corners and centre of an emitting quad (5, 3)."""
    quad = emitting_quad(scene, emitter)
    c, e1, e2 = (quad[k].astype(np.float64) for k in ("corner", "edge1", "edge2"))
    return np.array([c, c + e1, c + e2, c + e1 + e2, c + 0.5 * (e1 + e2)])


def light_grid(scene: Scene, emitter: int = 0, cells: int = LIGHT_GRID_CELLS) -> np.ndarray:
    """The centres of a cells x cells grid over an emitting quad (cells * cells, 3)."""
    quad = emitting_quad(scene, emitter)
    c, e1, e2 = (quad[k].astype(np.float64) for k in ("corner", "edge1", "edge2"))
    s = (np.arange(cells) + 0.5) / cells
    return (c + s[:, None, None] * e1 + s[None, :, None] * e2).reshape(-1, 3)


def shadow_blockers(scene: Scene, points: np.ndarray, targets: np.ndarray) -> np.ndarray:
    """(..., T) the shape id blocking the shadow ray from each point to each target (T, 3),
    NO_HIT where the target is unoccluded (small offset at the point, as sees_points)."""
    to = targets - points[..., None, :]
    dist = np.linalg.norm(to, axis=-1)
    d = to / dist[..., None]
    o = points[..., None, :] + 1e-3 * d
    t, shape = first_hits(scene, o, d)
    return np.where(t >= dist * (1.0 - 1e-4), NO_HIT, shape)


def sees_points(scene: Scene, points: np.ndarray, targets: np.ndarray) -> np.ndarray:
    """(...,) whether every target is unoccluded from each point (shadow rays, small offset)."""
    return (shadow_blockers(scene, points, targets) == NO_HIT).all(axis=-1)


def light_blockers(scene: Scene, points: np.ndarray, emitter: int = 0) -> np.ndarray:
    """(..., L) shadow_blockers of the points (..., 3) towards the light_grid points of an
    emitter, in chunks of points (the ray caster holds rays x shapes x 3 values)."""
    targets = light_grid(scene, emitter)
    flat = np.asarray(points, np.float64).reshape(-1, 3)
    chunks = [
        shadow_blockers(scene, flat[i : i + SHADOW_CHUNK], targets)
        for i in range(0, len(flat), SHADOW_CHUNK)
    ]
    blockers = np.concatenate(chunks) if chunks else np.empty((0, len(targets)), int)
    return blockers.reshape(*np.shape(points)[:-1], len(targets))


def visible_light_fraction(scene: Scene, points: np.ndarray, emitter: int = 0) -> np.ndarray:
    """(...,) the share of an emitter's light_grid points each point (..., 3) sees unoccluded:
    0 in the umbra, 1 fully lit, in between in the penumbra."""
    return (light_blockers(scene, points, emitter) == NO_HIT).mean(axis=-1)


# ---------------------------------------------------------------------------------------------
# Pixel finders


def clip_to_box(
    polygon: np.ndarray, low: tuple[float, float], high: tuple[float, float]
) -> np.ndarray:
    """The part of a convex polygon (V, 2) inside the box [low, high] (Sutherland-Hodgman on
    the box's four edges); (0, 2) if nothing is left."""
    poly = np.asarray(polygon, np.float64)
    for axis, bound, keep_below in (
        (0, low[0], False),
        (0, high[0], True),
        (1, low[1], False),
        (1, high[1], True),
    ):
        if len(poly) == 0:
            break
        inside = poly[:, axis] <= bound if keep_below else poly[:, axis] >= bound
        nxt = np.roll(poly, -1, axis=0)
        out = []
        for p, q, p_in, q_in in zip(poly, nxt, inside, np.roll(inside, -1), strict=True):
            if p_in:
                out.append(p)
            if p_in != q_in:
                out.append(p + (bound - p[axis]) / (q[axis] - p[axis]) * (q - p))
        poly = np.array(out).reshape(-1, 2)
    return poly


def polygon_area(polygon: np.ndarray) -> float:
    if len(polygon) < 3:
        return 0.0
    xs, ys = polygon[:, 0], polygon[:, 1]
    return float(0.5 * abs(np.dot(xs, np.roll(ys, -1)) - np.dot(ys, np.roll(xs, -1))))


def polygon_pixel_coverage(polygon: np.ndarray, x: int, y: int) -> float:
    """Area of the convex polygon (V, 2) inside pixel [x, x+1] x [y, y+1]."""
    return polygon_area(clip_to_box(polygon, (x, y), (x + 1, y + 1)))


def light_edge_pixel(scene: Scene, width: int, height: int, emitter: int = 0) -> ProbePixel:
    """A pixel the light's outline crosses, covered closest to half by the light (projected
    analytically; the light must face the camera and be unoccluded at that pixel)."""
    corners = light_points(scene, emitter)[[0, 1, 3, 2]]  # in order around the quad
    polygon = project(scene, width, height, corners)
    candidates = _outline_pixels(polygon, width, height)
    coverage = np.array([polygon_pixel_coverage(polygon, x, y) for x, y in candidates])
    best = int(np.argmin(np.abs(coverage - 0.5)))
    x, y = (int(v) for v in candidates[best])
    return ProbePixel(
        x,
        y,
        width,
        "light edge",
        {"light_coverage": float(coverage[best]), "light_polygon": polygon.tolist()},
    )


def _outline_pixels(polygon: np.ndarray, width: int, height: int) -> np.ndarray:
    """Distinct pixels (x, y) under points densely spaced along the polygon's edges."""
    ends = np.roll(polygon, -1, axis=0)
    s = np.linspace(0.02, 0.98, 200)[:, None, None]
    points = (polygon + s * (ends - polygon)).reshape(-1, 2)
    pixels = np.unique(np.floor(points).astype(int), axis=0)
    inside = (
        (pixels[:, 0] >= 0) & (pixels[:, 0] < width) & (pixels[:, 1] >= 0) & (pixels[:, 1] < height)
    )
    if not inside.any():
        raise ParameterError("the light's outline is outside the image")
    return pixels[inside]


def diffuse_wall_pixel(
    scene: Scene, width: int, height: int, wall: str = "back wall"
) -> ProbePixel:
    """The pixel deepest inside the part of a wall that is seen directly and fully lit (every
    probe ray hits the wall, and each hit sees the light's corners and centre): farthest from
    any other pixel, ties broken towards the image centre."""
    shape, points = pixel_hits(scene, width, height)
    wall_id = scene.quad_names.index(wall)
    on_wall = (shape == wall_id).all(axis=-1)
    lit = np.zeros_like(on_wall)
    lit[on_wall] = sees_points(scene, points[on_wall][:, 0], light_points(scene))
    return _deepest(lit, width, height, f"diffuse wall ({wall})")


def _deepest(mask: np.ndarray, width: int, height: int, what: str) -> ProbePixel:
    if not mask.any():
        raise ParameterError(f"no pixel qualifies for the {what} probe")
    depth = ndimage.distance_transform_edt(np.pad(mask, 1))[1:-1, 1:-1]
    ys, xs = np.mgrid[0:height, 0:width]
    centre = np.hypot(xs + 0.5 - width / 2, ys + 0.5 - height / 2)
    score = np.where(mask, depth - 1e-3 * centre, -np.inf)
    y, x = np.unravel_index(int(np.argmax(score)), score.shape)
    return ProbePixel(
        int(x), int(y), width, what, {"distance_to_region_edge_px": float(depth[y, x])}
    )


def shadow_boundary_pixel(
    scene: Scene, width: int, height: int, surface: str = "floor", emitter: int = 0
) -> ProbePixel:
    """A pixel of a diffuse surface that the boundary of an opaque occluder's shadow crosses.

    At each of the pixel's PIXEL_PROBES points (centre and four near-corners) the visible
    fraction of the light is the share of a LIGHT_GRID_CELLS x LIGHT_GRID_CELLS grid of points
    on the emitter that the point sees unoccluded. A pixel qualifies when every probe ray hits
    the surface, the probes' mean fraction lies in [1/4, 3/4] (penumbra, not umbra or full
    light) and every blocked shadow ray is blocked by an opaque shape (not glass: the path
    tracer's shadow rays stop at glass too, but a caustic fills its shadow). Of those, the
    pixel whose fraction changes most across it (largest max - min over its probes) is
    chosen, ties broken towards a mean fraction of 1/2."""
    surface_id = scene.quad_names.index(surface)
    material = scene.materials[scene.quads["material"][surface_id]]
    if material["type"] != MATERIAL_TYPES["diffuse"]:
        raise ParameterError(f"the {surface} is not diffuse")
    shape, points = pixel_hits(scene, width, height)
    on_surface = (shape == surface_id).all(axis=-1)
    blockers = light_blockers(scene, points[on_surface], emitter)  # (P, K, L)
    fraction = (blockers == NO_HIT).mean(axis=-1)  # (P, K)
    through_glass = np.isin(blockers, glass_shapes(scene)).any(axis=(-2, -1))
    mean = fraction.mean(axis=-1)
    spread = fraction.max(axis=-1) - fraction.min(axis=-1)
    qualifies = (mean >= 0.25) & (mean <= 0.75) & ~through_glass
    if not qualifies.any():
        raise ParameterError(f"no pixel of the {surface} sees an opaque shadow's boundary")
    score = np.where(qualifies, spread - 1e-3 * np.abs(mean - 0.5), -np.inf)
    best = int(np.argmax(score))
    y, x = (int(v[best]) for v in np.nonzero(on_surface))
    names = scene.quad_names + scene.sphere_names
    occluders = sorted({names[i] for i in np.unique(blockers[best]) if i != NO_HIT})
    return ProbePixel(
        x,
        y,
        width,
        f"shadow boundary ({surface})",
        {
            "light_fraction_at_probes": fraction[best].tolist(),
            "light_fraction_spread": float(spread[best]),
            "occluders": occluders,
        },
    )


def sphere_pixel(scene: Scene, width: int, height: int, sphere: int = 0) -> ProbePixel:
    """The pixel the sphere's centre projects to (checked to see that sphere)."""
    centre = scene.spheres["center"][sphere].astype(np.float64)
    x, y = (int(v) for v in np.floor(project(scene, width, height, centre)))
    shape, _ = pixel_hits(scene, width, height)
    sphere_id = len(scene.quads) + sphere
    if not (shape[y, x] == sphere_id).all():
        raise ParameterError(f"the pixel of sphere {sphere}'s centre does not see it")
    return ProbePixel(x, y, width, f"sphere ({scene.sphere_names[sphere]})", {})


def emitting_sphere(scene: Scene, emitter: int) -> int:
    """The sphere index of emitter number `emitter`, which must be a sphere."""
    record = scene.emitters[emitter]
    if record["shape"] != EMITTER_SHAPES["sphere"]:
        raise ParameterError(f"{scene.name}: emitter {emitter} is not a sphere")
    return int(record["index"])


def sphere_outline(
    scene: Scene, width: int, height: int, sphere: int, points: int = 360
) -> np.ndarray:
    """The image outline (points, 2) of a sphere: the projection of its silhouette circle (the
    points whose view ray from the camera grazes it), a convex polygon."""
    origin = camera_frame(scene, width, height)[0]
    centre = scene.spheres["center"][sphere].astype(np.float64)
    r = float(scene.spheres["radius"][sphere])
    axis = centre - origin
    dist = float(np.linalg.norm(axis))
    if dist <= r:
        raise ParameterError(f"the camera is inside sphere {sphere}")
    axis /= dist
    s = np.cross(axis, [0.0, 1.0, 0.0] if abs(axis[1]) < 0.9 else [1.0, 0.0, 0.0])
    s /= np.linalg.norm(s)
    t = np.cross(axis, s)
    ring_centre = centre - (r * r / dist) * axis
    ring_radius = r * math.sqrt(1.0 - (r / dist) ** 2)
    phi = 2.0 * np.pi * np.arange(points) / points
    ring = ring_centre + ring_radius * (np.cos(phi)[:, None] * s + np.sin(phi)[:, None] * t)
    return project(scene, width, height, ring)


def sphere_light_edge_pixel(scene: Scene, width: int, height: int, emitter: int = 0) -> ProbePixel:
    """A pixel a spherical light's outline crosses, covered closest to half by the light (its
    outline projected analytically), among pixels where some probe rays see the light and
    some do not (so nothing hides that edge)."""
    sphere = emitting_sphere(scene, emitter)
    polygon = sphere_outline(scene, width, height, sphere)
    candidates = _outline_pixels(polygon, width, height)
    shape, _ = pixel_hits(scene, width, height)
    sees = shape[candidates[:, 1], candidates[:, 0]] == len(scene.quads) + sphere
    mixed = sees.any(axis=-1) & ~sees.all(axis=-1)
    if not mixed.any():
        raise ParameterError(f"the outline of light {emitter} is hidden everywhere")
    candidates = candidates[mixed]
    coverage = np.array([polygon_pixel_coverage(polygon, x, y) for x, y in candidates])
    best = int(np.argmin(np.abs(coverage - 0.5)))
    x, y = (int(v) for v in candidates[best])
    return ProbePixel(
        x,
        y,
        width,
        f"sphere light edge ({scene.sphere_names[sphere]})",
        {"light_coverage": float(coverage[best])},
    )


def glossy_reflection_pixel(
    scene: Scene, width: int, height: int, emitter: int = 0, material: str = ""
) -> ProbePixel:
    """A pixel of a spherical light's reflection on a flat glossy surface of `material`: the
    light's centre mirrored in the plane of each face of that material that faces both the
    camera and the light, projected; of the pixels whose probe rays all see that face, the
    one nearest that point (the point itself when the face shows it; a rough face's broad
    highlight also reaches pixels beside a mirror point it hides). Nearest over the faces."""
    sphere = emitting_sphere(scene, emitter)
    centre = scene.spheres["center"][sphere].astype(np.float64)
    origin = camera_frame(scene, width, height)[0]
    wanted = scene.material_names.index(material)
    shape, _ = pixel_hits(scene, width, height)
    ys, xs = np.mgrid[0:height, 0:width]
    best = None
    for quad_id in np.flatnonzero(scene.quads["material"] == wanted):
        quad = scene.quads[quad_id]
        n = quad["normal"].astype(np.float64)
        corner = quad["corner"].astype(np.float64)
        light_side, camera_side = (centre - corner) @ n, (origin - corner) @ n
        on_face = (shape == quad_id).all(axis=-1)
        if light_side <= 0.0 or camera_side <= 0.0 or not on_face.any():
            continue
        mirrored = centre - 2.0 * light_side * n
        target = project(scene, width, height, mirrored)
        distance = np.where(on_face, np.hypot(xs + 0.5 - target[0], ys + 0.5 - target[1]), np.inf)
        y, x = np.unravel_index(int(np.argmin(distance)), distance.shape)
        if best is None or distance[y, x] < best[0]:
            best = (float(distance[y, x]), int(x), int(y), quad_id, target)
    if best is None:
        raise ParameterError(f"no face of {material} faces both the camera and light {emitter}")
    offset, x, y, quad_id, target = best
    return ProbePixel(
        x,
        y,
        width,
        f"reflection of {scene.sphere_names[sphere]} on {material}",
        {
            "quad": scene.quad_names[quad_id],
            "mirror_point_px": target.tolist(),
            "offset_from_mirror_point_px": offset,
        },
    )


def glossy_pixels(scene: Scene, width: int, height: int) -> np.ndarray:
    """(H, W) mask of pixels whose probe rays all hit one rough-conductor shape."""
    shape, _ = pixel_hits(scene, width, height)
    materials = shape_materials(scene)[np.maximum(shape, 0)]
    glossy = np.isin(
        materials, np.flatnonzero(scene.materials["type"] == MATERIAL_TYPES["roughconductor"])
    )
    same = (shape == shape[..., :1]).all(axis=-1)
    return glossy.all(axis=-1) & same & (shape[..., 0] != NO_HIT)


def glossy_highlight_pixel(scene: Scene, image: np.ndarray) -> ProbePixel:
    """The brightest pixel of a short render `image` (H, W, 3) among pixels seeing one glossy
    surface, at least 3 pixels inside that surface's region. Brightness is the channel mean
    after a 5 x 5 median filter, so that a lone firefly of a noisy render is not chosen."""
    brightness, interior = glossy_brightness(scene, image)
    y, x = argmax_where(brightness, interior)
    return ProbePixel(
        x,
        y,
        image.shape[1],
        "glossy highlight",
        {"short_render_radiance": float(brightness[y, x])},
    )


def glossy_highlight_edge_pixel(scene: Scene, image: np.ndarray) -> ProbePixel:
    """A pixel on the edge of the glossy highlight of a short render `image` (H, W, 3), where
    its brightness falls off most steeply. Brightness and pixels as glossy_highlight_pixel; the
    highlight is the connected region around the brightest pixel where the brightness is at
    least half that peak; its edge, the highlight's pixels with a 4-neighbour below half the
    peak; of those, the one with the largest brightness gradient (Gaussian derivative, sigma 1
    pixel, truncated at 2 pixels)."""
    brightness, interior = glossy_brightness(scene, image)
    peak_at = argmax_where(brightness, interior)
    half = 0.5 * brightness[peak_at]
    regions, _ = ndimage.label(interior & (brightness >= half))
    highlight = regions == regions[peak_at]
    dimmer = interior & (brightness < half)
    edge = highlight & ndimage.binary_dilation(dimmer)  # the default structure: 4-neighbours
    if not edge.any():
        raise ParameterError("the glossy highlight has no edge inside the glossy surface")
    steepness = ndimage.gaussian_gradient_magnitude(brightness, 1.0, truncate=2.0)
    y, x = argmax_where(steepness, edge)
    return ProbePixel(
        x,
        y,
        image.shape[1],
        "glossy highlight edge",
        {
            "short_render_radiance": float(brightness[y, x]),
            "highlight_peak_radiance": float(brightness[peak_at]),
            "highlight_peak_pixel": [peak_at[1], peak_at[0]],
        },
    )


def argmax_where(values: np.ndarray, where: np.ndarray) -> tuple[int, int]:
    """(y, x) of the largest of `values` (H, W) where `where` (H, W) holds; the first in row
    order on ties."""
    y, x = np.unravel_index(int(np.argmax(np.where(where, values, -np.inf))), values.shape)
    return int(y), int(x)


def glossy_brightness(scene: Scene, image: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(brightness, interior), both (H, W): the channel mean of `image` (H, W, 3) after a 5 x 5
    median filter, and the pixels at least 3 pixels inside the region of glossy_pixels, where
    that filter reads glossy pixels only."""
    height, width, _ = image.shape
    mask = glossy_pixels(scene, width, height)
    interior = ndimage.distance_transform_edt(np.pad(mask, 1))[1:-1, 1:-1] >= 3
    if not interior.any():
        raise ParameterError("the scene has no glossy surface in view")
    return ndimage.median_filter(image.mean(axis=-1), size=5), interior


# ---------------------------------------------------------------------------------------------
# Tracing one pixel many times


@dataclass
class PixelRuns:
    """R sample sets of one pixel with their radiance (traced-sample order), and the time the
    device took to draw and trace them (seconds, whole launch)."""

    sets: SampleSets
    radiance: np.ndarray  # (T, 3) float64
    trace_seconds: float

    @property
    def runs(self) -> int:
        return len(self.sets.offsets) - 1


def trace_pixel_runs(
    runtime: Runtime,
    tracer: PathTracer,
    sampler: SamplerConfig,
    seed: int,
    pixel: int,
    runs: int,
    width: int,
    height: int,
    first_redraw: int = 0,
) -> PixelRuns:
    """Draw and trace `runs` independent sample sets of one pixel in one launch (run r uses
    redraw number first_redraw + r)."""
    pixels = np.full(runs, pixel, np.uint32)
    redraws = np.arange(first_redraw, first_redraw + runs, dtype=np.uint32)
    start = time.perf_counter()
    device_sets = generate_sample_sets(runtime, sampler, seed, pixels, redraws, (width, height))
    result = tracer.trace(device_sets, seed, width, height)
    radiance = result.to_host()
    sets = device_sets.to_host(runtime.queue)
    seconds = time.perf_counter() - start
    return PixelRuns(sets, radiance.astype(np.float64), seconds)
