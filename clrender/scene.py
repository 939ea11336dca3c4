"""Scene files: reading and validating them; the device records come from scene_device.

A scene file has three parts: ``[camera]``, named ``[materials.NAME]`` tables and a
``[[shapes]]`` array. Unknown keys, missing fields, wrong types and non-finite numbers are
errors (`SceneError`, naming the file, the object and the field). Lengths are in scene units
(whatever the file uses), angles in degrees, colours are linear RGB.

``[camera]`` (a pinhole; image row 0 is the top of the image, image right is
``cross(forward, up)``, the usual right-handed look-at camera):

=============  ============  =========  =====================================================
field          type          default    meaning
=============  ============  =========  =====================================================
look_from      [x, y, z]     required   eye position
look_at        [x, y, z]     required   point at the image centre
up             [x, y, z]     [0, 1, 0]  up direction (need not be orthogonal to the view)
fov            degrees       required   vertical field of view, in (0, 180)
resolution     [w, h]        required   default image size in pixels
handedness     string        "right"    "left": image right is cross(up, forward), the
                                        mirror image, as pbrt's left-handed camera draws
                                        a scene (the pbrt importer writes it)
=============  ============  =========  =====================================================

``[materials.NAME]``, selected by ``type``:

=================  ===========  =========  ===================================================
type / field       type         default    meaning
=================  ===========  =========  ===================================================
diffuse.albedo     RGB in [0,1] required   Lambertian reflectance
diffuse.two_sided  bool         true       false: a back-side hit is black (like Mitsuba)
dielectric.ior     number > 0   1.5        interior index of refraction (exterior is 1);
                                           smooth interface, exact unpolarised Fresnel,
                                           reflection and refraction; the side is given
                                           by the surface normal (sphere: outwards)
roughconductor     (GGX)                   glossy metal: GGX microfacet distribution,
                                           height-correlated Smith masking, exact conductor
                                           Fresnel, visible-normal sampling
 .alpha            [1e-3, 1]    0.1        the microfacet alpha itself (Mitsuba's
                                           convention; pbrt's `roughness` is remapped)
 .eta              RGB > 0      aluminium  real part of the index of refraction
                                           (default 1.657, 0.880, 0.521)
 .k                RGB >= 0     aluminium  imaginary part (default 9.224, 6.270, 4.837)
 .two_sided        bool         true       false: a back-side hit is black
=================  ===========  =========  ===================================================

``[[shapes]]``, selected by ``type``; every shape has an optional ``name`` (used in messages)
and ``material`` (a material name; required except on an emitter, which then only emits):

==================  ===========  =========  ==================================================
type / field        type         default    meaning
==================  ===========  =========  ==================================================
quad.corner         [x, y, z]    (a)        one corner of a parallelogram
quad.edge1, .edge2  [x, y, z]    (a)        its two edges from the corner; the normal
                                            cross(edge1, edge2) gives the front side
quad.vertices       4 x [x,y,z]  (a)        alternative: v0, v1, v2, v3 in order, a planar
                                            parallelogram (v2 = v1 + v3 - v0, checked);
                                            corner v0, edges v1 - v0 and v3 - v0
quad.emission       RGB >= 0     none       makes the quad a one-sided area emitter of this
                                            radiance, emitting on its front side
box.min, .max       [x, y, z]    required   opposite corners, min < max on every axis
box.rotate_y        degrees      0          rotation about the y axis (right-handed),
                                            applied first
box.translate       [x, y, z]    [0,0,0]    then this translation; the box becomes 6
                                            quads with outward normals
sphere.center       [x, y, z]    required   centre
sphere.radius       number > 0   required   radius; the normal points outwards
sphere.emission     RGB >= 0     none       makes the sphere a one-sided diffuse emitter of
                                            this radiance, emitting outwards (invisible
                                            from inside); lit points sample the cone of
                                            directions it subtends (its visible cap)
mesh.positions      V x [x,y,z]  (b)        vertices of a triangle mesh
mesh.indices        T x [i,j,k]  (b)        triangles, 0-based vertex indices; the front
                                            side is counter-clockwise: geometric normal
                                            cross(p[j] - p[i], p[k] - p[i]) (pbrt's)
mesh.normals        V x [x,y,z]  none       per-vertex shading normals (interpolated, turned
                                            to the front side; the geometric normal still
                                            decides sidedness and ray offsets); a zero normal
                                            adds nothing to the interpolation, and where the
                                            interpolated normal is zero the geometric normal
                                            shades (pbrt-v4's rule)
mesh.file           path         (b)        alternative: a PLY or OBJ file (relative to the
                                            scene file; clrender/mesh_files.py), normals
                                            from the file when it has them
mesh.emission       RGB >= 0     none       makes every triangle of the mesh a one-sided area
                                            emitter of this radiance, emitting on its front
                                            (counter-clockwise) side, whatever the shading
                                            normals; lit points pick a triangle by power and
                                            sample it uniformly by area
==================  ===========  =========  ==================================================

(a) a quad takes either ``corner`` + ``edge1`` + ``edge2`` or ``vertices``.
(b) a mesh takes either ``positions`` + ``indices`` (+ ``normals``) or ``file``. Degenerate
triangles (zero area, or repeated indices) are skipped with a warning; a mesh left with none is
an error. Scenes of more than
about 200 quads or 12 triangles (scene_device.BRUTE_FORCE_LIMIT) are traced through a BVH
(clrender/bvh.py), smaller ones by brute force.

Optional top-level ``description`` (string). Loading warns (`SceneWarning`, listed in
`Scene.warnings`) when a scene will not render what one expects: no emitter (the image is
black), or the camera inside a solid shape. That check is cheap and deliberately narrow:
``look_from`` strictly inside a sphere, or strictly inside a box (in the box's own frame,
before its rotation and translation). Quads are never solids, so a camera inside a room of
quads (the Cornell box, the furnace) is not flagged. clrender.scene_checks adds the whole-scene
checks against the device's float32: a scene spanning under 1e-15 is refused; a shape below
float32 resolution at its distance (a mesh by its triangles) and a camera on a surface (a mesh
triangle too) are warned about.

This module is the reading side of the scene: files, their validation, errors and warnings, and
the loaded `Scene`. The byte layout the kernels read (the NumPy twins of kernels/scene_types.h
and the packing into them) is clrender/scene_device.py, which this module imports and which
imports nothing back.
"""

from __future__ import annotations

import difflib
import errno
import math
import stat
import tomllib
import warnings
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from clrender.errors import ClrenderError
from clrender.mesh_files import MeshFileError, read_mesh_file
from clrender.package_data import shipped_dir
from clrender.scene_checks import (
    MeshGeometry,
    ShapeGeometry,
    camera_on_surface,
    extent_error,
    unresolved_shape_notes,
)
from clrender.scene_device import (
    BRUTE_FORCE_LIMIT,
    MATERIAL_NONE,
    NORMALS_DTYPE,
    QUAD_BLOCK_WIDTH,
    TRIANGLE_DTYPE,
    pack_bvh,
    pack_camera,
    pack_emitters,
    pack_materials,
    pack_quads,
    pack_scene_quad_blocks,
    pack_spheres,
    pack_triangles,
    scene_bounds,
)


class SceneError(ClrenderError, ValueError):
    """A scene file cannot be read: the message names the file, the object and the field."""


class SceneWarning(UserWarning):
    """A scene loads but will not render what one expects (e.g. it has no emitter)."""


ALUMINIUM_ETA = (1.657, 0.880, 0.521)
ALUMINIUM_K = (9.224, 6.270, 4.837)
# Scene numbers the device's float32 holds: magnitudes up to SCENE_NUMBER_LIMIT (their squares,
# distances and areas stay finite: float32 ends at 3.4e38), and none between 0 and the smallest
# normal float32 (it would become 0 or lose its digits).
SCENE_NUMBER_LIMIT = 1e18
FLOAT32_SMALLEST = float(np.finfo(np.float32).tiny)
# Relative tolerance of the parallelogram check of quad vertices.
PARALLELOGRAM_TOLERANCE = 1e-5


@dataclass(frozen=True)
class Camera:
    """A pinhole camera; `basis` gives the vectors the kernel uses."""

    look_from: tuple[float, float, float]
    look_at: tuple[float, float, float]
    up: tuple[float, float, float]
    fov: float  # vertical field of view, degrees
    resolution: tuple[int, int]  # (width, height)
    handedness: str = "right"  # "left": pbrt's camera, image right = cross(up, forward)

    def basis(self, width: int, height: int) -> np.ndarray:
        """The kernel's CAMERA_DTYPE record for a width x height image (see
        scene_device.pack_camera): ray direction forward + sx * right + sy * up."""
        return pack_camera(
            self.look_from, self.look_at, self.up, self.fov, width, height, self.handedness
        )


@dataclass
class Scene:
    """A loaded scene: camera plus device-ready structured arrays (scene_device's dtypes).

    quads: every quad, boxes expanded (6 each); spheres; materials (indexed by the shapes'
    `material`, -1 for a pure emitter); emitters (one per emitting quad, then one per
    emitting sphere, with the light selection pdf proportional to power = area * mean
    radiance).
    """

    path: Path
    name: str
    description: str
    camera: Camera
    materials: np.ndarray
    quads: np.ndarray
    spheres: np.ndarray
    emitters: np.ndarray
    material_names: list[str]
    quad_names: list[str]
    sphere_names: list[str]
    warnings: list[str] = field(default_factory=list)
    triangles: np.ndarray = field(default_factory=lambda: np.zeros(0, TRIANGLE_DTYPE))
    triangle_normals: np.ndarray = field(default_factory=lambda: np.zeros(0, NORMALS_DTYPE))
    mesh_names: list[str] = field(default_factory=list)
    mesh_first_triangle: list[int] = field(default_factory=list)  # per mesh, into triangles

    @property
    def resolution(self) -> tuple[int, int]:
        return self.camera.resolution

    @property
    def primitive_count(self) -> int:
        return len(self.quads) + len(self.spheres) + len(self.triangles)

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        return scene_bounds(self.quads, self.spheres, self.triangles)

    def bvh(self, brute_force_limit: int = BRUTE_FORCE_LIMIT) -> tuple[np.ndarray, np.ndarray]:
        """(BVH nodes, leaf records) of the scene, empty when brute force is cheaper
        (scene_device.pack_bvh; brute_force_limit -1: always a BVH, over the primitives but up
        to BVH_MAX_BRUTE_QUADS quads, which are tested beside it: none for a scene of such quads
        alone)."""
        return pack_bvh(self.quads, self.spheres, self.triangles, brute_force_limit)

    def quad_blocks(self, width: int = QUAD_BLOCK_WIDTH) -> np.ndarray:
        return pack_scene_quad_blocks(self.quads, self.spheres, self.quad_names, width)


# --------------------------------------------------------------------------- locating files


def scenes_dir() -> Path:
    """The shipped scenes: inside the installed package, else the source checkout."""
    return shipped_dir("scenes", "shipped scenes")


def list_scenes() -> list[str]:
    """Names of the shipped scenes (load them with `load_scene(name)`)."""
    return sorted(path.stem for path in scenes_dir().glob("*.toml"))


def resolve_scene_path(path_or_name: str | Path) -> Path:
    """A path to an existing file, or a bare shipped scene name ("cornell-box")."""
    path = Path(path_or_name)
    text = str(path_or_name)
    if not text.strip():  # Path("") is ".", a directory
        raise SceneError(
            f"no scene given (an empty name); shipped scenes: {', '.join(list_scenes())}"
        )
    try:
        mode = path.stat().st_mode
    except OSError as err:
        if err.errno == errno.ENAMETOOLONG:
            raise SceneError(f"scene file {text[:60]!r}...: name too long") from None
        mode = None  # does not exist: perhaps a shipped scene's name
    if mode is not None:
        if stat.S_ISREG(mode):
            return path
        what = "a directory" if stat.S_ISDIR(mode) else "not a regular file (a FIFO or device)"
        raise SceneError(f"scene file {text!r} is {what}: give a .toml file or a scene name")
    if "/" not in text and "\\" not in text and not text.lower().endswith(".pbrt"):
        shipped = scenes_dir() / (text if text.endswith(".toml") else f"{text}.toml")
        if shipped.is_file():
            return shipped
        known = list_scenes()
        hint = _did_you_mean(text.removesuffix(".toml"), known)
        raise SceneError(
            f"no scene file {text!r} and no shipped scene of that name{hint}; "
            f"shipped scenes: {', '.join(known)}"
        )
    raise SceneError(f"scene file {text!r} does not exist")


def load_scene(path_or_name: str | Path) -> Scene:
    """Read and validate a scene file (or a shipped scene by name); a .pbrt file is read by
    clrender.pbrt (pbrt-v4's format, a subset)."""
    path = resolve_scene_path(path_or_name)
    if path.suffix.lower() == ".pbrt":  # scene.PBRT too, as pbrt-v4's HasExtension compares
        from clrender.pbrt import load_pbrt_scene

        return load_pbrt_scene(path)
    try:
        data = path.read_bytes()
    except OSError as err:
        raise SceneError(f"{path}: cannot read: {err.strerror}") from None
    return SceneBuilder(path).build(parse_scene_text(path, data))


def parse_scene_text(path: Path, data: bytes) -> dict:
    """The TOML document of a scene file's bytes; SceneError (one line) if they are not UTF-8
    TOML or nest beyond what a scene needs."""
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as err:
        raise SceneError(
            f"{path}: not UTF-8 text (byte 0x{data[err.start]:02x} at offset {err.start}): "
            "scene files are TOML, which must be UTF-8"
        ) from None
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as err:
        kind = (
            ""
            if path.suffix.lower() == ".toml"
            else (
                f" (scene files are TOML, .toml, or pbrt-v4's format, .pbrt: read as TOML, this "
                f"{path.suffix or 'file without a suffix'} is not)"
            )
        )
        raise SceneError(f"{path}: TOML syntax error: {err}{kind}") from None
    except RecursionError:
        raise SceneError(
            f"{path}: arrays or tables nested too deeply to read (a scene nests at most 3)"
        ) from None


# --------------------------------------------------------------------------- validation


def _did_you_mean(word: str, choices: list[str] | tuple[str, ...]) -> str:
    close = difflib.get_close_matches(word, list(choices), n=1, cutoff=0.6)
    return f" (did you mean {close[0]!r}?)" if close else ""


class _Table:
    """One TOML table being read: every access is checked and named in error messages."""

    def __init__(self, path: Path, where: str, data: object):
        self.path = path
        self.where = where
        if not isinstance(data, dict):
            self.fail(None, f"expected a table, got {_describe(data)}")
        self.data = data

    def fail(self, key: str | None, message: str):
        field_part = f", field {key!r}" if key else ""
        raise SceneError(f"{self.path}: {self.where}{field_part}: {message}")

    def check_keys(self, allowed: tuple[str, ...]) -> None:
        for key in self.data:
            if key not in allowed:
                hint = _did_you_mean(key, allowed)
                self.fail(key, f"unknown field{hint}; accepted: {', '.join(allowed)}")

    def has(self, key: str) -> bool:
        return key in self.data

    def get(self, key: str, default: object):
        if key in self.data:
            return self.data[key]
        if default is _REQUIRED:
            self.fail(key, "missing (required)")
        return default

    def string(self, key: str, default: object = None) -> str | None:
        value = self.get(key, default)
        if value is not None and not isinstance(value, str):
            self.fail(key, f"expected a string, got {_describe(value)}")
        return value

    def boolean(self, key: str, default: object) -> bool:
        value = self.get(key, default)
        if not isinstance(value, bool):
            self.fail(key, f"expected true or false, got {_describe(value)}")
        return value

    def number(self, key: str, default: object = None, low=None, high=None, what="") -> float:
        value = self.get(key, default)
        if isinstance(value, bool) or not isinstance(value, int | float):
            self.fail(key, f"expected a number{what}, got {_describe(value)}")
        value = float(value)
        if not math.isfinite(value):
            self.fail(key, f"expected a finite number{what}, got {value}")
        self.check_device_range(key, value)
        if (low is not None and value < low) or (high is not None and value > high):
            self.fail(key, f"expected a number{what}, got {value:g}")
        return value

    def vector(self, key: str, default: object = None, length: int = 3, what: str = "") -> tuple:
        value = self.get(key, default)
        expected = f"a list of {length} finite numbers{what}"
        if not isinstance(value, list | tuple) or len(value) != length:
            self.fail(key, f"expected {expected}, got {_describe(value)}")
        for item in value:
            if isinstance(item, bool) or not isinstance(item, int | float):
                self.fail(key, f"expected {expected}, got {_describe(value)}")
            if not math.isfinite(float(item)):
                self.fail(key, f"expected {expected}, got a non-finite entry in {value}")
            self.check_device_range(key, float(item))
        return tuple(float(item) for item in value)

    def check_device_range(self, key: str, value: float) -> None:
        """The device computes in float32, with squares of coordinates: a number must be 0 or
        within [FLOAT32_SMALLEST, SCENE_NUMBER_LIMIT] in magnitude."""
        size = abs(value)
        if size > SCENE_NUMBER_LIMIT:
            self.fail(
                key,
                f"{value:g} is too large for the device's float32 arithmetic (a scene's numbers "
                f"stay within {SCENE_NUMBER_LIMIT:g}, so that their squares fit)",
            )
        if 0.0 < size < FLOAT32_SMALLEST:
            self.fail(
                key,
                f"{value:g} underflows the device's float32 (smallest normal "
                f"{FLOAT32_SMALLEST:.3g}): use 0 or a larger unit",
            )

    def rgb(self, key: str, default: object = None, high: float | None = None) -> tuple:
        bound = f" in [0, {high:g}]" if high is not None else " >= 0"
        value = self.vector(key, default, 3, what=bound)
        if any(c < 0.0 or (high is not None and c > high) for c in value):
            self.fail(key, f"expected 3 numbers{bound} (RGB), got {list(value)}")
        return value


_REQUIRED = object()


def _describe(value: object) -> str:
    kind = {bool: "a boolean", str: "a string", int: "an integer", float: "a number"}
    if isinstance(value, list):
        return f"a list of {len(value)} ({_toml_text(value)})" if len(value) < 8 else "a long list"
    if isinstance(value, dict):
        return "a table"
    return f"{kind.get(type(value), type(value).__name__)} ({_toml_text(value)})"


def _toml_text(value: object) -> str:
    """A value as the scene file spells it: true, not Python's True."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, list):
        return "[" + ", ".join(map(_toml_text, value)) + "]"
    return repr(value)


SHAPE_FIELDS = {
    "quad": ("type", "name", "material", "corner", "edge1", "edge2", "vertices", "emission"),
    "box": ("type", "name", "material", "min", "max", "rotate_y", "translate"),
    "sphere": ("type", "name", "material", "center", "radius", "emission"),
    "mesh": ("type", "name", "material", "positions", "indices", "normals", "file", "emission"),
}
MESH_ARRAYS = ("positions", "indices", "normals")
# A triangle is degenerate when |cross(e1, e2)| <= this times |e1| |e2| (as quads' check).
DEGENERATE_TRIANGLE = 1e-9
MATERIAL_FIELDS = {
    "diffuse": ("type", "albedo", "two_sided"),
    "dielectric": ("type", "ior"),
    "roughconductor": ("type", "alpha", "eta", "k", "two_sided"),
}
EMITTING_SHAPES = ("quad", "sphere", "mesh")  # shapes that take `emission`
CAMERA_FIELDS = ("look_from", "look_at", "up", "fov", "resolution", "handedness")
CAMERA_HANDEDNESS = ("right", "left")
TOP_FIELDS = ("description", "camera", "materials", "shapes")


class SceneBuilder:
    """Turns a parsed TOML document into a Scene, validating as it goes."""

    def __init__(self, path: Path):
        self.path = path
        self.material_index: dict[str, int] = {}
        self.materials: list[dict] = []  # scene_device.pack_materials' input
        self.quads: list[dict] = []
        self.quad_names: list[str] = []
        self.spheres: list[dict] = []
        self.sphere_names: list[str] = []
        self.solids: list[tuple[str, Callable[[np.ndarray], bool]]] = []  # (label, inside)
        self.geometry: list[ShapeGeometry] = []  # every quad and sphere, for scene_checks
        self.meshes: list[dict] = []  # scene_device.pack_triangles' input
        self.mesh_names: list[str] = []
        self.mesh_bounds: list[ShapeGeometry] = []  # a sphere around each mesh (extent only)
        self.mesh_geometry: list[MeshGeometry] = []  # each mesh's triangles, for scene_checks
        self.notes: list[str] = []  # warnings raised while reading shapes

    def build(self, document: dict) -> Scene:
        top = _Table(self.path, "top level", document)
        for key in ("emitters", "emitter", "lights", "light"):
            if key in document:
                top.fail(
                    key,
                    "unknown field: an emitter is a [[shapes]] quad, sphere or mesh with an "
                    "`emission` field",
                )
        top.check_keys(TOP_FIELDS)
        description = top.string("description", "") or ""
        camera = self.read_camera(_Table(self.path, "[camera]", top.get("camera", _REQUIRED)))
        materials = top.get("materials", {})
        if not isinstance(materials, dict):
            top.fail("materials", f"expected tables [materials.NAME], got {_describe(materials)}")
        for name, data in materials.items():
            self.read_material(name, _Table(self.path, f"[materials.{name}]", data))
        shapes = top.get("shapes", _REQUIRED)
        if not isinstance(shapes, list):
            top.fail("shapes", f"expected an array of tables [[shapes]], got {_describe(shapes)}")
        for index, data in enumerate(shapes):
            self.read_shape(index, data)
        return self.finish(camera, description)

    # -- camera
    def read_camera(self, table: _Table) -> Camera:
        table.check_keys(CAMERA_FIELDS)
        look_from = table.vector("look_from", _REQUIRED)
        look_at = table.vector("look_at", _REQUIRED)
        up = table.vector("up", [0.0, 1.0, 0.0])
        fov = table.number("fov", _REQUIRED, 1e-3, 179.0, " of degrees in (0, 180)")
        resolution = table.get("resolution", _REQUIRED)
        if (
            not isinstance(resolution, list)
            or len(resolution) != 2
            or not all(isinstance(r, int) and not isinstance(r, bool) and r > 0 for r in resolution)
        ):
            table.fail(
                "resolution",
                f"expected [width, height], positive integers, got {_describe(resolution)}",
            )
        forward = np.subtract(look_at, look_from)
        if np.linalg.norm(forward) == 0.0:
            table.fail("look_at", "must differ from look_from")
        if np.linalg.norm(np.cross(forward, up)) <= 1e-9 * np.linalg.norm(forward) * max(
            np.linalg.norm(up), 1e-300
        ):
            table.fail("up", f"must not be zero or parallel to the view direction, got {list(up)}")
        handedness = table.string("handedness", "right")
        if handedness not in CAMERA_HANDEDNESS:
            table.fail(
                "handedness",
                f"expected one of {', '.join(map(repr, CAMERA_HANDEDNESS))}, got {handedness!r}",
            )
        return Camera(look_from, look_at, up, fov, (resolution[0], resolution[1]), handedness)

    # -- materials
    def read_material(self, name: str, table: _Table) -> None:
        kind = table.string("type", _REQUIRED)
        if kind not in MATERIAL_FIELDS:
            hint = _did_you_mean(kind, tuple(MATERIAL_FIELDS))
            table.fail(
                "type",
                f"unknown material type {kind!r}{hint}; accepted: {', '.join(MATERIAL_FIELDS)}",
            )
        table.check_keys(MATERIAL_FIELDS[kind])
        record: dict = {"type": kind, "two_sided": True}
        if kind == "diffuse":
            record["albedo"] = table.rgb("albedo", _REQUIRED, high=1.0)
            record["two_sided"] = table.boolean("two_sided", True)
        elif kind == "dielectric":
            ior = table.number("ior", 1.5, what=" > 0")
            if ior <= 0.0:
                table.fail("ior", f"expected a number > 0, got {ior:g}")
            record["eta"] = (ior, ior, ior)
        else:
            record["alpha"] = table.number("alpha", 0.1, 1e-3, 1.0, " in [0.001, 1]")
            eta = table.rgb("eta", list(ALUMINIUM_ETA))
            if min(eta) <= 0.0:
                table.fail("eta", f"expected 3 numbers > 0, got {list(eta)}")
            record["eta"] = eta
            record["k"] = table.rgb("k", list(ALUMINIUM_K))
            record["two_sided"] = table.boolean("two_sided", True)
        self.material_index[name] = len(self.materials)
        self.materials.append(record)

    # -- shapes
    def read_shape(self, index: int, data: object) -> None:
        label = f"shapes[{index}]"
        if isinstance(data, dict) and isinstance(data.get("name"), str):
            label += f" ({data['name']!r})"
        table = _Table(self.path, label, data)
        kind = table.string("type", _REQUIRED)
        if kind not in SHAPE_FIELDS:
            hint = _did_you_mean(kind, tuple(SHAPE_FIELDS))
            table.fail(
                "type", f"unknown shape type {kind!r}{hint}; accepted: {', '.join(SHAPE_FIELDS)}"
            )
        if kind not in EMITTING_SHAPES and table.has("emission"):
            table.fail(
                "emission", f"a {kind} cannot be an emitter: only quads, spheres and meshes emit"
            )
        if table.has("emitter"):  # Mitsuba's nested emitter: here a quad field, no types
            table.fail(
                "emitter",
                "unknown field: there are no emitter types; a quad, sphere or mesh emits "
                "with `emission = [r, g, b]`",
            )
        table.check_keys(SHAPE_FIELDS[kind])
        name = table.string("name", None) or f"shapes[{index}]"
        emission = table.rgb("emission", None) if table.has("emission") else None
        if emission is not None and max(emission) == 0.0:
            emission = None
        if emission is None and table.has("emission") and not table.has("material"):
            table.fail(
                "material",
                "missing: a shape needs a material unless it emits, and its emission "
                "[0, 0, 0] emits nothing",
            )
        material = self.material_reference(table, required=emission is None)
        if kind == "quad":
            corner, edge1, edge2 = self.read_quad_frame(table)
            self.add_quad(table, name, corner, edge1, edge2, material, emission)
        elif kind == "box":
            self.read_box(table, name, label, material)
        elif kind == "mesh":
            self.read_mesh(table, name, label, material, emission)
        else:
            center = table.vector("center", _REQUIRED)
            radius = table.number("radius", _REQUIRED, what=" > 0")
            if radius <= 0.0:
                table.fail("radius", f"expected a number > 0, got {radius:g}")
            self.spheres.append(
                {"center": center, "radius": radius, "material": material, "emission": emission}
            )
            self.sphere_names.append(name)
            self.geometry.append(ShapeGeometry(label, center=np.array(center), radius=radius))
            centre = np.array(center)
            self.solids.append(
                (f"{label} (a sphere)", lambda p: float(np.linalg.norm(p - centre)) < radius)
            )

    def material_reference(self, table: _Table, required: bool) -> int:
        name = table.string("material", _REQUIRED if required else None)
        if name is None:
            return MATERIAL_NONE
        if name not in self.material_index:
            known = tuple(self.material_index)
            hint = _did_you_mean(name, known)
            table.fail(
                "material",
                f"unknown material {name!r}{hint}; defined: {', '.join(known) or 'none'}",
            )
        return self.material_index[name]

    def read_quad_frame(self, table: _Table) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        frame_keys = [key for key in ("corner", "edge1", "edge2") if table.has(key)]
        if table.has("vertices"):
            if frame_keys:
                table.fail(frame_keys[0], "give either corner/edge1/edge2 or vertices, not both")
            return self.read_quad_vertices(table)
        corner = np.array(table.vector("corner", _REQUIRED))
        edge1 = np.array(table.vector("edge1", _REQUIRED))
        edge2 = np.array(table.vector("edge2", _REQUIRED))
        return corner, edge1, edge2

    def read_quad_vertices(self, table: _Table) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        value = table.data["vertices"]
        if not isinstance(value, list) or len(value) != 4:
            table.fail("vertices", f"expected 4 points [x, y, z], got {_describe(value)}")
        points = []
        for i, point in enumerate(value):
            inner = _Table(self.path, table.where, {f"vertices[{i}]": point})
            points.append(np.array(inner.vector(f"vertices[{i}]")))
        v0, v1, v2, v3 = points
        scale = max(np.abs(np.array(points)).max(), np.linalg.norm(v1 - v0), 1e-30)
        if np.abs(v1 + v3 - v0 - v2).max() > PARALLELOGRAM_TOLERANCE * scale:
            table.fail(
                "vertices",
                "not a parallelogram: v2 must equal v1 + v3 - v0 "
                f"(off by {np.abs(v1 + v3 - v0 - v2).max():g})",
            )
        return v0, v1 - v0, v3 - v0

    def add_quad(self, table, name, corner, edge1, edge2, material, emission) -> None:
        normal = np.cross(edge1, edge2)
        area = float(np.linalg.norm(normal))
        scale = float(np.linalg.norm(edge1) * np.linalg.norm(edge2))
        if not (area > 1e-9 * scale and area > 0.0):
            key = "vertices" if table.has("vertices") else "edge2"
            table.fail(key, "degenerate quad: its edges are zero or parallel")
        self.quads.append(
            {
                "corner": corner,
                "edge1": edge1,
                "edge2": edge2,
                "material": material,
                "emission": emission,
            }
        )
        self.quad_names.append(name)
        self.geometry.append(ShapeGeometry(table.where, corner, edge1, edge2))

    def read_box(self, table: _Table, name: str, label: str, material: int) -> None:
        low = np.array(table.vector("min", _REQUIRED))
        high = np.array(table.vector("max", _REQUIRED))
        if np.any(high <= low):
            table.fail(
                "max",
                f"expected max > min on every axis (a box of positive size), "
                f"got min {low.tolist()}, max {high.tolist()}",
            )
        angle = math.radians(table.number("rotate_y", 0.0))
        translate = np.array(table.vector("translate", [0.0, 0.0, 0.0]))
        for face, (corner, edge1, edge2) in enumerate(box_faces(low, high)):
            rotated = [rotate_y(v, angle) for v in (corner, edge1, edge2)]
            self.quads.append(
                {
                    "corner": rotated[0] + translate,
                    "edge1": rotated[1],
                    "edge2": rotated[2],
                    "material": material,
                    "emission": None,
                }
            )
            self.quad_names.append(f"{name}/face{face}")
            self.geometry.append(
                ShapeGeometry(f"{label} face {face}", rotated[0] + translate, *rotated[1:])
            )

        def inside(point: np.ndarray) -> bool:
            local = rotate_y(point - translate, -angle)
            return bool(np.all(low < local) and np.all(local < high))

        self.solids.append((f"{label} (a box)", inside))

    # -- meshes
    def read_mesh(
        self, table: _Table, name: str, label: str, material: int, emission: tuple | None
    ) -> None:
        if table.has("file"):
            inline = [key for key in MESH_ARRAYS if table.has(key)]
            if inline:
                table.fail(inline[0], "give either file or positions/indices/normals, not both")
            file_path = self.path.parent / table.string("file")
            try:
                mesh = read_mesh_file(file_path)
            except MeshFileError as err:
                table.fail("file", str(err))
            positions, indices, normals = mesh.positions, mesh.indices, mesh.normals
            where = "file"
        else:
            positions = self.read_array(table, "positions", float, required=True)
            indices = self.read_array(table, "indices", int, required=True)
            normals = self.read_array(table, "normals", float, required=False)
            where = None
        self.check_mesh_numbers(table, where or "positions", positions)
        if normals is not None:
            self.check_mesh_numbers(table, where or "normals", normals)
            if normals.shape != positions.shape:
                table.fail(
                    where or "normals",
                    f"expected one normal per position ({len(positions)}), got {len(normals)}",
                )
        bad = np.flatnonzero((indices < 0) | (indices >= len(positions)))
        if len(bad):
            i = bad[0] if indices.ndim == 1 else np.unravel_index(bad[0], indices.shape)[0]
            table.fail(
                where or "indices",
                f"triangle {i} has index {indices.reshape(-1)[bad[0]]} outside "
                f"0..{len(positions) - 1} (the positions)",
            )
        # Degenerate triangles (zero area, repeated vertices) are skipped with a warning
        p0, p1, p2 = (positions[indices[:, k]] for k in range(3))
        e1, e2 = p1 - p0, p2 - p0
        area = np.linalg.norm(np.cross(e1, e2), axis=1)
        scale = np.linalg.norm(e1, axis=1) * np.linalg.norm(e2, axis=1)
        degenerate = ~((area > DEGENERATE_TRIANGLE * scale) & (area > 0.0))
        if degenerate.all():
            table.fail(where or "indices", "every triangle is degenerate (zero area)")
        if degenerate.any():
            first = int(np.flatnonzero(degenerate)[0])
            self.notes.append(
                f"{self.path}: {label}: skipped {int(degenerate.sum())} degenerate "
                f"(zero-area) triangles of {len(indices)}, the first triangle {first}"
            )
            warnings.warn(self.notes[-1], SceneWarning, stacklevel=5)
            indices = indices[~degenerate]
        self.meshes.append(
            {
                "positions": positions,
                "indices": indices,
                "normals": normals,
                "material": material,
                "emission": emission,
            }
        )
        self.mesh_names.append(name)
        used = positions[np.unique(indices)]
        low, high = used.min(axis=0), used.max(axis=0)
        self.mesh_bounds.append(
            ShapeGeometry(label, center=0.5 * (low + high), radius=0.5 * np.linalg.norm(high - low))
        )
        self.mesh_geometry.append(MeshGeometry(label, positions, indices))

    def read_array(self, table: _Table, key: str, kind: type, required: bool) -> np.ndarray | None:
        """An inline mesh array of rows of 3 numbers (kind float) or integers (kind int)."""
        value = table.get(key, _REQUIRED if required else None)
        if value is None:
            return None
        what = "integers" if kind is int else "finite numbers"
        expected = f"expected a list of [a, b, c] rows of 3 {what}"
        if isinstance(value, np.ndarray):  # a pbrt plymesh's arrays (clrender.pbrt), not TOML
            if value.ndim != 2 or value.shape[1] != 3 or not len(value):
                table.fail(key, f"{expected}, got an array of shape {value.shape}")
            return value.astype(np.int64 if kind is int else np.float64, copy=False)
        allowed = (int,) if kind is int else (int, float)
        if not isinstance(value, list) or not value:
            table.fail(key, f"{expected}, got {_describe(value)}")
        for i, row in enumerate(value):
            if not (isinstance(row, list) and len(row) == 3):
                table.fail(key, f"{expected}, got row {i}: {_describe(row)}")
            for x in row:
                if type(x) not in allowed:
                    table.fail(key, f"{expected}, got {_describe(x)} in row {i}")
        return np.array(value, np.int64 if kind is int else np.float64)

    def check_mesh_numbers(self, table: _Table, key: str, values: np.ndarray) -> None:
        """Finite numbers the device's float32 holds (as _Table.check_device_range)."""
        if values.ndim != 2 or values.shape[1] != 3:
            table.fail(key, f"expected rows of 3 numbers, got shape {values.shape}")
        if not np.isfinite(values).all():
            row = int(np.flatnonzero(~np.isfinite(values).all(axis=1))[0])
            table.fail(key, f"row {row} has a non-finite number: {values[row].tolist()}")
        size = np.abs(values)
        if size.max() > SCENE_NUMBER_LIMIT:
            table.fail(key, f"{size.max():g} is too large for the device's float32 arithmetic")
        tiny = (size > 0.0) & (size < FLOAT32_SMALLEST)
        if tiny.any():
            table.fail(key, f"{size[tiny].min():g} underflows the device's float32")

    # -- packing
    def finish(self, camera: Camera, description: str) -> Scene:
        quads = pack_quads(self.quads)
        spheres = pack_spheres(self.spheres)
        materials = pack_materials(self.materials)
        triangles, triangle_normals = pack_triangles(self.meshes)
        emitters = pack_emitters(self.quads, quads, self.spheres, spheres, self.meshes, triangles)
        if len(quads) + len(spheres) + len(triangles) == 0:
            raise SceneError(f"{self.path}: shapes: the scene has no shapes")
        origin = np.array(camera.look_from)
        too_small = extent_error(self.geometry + self.mesh_bounds, origin)
        if too_small:
            raise SceneError(f"{self.path}: shapes: {too_small}")
        notes = list(self.notes)
        if len(emitters) == 0:
            notes.append(
                f"{self.path}: the scene has no emitter (no shape with emission): it renders black"
            )
            warnings.warn(notes[-1], SceneWarning, stacklevel=3)
        for label, inside in self.solids:
            if inside(origin):
                where = f"[camera] look_from {list(camera.look_from)} is inside {label}"
                notes.append(f"{self.path}: {where}: the image shows that shape from the inside")
                warnings.warn(notes[-1], SceneWarning, stacklevel=3)
        on_surface = camera_on_surface(self.geometry, origin, self.mesh_geometry)
        for note in ([on_surface] if on_surface else []) + unresolved_shape_notes(
            self.geometry, origin, self.mesh_geometry
        ):
            notes.append(f"{self.path}: {note}")
            warnings.warn(notes[-1], SceneWarning, stacklevel=3)
        return Scene(
            path=self.path,
            name=self.path.stem,
            description=description,
            camera=camera,
            materials=materials,
            quads=quads,
            spheres=spheres,
            emitters=emitters,
            material_names=list(self.material_index),
            quad_names=self.quad_names,
            sphere_names=self.sphere_names,
            warnings=notes,
            triangles=triangles,
            triangle_normals=triangle_normals,
            mesh_names=self.mesh_names,
            mesh_first_triangle=list(
                np.cumsum([0] + [len(m["indices"]) for m in self.meshes])[:-1].astype(int)
            ),
        )


def rotate_y(v: np.ndarray, angle: float) -> np.ndarray:
    """Right-handed rotation about +y: x' = cos x + sin z, z' = -sin x + cos z."""
    c, s = math.cos(angle), math.sin(angle)
    return np.array([c * v[0] + s * v[2], v[1], -s * v[0] + c * v[2]])


def box_faces(low: np.ndarray, high: np.ndarray) -> list[tuple[np.ndarray, ...]]:
    """The 6 faces of an axis-aligned box as (corner, edge1, edge2), normals outwards."""
    dx = np.array([high[0] - low[0], 0.0, 0.0])
    dy = np.array([0.0, high[1] - low[1], 0.0])
    dz = np.array([0.0, 0.0, high[2] - low[2]])
    return [
        (low.copy(), dy, dx),  # z = min, normal -z
        (low + dz, dx, dy),  # z = max, normal +z
        (low.copy(), dz, dy),  # x = min, normal -x
        (low + dx, dy, dz),  # x = max, normal +x
        (low.copy(), dx, dz),  # y = min, normal -y
        (low + dy, dz, dx),  # y = max, normal +y
    ]
