"""pbrt-v4 scene files: the subset clrender renders, read into clrender.scene's document.

`load_pbrt_scene(path)` reads a ``.pbrt`` file (``clrender.load_scene`` dispatches on the
suffix) and writes the same document dict a TOML scene file parses into, so
``SceneBuilder.build`` validates both alike (a plymesh's arrays are NumPy arrays there, which
the builder takes as it takes TOML's lists). Only what clrender can render exactly is read;
everything else is refused with one line naming the file, the line, the directive (and the
parameter) and what is supported.

======================================  ==========================================================
pbrt-v4 directive                       clrender
======================================  ==========================================================
Camera "perspective" "float fov"        [camera]; pbrt's fov spans the shorter image axis (the
                                        vertical fov is converted when the image is taller than
                                        wide); pbrt's left-handed camera space (x right, y up,
                                        z forward) gives ``handedness = "left"``, a mirroring
                                        camera transform gives "right"; the transform rigid
                                        up to uniform scale within SIMILARITY_TOLERANCE, its
                                        nearest similarity used
Film "rgb" x/yresolution                [camera] resolution (pbrt's default 1280 x 720)
LookAt, Transform, ConcatTransform,     the current transform (Transform's 16 numbers are
Translate, Scale, Rotate, Identity      column-major, as pbrt writes them)
AttributeBegin/End, Attribute           graphics state push/pop; Attribute "shape" | "light" |
                                        "material" sets default parameters
MakeNamedMaterial, NamedMaterial,       diffuse ("rgb reflectance") -> diffuse; conductor
Material                                ("rgb eta", "rgb k", roughness or uroughness =
                                        vroughness, remaproughness: alpha = sqrt(roughness))
                                        -> roughconductor; dielectric ("float eta") -> dielectric;
                                        names resolved when the file ends (pbrt-v4's order)
AreaLightSource "diffuse"               emission = "rgb L" x "float scale" on the shapes that
                                        follow; with a diffuse material of reflectance 0 the
                                        shape only emits
Shape "trianglemesh"                    quads when every triangle pair (2k, 2k+1) is a
                                        parallelogram with flat normals, else a mesh
Shape "bilinearmesh"                    quads (every patch must be a parallelogram)
Shape "plymesh"                         a mesh of the file's triangles (under the transform;
                                        front sides toward its normals N, as for trianglemesh)
Shape "sphere"                          a sphere (the transform a similarity: rotation, uniform
                                        scale, translation, within SIMILARITY_TOLERANCE)
Include                                 the file; a relative name (here and in plymesh) from
                                        the top-level file's folder (pbrt-v4's rule), else
                                        from the including file's
Integrator, Sampler, PixelFilter,       ignored with one warning each: clrender chooses these
ColorSpace, Option, Accelerator,        on its command line
Film "string filename"
======================================  ==========================================================
"""

from __future__ import annotations

import copy
import math
import re
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from clrender.scene import (
    PARALLELOGRAM_TOLERANCE,
    Scene,
    SceneBuilder,
    SceneError,
    SceneWarning,
)

DEFAULT_RESOLUTION = (1280, 720)
DEFAULT_FOV = 90.0
# Directives read only to be ignored: clrender's command line chooses what they choose.
IGNORED_DIRECTIVES = ("Integrator", "Sampler", "PixelFilter", "ColorSpace", "Option", "Accelerator")
# Why a rendering option is ignored (the warning's reason)
IGNORED_BECAUSE = {
    "Integrator": "clrender path-traces with next-event estimation (--max-depth, "
    "--russian-roulette)",
    "Sampler": "clrender's sampler is chosen on its command line (--sampler, --spp)",
    "PixelFilter": "clrender integrates each pixel with a box filter (the estimators' pixel "
    "integrals)",
    "Accelerator": "clrender builds its own BVH",
}
# pbrt-v4 directives outside the subset (refused as "not supported", not as unknown).
UNSUPPORTED_DIRECTIVES = (
    "ActiveTransform",
    "CoordinateSystem",
    "CoordSysTransform",
    "Import",
    "LightSource",
    "MakeNamedMedium",
    "MediumInterface",
    "ObjectBegin",
    "ObjectEnd",
    "ObjectInstance",
    "ReverseOrientation",
    "Texture",
    "TransformBegin",
    "TransformEnd",
    "TransformTimes",
    "WorldEnd",
)
PARAMETER_TYPE_ALIASES = {
    "point": "point3",
    "vector": "vector3",
    "normal": "normal3",
    "color": "rgb",
}
PARAMETER_TYPES = (
    "integer",
    "float",
    "point2",
    "vector2",
    "point3",
    "vector3",
    "normal3",
    "rgb",
    "spectrum",
    "blackbody",
    "bool",
    "string",
    "texture",
)
# Cosine below which a vertex normal N is not the flat face normal (quads carry no normals).
FLAT_NORMAL_COSINE = 1.0 - 1e-6
# Relative tolerance of the similarity check of a sphere's and the camera's transform: its
# linear part L must satisfy |L^T L - s^2 I| <= this times s^2. Exporters print matrices to 6
# significant digits (or compute them in float32), which leaves L^T L off s^2 I by up to ~2e-5
# (Bitterli's teapot camera: 1.7e-5); a real shear or non-uniform scale is far larger. 1e-4
# moves a camera ray by at most ~5e-5 radians, a tenth of a pixel of a 1280-pixel, 40-degree
# image.
SIMILARITY_TOLERANCE = 1e-4
MAX_INCLUDE_DEPTH = 32
TOKEN_PATTERN = re.compile(r'"(?:[^"\\\n]|\\.)*"|\[|\]|#[^\n]*|[^\s"\[\]#]+|"')
ESCAPES = {"n": "\n", "t": "\t", "r": "\r", "b": "\b", "f": "\f", '"': '"', "\\": "\\", "'": "'"}


# --------------------------------------------------------------------------- tokens


@dataclass(frozen=True)
class Token:
    """One token of a pbrt file: its text (a string's without quotes), line and whether quoted."""

    text: str
    line: int
    quoted: bool = False


def tokenize(path: Path, text: str) -> list[Token]:
    """The tokens of a pbrt file: "strings", [, ], and bare words; # comments dropped."""
    tokens: list[Token] = []
    line, position = 1, 0
    for match in TOKEN_PATTERN.finditer(text):
        line += text.count("\n", position, match.start())
        position = match.start()
        word = match.group()
        if word.startswith("#"):
            continue
        if word == '"':
            raise SceneError(f'{path}:{line}: a string opened with " is not closed on its line')
        if word.startswith('"'):
            body = re.sub(r"\\(.)", lambda m: ESCAPES.get(m.group(1), m.group(1)), word[1:-1])
            tokens.append(Token(body, line, True))
        else:
            tokens.append(Token(word, line))
    return tokens


@dataclass
class Parameter:
    """One `"type name" [values]` of a directive; `used` marks it as read."""

    kind: str
    name: str
    values: list
    line: int
    used: bool = False

    @property
    def label(self) -> str:
        return f'"{self.kind} {self.name}"'


@dataclass(frozen=True)
class Location:
    """Where a directive is: for messages."""

    path: Path
    line: int
    directive: str

    def fail(self, message: str, parameter: Parameter | None = None):
        if parameter is None:
            raise SceneError(f"{self.path}:{self.line}: {self.directive}: {message}")
        raise SceneError(
            f"{self.path}:{parameter.line}: {self.directive} {parameter.label}: {message}"
        )


class Cursor:
    """Reads a file's tokens in order, with the file for messages."""

    def __init__(self, path: Path, tokens: list[Token]):
        self.path = path
        self.tokens = tokens
        self.index = 0

    def done(self) -> bool:
        return self.index >= len(self.tokens)

    def peek(self) -> Token | None:
        return None if self.done() else self.tokens[self.index]

    def next(self, where: Location, what: str) -> Token:
        if self.done():
            where.fail(f"the file ends where {what} should follow")
        self.index += 1
        return self.tokens[self.index - 1]

    def string(self, where: Location, what: str) -> str:
        token = self.next(where, what)
        if not token.quoted:
            raise SceneError(
                f"{self.path}:{token.line}: {where.directive}: expected {what}, got {token.text!r}"
            )
        return token.text

    def numbers(self, where: Location, count: int, bracketed: bool | None = None) -> list[float]:
        """`count` numbers, in [ ] when bracketed (None: with or without)."""
        opened = self.peek() is not None and self.peek().text == "[" and not self.peek().quoted
        if bracketed is True and not opened:
            where.fail(f"expected [ {count} numbers ]")
        if opened:
            self.index += 1
        values = []
        for _ in range(count):
            token = self.next(where, f"{count} numbers")
            values.append(self.number(token, where))
        if opened:
            token = self.next(where, "]")
            if token.text != "]" or token.quoted:
                where.fail(f"expected exactly {count} numbers in [ ], got more")
        return values

    def number(self, token: Token, where: Location) -> float:
        try:
            value = float(token.text) if not token.quoted else None
        except ValueError:
            value = None
        if value is None or not math.isfinite(value):
            raise SceneError(
                f"{self.path}:{token.line}: {where.directive}: expected a number, "
                f"got {token.text!r}"
            )
        return value

    def parameters(self, where: Location) -> dict[str, Parameter]:
        """The `"type name" value-or-[values]` list that follows a directive."""
        found: dict[str, Parameter] = {}
        while not self.done() and self.peek().quoted:
            declaration = self.next(where, "a parameter")
            words = declaration.text.split()
            if len(words) != 2:
                raise SceneError(
                    f"{self.path}:{declaration.line}: {where.directive}: expected a parameter "
                    f'"type name", got "{declaration.text}"'
                )
            kind = PARAMETER_TYPE_ALIASES.get(words[0], words[0])
            parameter = Parameter(kind, words[1], [], declaration.line)
            if kind not in PARAMETER_TYPES:
                where.fail(f"unknown parameter type {words[0]!r}", parameter)
            if words[1] in found:
                where.fail("given twice", parameter)
            parameter.values = self.values(where, parameter)
            found[words[1]] = parameter
        return found

    def values(self, where: Location, parameter: Parameter) -> list:
        token = self.next(where, f"the value of {parameter.label}")
        if token.text == "[" and not token.quoted:
            values = []
            while True:
                token = self.next(where, f"the values of {parameter.label} and ]")
                if token.text == "]" and not token.quoted:
                    return values
                values.append(self.value(token, where, parameter))
        return [self.value(token, where, parameter)]

    def value(self, token: Token, where: Location, parameter: Parameter):
        if token.quoted:
            if parameter.kind == "bool" and token.text in ("true", "false"):
                return token.text == "true"
            return token.text
        if token.text in ("true", "false"):
            return token.text == "true"
        try:
            value = float(token.text)
        except ValueError:
            raise SceneError(
                f"{self.path}:{token.line}: {where.directive} {parameter.label}: expected a "
                f"value, got {token.text!r} (a directive? a parameter list ends at one)"
            ) from None
        if not math.isfinite(value):
            where.fail(f"expected finite numbers, got {token.text}", parameter)
        return value


# --------------------------------------------------------------------------- parameters


class Parameters:
    """A directive's parameters (its own, then Attribute defaults), each read with its type."""

    def __init__(self, where: Location, own: dict[str, Parameter], defaults=None):
        self.where = where
        self.own = own
        self.defaults = defaults or {}

    def find(self, name: str) -> Parameter | None:
        parameter = self.own.get(name) or self.defaults.get(name)
        if parameter is not None:
            parameter.used = True
        return parameter

    def fail(self, name: str, message: str):
        self.where.fail(message, self.find(name))

    def typed(self, name: str, kinds: tuple[str, ...], count: int | None) -> list | None:
        parameter = self.find(name)
        if parameter is None:
            return None
        if parameter.kind not in kinds:
            expected = " or ".join(f'"{kind} {name}"' for kind in kinds)
            self.where.fail(f"not supported: give {expected}", parameter)
        values = parameter.values
        numeric = parameter.kind not in ("string", "bool", "texture")
        if numeric and not all(isinstance(v, float) for v in values):
            self.where.fail("expected numbers", parameter)
        if parameter.kind == "bool" and not all(isinstance(v, bool) for v in values):
            self.where.fail("expected true or false", parameter)
        if parameter.kind == "string" and not all(isinstance(v, str) for v in values):
            self.where.fail("expected a string", parameter)
        if count is not None and len(values) != count:
            self.where.fail(f"expected {count} value(s), got {len(values)}", parameter)
        return values

    def number(self, name: str, default: float | None) -> float | None:
        values = self.typed(name, ("float",), 1)
        return default if values is None else values[0]

    def integer(self, name: str, default: int) -> int:
        values = self.typed(name, ("integer",), 1)
        if values is None:
            return default
        if values[0] != int(values[0]):
            self.fail(name, f"expected an integer, got {values[0]:g}")
        return int(values[0])

    def boolean(self, name: str, default: bool) -> bool:
        values = self.typed(name, ("bool",), 1)
        return default if values is None else values[0]

    def string(self, name: str, default: str | None) -> str | None:
        values = self.typed(name, ("string",), 1)
        return default if values is None else values[0]

    def rgb(self, name: str, default: list[float] | None) -> list[float] | None:
        values = self.typed(name, ("rgb",), 3)
        return default if values is None else values

    def array(self, name: str, kind: str, width: int) -> np.ndarray | None:
        """A flat list of `kind` values as an (n, width) array; None when absent."""
        values = self.typed(name, (kind,), None)
        if values is None:
            return None
        if len(values) % width:
            self.fail(name, f"expected a multiple of {width} numbers, got {len(values)}")
        array = np.array(values, np.float64).reshape(-1, width)
        if kind == "integer" and np.any(array != np.round(array)):
            self.fail(name, "expected integers")
        return array

    def refuse_unused(self, supported: str) -> None:
        """Refuse the directive's own parameters that nothing read."""
        for parameter in self.own.values():
            if not parameter.used:
                self.where.fail(f"not supported; supported: {supported or 'none'}", parameter)


# --------------------------------------------------------------------------- transforms


def translate(delta) -> np.ndarray:
    matrix = np.eye(4)
    matrix[:3, 3] = delta
    return matrix


def scale(factors) -> np.ndarray:
    return np.diag([*factors, 1.0])


def rotate(angle_degrees: float, axis) -> np.ndarray:
    """Right-handed rotation by the angle about the axis (pbrt's Rotate)."""
    a = np.asarray(axis, np.float64) / np.linalg.norm(axis)
    theta = math.radians(angle_degrees)
    cross = np.array([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]])
    matrix = np.eye(4)
    matrix[:3, :3] = (
        math.cos(theta) * np.eye(3)
        + math.sin(theta) * cross
        + (1 - math.cos(theta)) * np.outer(a, a)
    )
    return matrix


def look_at(eye, target, up) -> np.ndarray | None:
    """pbrt's LookAt: the world-to-camera matrix of a camera at eye looking at target, camera
    +x = cross(up, forward) (left-handed camera space); None if degenerate."""
    eye, target, up = (np.asarray(v, np.float64) for v in (eye, target, up))
    forward = target - eye
    if np.linalg.norm(forward) == 0.0 or np.linalg.norm(up) == 0.0:
        return None
    forward /= np.linalg.norm(forward)
    right = np.cross(up / np.linalg.norm(up), forward)
    if np.linalg.norm(right) < 1e-12:
        return None
    right /= np.linalg.norm(right)
    camera_to_world = np.eye(4)
    camera_to_world[:3, 0] = right
    camera_to_world[:3, 1] = np.cross(forward, right)
    camera_to_world[:3, 2] = forward
    camera_to_world[:3, 3] = eye
    return np.linalg.inv(camera_to_world)


def is_affine(matrix: np.ndarray) -> bool:
    return bool(np.array_equal(matrix[3], [0.0, 0.0, 0.0, 1.0]))


def similarity_scale(linear: np.ndarray, mirrored: bool = False) -> float | None:
    """s when the 3x3 matrix is s times a rotation (s > 0; with `mirrored`, possibly times a
    reflection too), else None."""
    determinant = float(np.linalg.det(linear))
    if not (determinant > 0.0 or (mirrored and determinant < 0.0)):
        return None
    s = abs(determinant) ** (1.0 / 3.0)
    if np.abs(linear.T @ linear - s * s * np.eye(3)).max() > SIMILARITY_TOLERANCE * s * s:
        return None
    return s


# --------------------------------------------------------------------------- camera


def nearest_similarity(linear: np.ndarray) -> np.ndarray:
    """The similarity (s times a rotation, or times a rotation and a mirroring) nearest to a
    3x3 matrix: its polar decomposition's orthogonal factor U V^T (the orthogonal matrix
    nearest in the Frobenius norm, of the same determinant sign for a matrix near one) times
    s = |det|^(1/3). It removes the rounding of a matrix printed to a few digits symmetrically,
    leaving no axis favoured."""
    u, _, vt = np.linalg.svd(linear)
    return abs(float(np.linalg.det(linear))) ** (1.0 / 3.0) * (u @ vt)


def camera_table(world_to_camera: np.ndarray, fov: float, resolution: tuple[int, int]) -> dict:
    """clrender's [camera] table of a pbrt perspective camera whose CTM is world_to_camera (a
    rigid transform up to uniform scale, within SIMILARITY_TOLERANCE: its linear part is
    replaced by the nearest similarity first): look_from = the camera origin, look_at one unit
    along camera +z, up = camera +y; "left" when camera +x = cross(up, forward) in world."""
    world_to_camera = world_to_camera.copy()
    world_to_camera[:3, :3] = nearest_similarity(world_to_camera[:3, :3])
    camera_to_world = np.linalg.inv(world_to_camera)
    linear = camera_to_world[:3, :3]
    origin = camera_to_world[:3, 3]
    right, up, forward = (linear[:, i] / np.linalg.norm(linear[:, i]) for i in range(3))
    handedness = "left" if np.dot(right, np.cross(up, forward)) > 0.0 else "right"
    width, height = resolution
    vertical_fov = fov
    if height > width:  # pbrt's fov spans the shorter axis, clrender's the vertical one
        vertical_fov = math.degrees(
            2.0 * math.atan(math.tan(math.radians(fov) / 2.0) * height / width)
        )
    return {
        "look_from": [float(v) for v in origin],
        "look_at": [float(v) for v in origin + forward],
        "up": [float(v) for v in up],
        "fov": vertical_fov,
        "resolution": [width, height],
        "handedness": handedness,
    }


# --------------------------------------------------------------------------- meshes


def orient_triangles(
    positions: np.ndarray, triangles: np.ndarray, normals: np.ndarray | None, mirrored: bool
) -> np.ndarray:
    """pbrt's front side of each triangle: toward its vertex normals N when given (their sum,
    the interpolated normal at its centre), else (or where that sum is zero) the winding's,
    reversed by a mirroring transform; triangles reordered so the winding says it."""
    if normals is None:
        return triangles[:, [0, 2, 1]] if mirrored else triangles
    # dot(cross(b - a, c - a), N_a + N_b + N_c), component by component (1 M triangles: 0.1 s)
    a, b, c = (positions[triangles[:, i]] for i in range(3))
    b -= a
    c -= a
    n = normals[triangles[:, 0]] + normals[triangles[:, 1]] + normals[triangles[:, 2]]
    dot = (b[:, 1] * c[:, 2] - b[:, 2] * c[:, 1]) * n[:, 0]
    dot += (b[:, 2] * c[:, 0] - b[:, 0] * c[:, 2]) * n[:, 1]
    dot += (b[:, 0] * c[:, 1] - b[:, 1] * c[:, 0]) * n[:, 2]
    # Where N sums to zero pbrt-v4 keeps the winding's normal, reversed by a mirroring
    flip = (dot < 0.0) | ((dot == 0.0) & mirrored)
    if not flip.any():
        return triangles
    oriented = triangles.copy()
    oriented[flip] = triangles[flip][:, [0, 2, 1]]
    return oriented


def pair_quads(
    positions: np.ndarray, triangles: np.ndarray, normals: np.ndarray | None
) -> list[list[int]] | None:
    """The vertex indices of the quads made by pairing triangles (2k, 2k+1), or None unless
    every pair is a planar parallelogram (within PARALLELOGRAM_TOLERANCE, as scene.py checks
    quads), consistently wound, with flat normals. tri1 = (a, b, c); tri2 shares one edge
    x -> y of tri1's winding (as y -> x) and adds d; the quad is tri1's cyclic order from a with
    d between x and y (0 2 1 / 0 3 2 -> 0 3 2 1; 0 1 2 / 0 2 3 -> 0 1 2 3)."""
    if len(triangles) == 0 or len(triangles) % 2:
        return None
    # Vertices are shared by position (a file may repeat a vertex per triangle)
    _, canonical = np.unique(positions, axis=0, return_inverse=True)
    ids = canonical.reshape(-1)[triangles]
    first, second = ids[0::2], ids[1::2]
    pairs = np.arange(len(first))
    # Each tri1 edge x -> y (edge e: from vertex e) met as y -> x in tri2 (from its vertex t)
    matches = np.zeros((len(first), 3, 3), bool)
    for e in range(3):
        for t in range(3):
            matches[:, e, t] = (second[:, t] == first[:, (e + 1) % 3]) & (
                second[:, (t + 1) % 3] == first[:, e]
            )
    if np.any(matches.sum(axis=(1, 2)) != 1):
        return None
    edge, turn = np.unravel_index(matches.reshape(len(first), 9).argmax(axis=1), (3, 3))
    d_id = second[pairs, (turn + 2) % 3]
    if np.any(first == d_id[:, None]):
        return None
    # tri1's cyclic order from a, d inserted after the edge's first vertex
    d_index = triangles[1::2][pairs, (turn + 2) % 3]
    tri1 = triangles[0::2]
    order = np.array([[0, 3, 1, 2], [0, 1, 3, 2], [0, 1, 2, 3]])[edge]
    quads = np.take_along_axis(np.c_[tri1, d_index], order, axis=1)
    corners = positions[quads]
    v0, v1, v2, v3 = (corners[:, i] for i in range(4))
    scale = np.maximum(
        np.abs(corners).max(axis=(1, 2)), np.maximum(np.linalg.norm(v1 - v0, axis=1), 1e-30)
    )
    if np.any(np.abs(v1 + v3 - v0 - v2).max(axis=1) > PARALLELOGRAM_TOLERANCE * scale):
        return None
    face = np.cross(v1 - v0, v3 - v0)
    area = np.linalg.norm(face, axis=1)
    sides = np.linalg.norm(v1 - v0, axis=1) * np.linalg.norm(v3 - v0, axis=1)
    if not np.all((area > 1e-9 * sides) & (area > 0.0)):
        return None
    if normals is not None:
        # Every corner's normal along the face (a zero normal, which adds nothing to pbrt's
        # interpolation, is no obstacle)
        corner_normals = normals[quads]
        lengths = np.linalg.norm(corner_normals, axis=2)
        cosines = np.einsum("qj,qvj->qv", face / area[:, None], corner_normals)
        if np.any((cosines < FLAT_NORMAL_COSINE * lengths) & (lengths > 0.0)):
            return None
    return quads.tolist()


def transform_points(matrix: np.ndarray, points: np.ndarray) -> np.ndarray:
    if np.array_equal(matrix, np.eye(4)):
        return points  # the file's values exactly
    return points @ matrix[:3, :3].T + matrix[:3, 3]


def transform_normals(matrix: np.ndarray, normals: np.ndarray) -> np.ndarray:
    if np.array_equal(matrix, np.eye(4)):
        return normals
    transformed = normals @ np.linalg.inv(matrix[:3, :3])
    length = np.linalg.norm(transformed, axis=1, keepdims=True)
    return np.divide(transformed, length, out=np.zeros_like(transformed), where=length > 0.0)


def load_ply(where: Location, path: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """(positions, triangles, vertex normals or None) of a PLY file, read as the scene's
    `mesh` shape reads its files (clrender.mesh_files: plyfile; polygons as triangle fans)."""
    from clrender.mesh_files import MeshFileError, read_mesh_file

    try:
        mesh = read_mesh_file(path)
    except MeshFileError as err:
        where.fail(str(err))
    return mesh.positions, mesh.indices, mesh.normals


# --------------------------------------------------------------------------- the reader


@dataclass
class GraphicsState:
    """pbrt's graphics state: what AttributeBegin saves and AttributeEnd restores."""

    transform: np.ndarray = field(default_factory=lambda: np.eye(4))
    material: str | None = None  # a document material name
    material_where: Location | None = None  # the NamedMaterial that chose it, for messages
    area_light: list[float] | None = None  # emission RGB
    attributes: dict[str, dict[str, Parameter]] = field(default_factory=dict)


class PbrtReader:
    """Reads a pbrt-v4 file (and its Includes) into clrender's scene document."""

    def __init__(self, path: Path):
        self.path = path
        self.state = GraphicsState()
        self.stack: list[tuple[GraphicsState, Location]] = []
        self.in_world = False
        self.camera: tuple[np.ndarray, float, Location] | None = None
        self.resolution = DEFAULT_RESOLUTION
        self.materials: dict[str, dict] = {}  # document materials, by name
        self.named: set[str] = set()
        self.anonymous: dict[str, dict] = {}  # Material directives: in the document once used
        self.shapes: list[dict] = []
        # Shapes whose NamedMaterial's MakeNamedMaterial had not come yet: (shape, material
        # name, emission, the NamedMaterial), resolved when the file ends, as pbrt-v4 resolves
        # names when it builds the scene
        self.unresolved: list[tuple[dict, str, list[float] | None, Location]] = []
        self.notes: list[str] = []
        self.warned: set[str] = set()
        self.includes: list[Path] = []

    def read(self) -> dict:
        """The scene document of the file."""
        self.read_file(self.path)
        if not self.in_world:
            raise SceneError(f"{self.path}: no WorldBegin: a pbrt scene's shapes follow it")
        if self.stack:
            where = self.stack[-1][1]
            where.fail("no AttributeEnd closes it")
        for shape, name, emission, where in self.unresolved:
            if name not in self.named:
                defined = ", ".join(map(repr, self.named)) or "none"
                where.fail(f"no MakeNamedMaterial {name!r} in the scene; defined: {defined}")
            self.attach_material(shape, name, emission)
        if self.camera is None:
            camera = camera_table(np.eye(4), DEFAULT_FOV, self.resolution)
        else:
            camera = camera_table(self.camera[0], self.camera[1], self.resolution)
        return {
            "description": f"Imported from the pbrt-v4 file {self.path.name}.",
            "camera": camera,
            "materials": self.materials,
            "shapes": self.shapes,
        }

    def read_file(self, path: Path, where: Location | None = None) -> None:
        try:
            text = path.read_bytes().decode("utf-8")
        except OSError as err:
            if where is not None:
                where.fail(f"cannot read {path}: {err.strerror}")
            raise SceneError(f"{path}: cannot read: {err.strerror}") from None
        except UnicodeDecodeError as err:
            raise SceneError(f"{path}: not UTF-8 text (offset {err.start})") from None
        text = text.removeprefix("\ufeff")  # a byte-order mark some editors write
        self.includes.append(path.resolve())
        cursor = Cursor(path, tokenize(path, text))
        while not cursor.done():
            token = cursor.next(Location(path, 0, ""), "a directive")
            here = Location(path, token.line, token.text)
            if token.quoted or token.text in ("[", "]"):
                raise SceneError(
                    f"{path}:{token.line}: expected a directive, got "
                    f"{'a string ' if token.quoted else ''}{token.text!r}"
                )
            handler = getattr(self, f"directive_{token.text}", None)
            if handler is None:
                if token.text in UNSUPPORTED_DIRECTIVES:
                    here.fail(f"not supported; supported: {SUPPORTED_SUMMARY}")
                here.fail(f"unknown directive; supported: {SUPPORTED_SUMMARY}")
            handler(cursor, here)
        self.includes.pop()

    def warn_once(self, key: str, message: str) -> None:
        if key not in self.warned:
            self.warned.add(key)
            self.notes.append(message)

    def require_world(self, where: Location, inside: bool) -> None:
        if inside and not self.in_world:
            where.fail("must come after WorldBegin")
        if not inside and self.in_world:
            where.fail("must come before WorldBegin")

    # -- options and ignored directives
    def ignore(self, cursor: Cursor, where: Location, named: bool) -> None:
        if named:
            cursor.string(where, "a name in quotes")
        cursor.parameters(where)
        self.warn_once(
            where.directive,
            f"{where.path}:{where.line}: {where.directive} ignored: "
            f"{IGNORED_BECAUSE.get(where.directive, 'clrender chooses it')}",
        )

    def ignore_rendering_option(self, cursor, where):
        """Integrator, Sampler, PixelFilter, Accelerator: before WorldBegin, named, ignored."""
        self.require_world(where, False)
        self.ignore(cursor, where, True)

    directive_Integrator = ignore_rendering_option
    directive_Sampler = ignore_rendering_option
    directive_PixelFilter = ignore_rendering_option
    directive_Accelerator = ignore_rendering_option

    def directive_ColorSpace(self, cursor, where):
        cursor.string(where, "a colour space name in quotes")
        self.warn_once(
            where.directive,
            f"{where.path}:{where.line}: ColorSpace ignored: clrender renders linear RGB",
        )

    def directive_Option(self, cursor, where):
        self.require_world(where, False)
        self.ignore(cursor, where, False)

    def directive_Film(self, cursor, where):
        self.require_world(where, False)
        kind = cursor.string(where, "a film type in quotes")
        params = Parameters(where, cursor.parameters(where))
        if kind != "rgb":
            where.fail(f'film {kind!r} not supported; supported: "rgb"')
        width = params.integer("xresolution", DEFAULT_RESOLUTION[0])
        height = params.integer("yresolution", DEFAULT_RESOLUTION[1])
        if width <= 0 or height <= 0:
            where.fail(f"expected a positive resolution, got {width} x {height}")
        self.resolution = (width, height)
        if params.string("filename", None) is not None:
            self.warn_once(
                "Film filename",
                f'{where.path}:{where.line}: Film "string filename" ignored: clrender writes '
                "the image named by --output",
            )
        params.refuse_unused('"integer xresolution", "integer yresolution", "string filename"')

    def directive_Camera(self, cursor, where):
        self.require_world(where, False)
        kind = cursor.string(where, "a camera type in quotes")
        params = Parameters(where, cursor.parameters(where))
        if kind != "perspective":
            where.fail(f'camera {kind!r} not supported; supported: "perspective"')
        if self.camera is not None:
            where.fail(f"a second Camera (the first is at line {self.camera[2].line})")
        fov = params.number("fov", DEFAULT_FOV)
        if not 0.0 < fov < 180.0:
            params.fail("fov", f"expected degrees in (0, 180), got {fov:g}")
        params.refuse_unused('"float fov"')
        matrix = self.state.transform
        if not is_affine(matrix) or similarity_scale(matrix[:3, :3], mirrored=True) is None:
            where.fail(
                "the camera transform must be rigid (rotation, translation, uniform scale, "
                "possibly mirrored): clrender's pinhole has no skew"
            )
        self.camera = (matrix.copy(), fov, where)

    def directive_WorldBegin(self, cursor, where):
        if self.in_world:
            where.fail("a second WorldBegin")
        self.in_world = True
        self.state.transform = np.eye(4)

    def directive_Include(self, cursor, where):
        name = cursor.string(where, "a file name in quotes")
        path = self.find_file(name, where, where.fail)
        if path.resolve() in self.includes:
            where.fail(f"{name!r} includes itself (directly or through other files)")
        if len(self.includes) >= MAX_INCLUDE_DEPTH:
            where.fail(f"Includes nest deeper than {MAX_INCLUDE_DEPTH}")
        self.read_file(path, where)

    def find_file(self, name: str, where: Location, fail) -> Path:
        """The file a name in `where`'s file refers to: pbrt-v4's ResolveFilename, a relative
        name taken from the top-level file's folder (in every included file: pbrt-v4-scenes rely
        on it), then, when no file is there, from the including file's folder (a scene written
        for clrender's earlier rule). pbrt-v4's last resort, the working directory, is not
        tried: a scene does not depend on where it is rendered from. `fail` reports a missing
        file, naming the folders tried."""
        path = Path(name)
        if path.is_absolute():
            tried = [path]
        else:
            tried = list(dict.fromkeys([self.path.parent / name, where.path.parent / name]))
        for candidate in tried:
            if candidate.is_file():
                return candidate
        fail(
            f"no file {name!r} (relative names are taken from the top-level file's folder, as "
            f"pbrt-v4 does, then from the including file's; tried {', '.join(map(str, tried))})"
        )

    # -- transforms
    def concatenate(self, matrix: np.ndarray) -> None:
        self.state.transform = self.state.transform @ matrix

    def directive_Identity(self, cursor, where):
        self.state.transform = np.eye(4)

    def directive_Translate(self, cursor, where):
        self.concatenate(translate(cursor.numbers(where, 3)))

    def directive_Scale(self, cursor, where):
        self.concatenate(scale(cursor.numbers(where, 3)))

    def directive_Rotate(self, cursor, where):
        angle, *axis = cursor.numbers(where, 4)
        if not any(axis):
            where.fail("the rotation axis is zero")
        self.concatenate(rotate(angle, axis))

    def directive_LookAt(self, cursor, where):
        values = cursor.numbers(where, 9)
        matrix = look_at(values[0:3], values[3:6], values[6:9])
        if matrix is None:
            where.fail("eye and look-at point coincide, or up is zero or along the view")
        self.concatenate(matrix)

    def directive_Transform(self, cursor, where):
        self.state.transform = np.array(cursor.numbers(where, 16, True)).reshape(4, 4).T

    def directive_ConcatTransform(self, cursor, where):
        self.concatenate(np.array(cursor.numbers(where, 16, True)).reshape(4, 4).T)

    # -- attributes
    def directive_AttributeBegin(self, cursor, where):
        self.require_world(where, True)
        self.stack.append((copy.deepcopy(self.state), where))

    def directive_AttributeEnd(self, cursor, where):
        self.require_world(where, True)
        if not self.stack:
            where.fail("no AttributeBegin to end")
        self.state = self.stack.pop()[0]

    def directive_Attribute(self, cursor, where):
        self.require_world(where, True)
        target = cursor.string(where, "a target in quotes")
        params = cursor.parameters(where)
        if target not in ("shape", "light", "material"):
            where.fail(f'target {target!r} not supported; supported: "shape", "light", "material"')
        self.state.attributes[target] = {**self.state.attributes.get(target, {}), **params}

    def parameters(self, cursor: Cursor, where: Location, target: str) -> Parameters:
        return Parameters(where, cursor.parameters(where), self.state.attributes.get(target))

    # -- materials
    def directive_MakeNamedMaterial(self, cursor, where):
        self.require_world(where, True)
        name = cursor.string(where, "a material name in quotes")
        params = self.parameters(cursor, where, "material")
        if name in self.named:
            where.fail(f"material {name!r} is defined twice")
        kind = params.string("type", None)
        if kind is None:
            where.fail('missing "string type"')
        self.materials[name] = self.material(kind, params, where)
        self.named.add(name)

    def directive_NamedMaterial(self, cursor, where):
        self.require_world(where, True)
        name = cursor.string(where, "a material name in quotes")
        self.state.material = name  # its MakeNamedMaterial may follow (see self.unresolved)
        self.state.material_where = where

    def directive_Material(self, cursor, where):
        self.require_world(where, True)
        kind = cursor.string(where, "a material type in quotes")
        params = self.parameters(cursor, where, "material")
        name = f"Material at {where.path.name}:{where.line}"
        self.anonymous[name] = self.material(kind, params, where)
        self.state.material = name
        self.state.material_where = None

    def material(self, kind: str, params: Parameters, where: Location) -> dict:
        """The document material of a pbrt material."""
        if kind == "diffuse":
            albedo = params.rgb("reflectance", [0.5, 0.5, 0.5])
            params.refuse_unused('"string type", "rgb reflectance"')
            return {"type": "diffuse", "albedo": albedo}
        if kind == "dielectric":
            eta = params.number("eta", 1.5)
            for name in ("roughness", "uroughness", "vroughness"):
                if params.number(name, 0.0) != 0.0:
                    params.fail(name, "a rough dielectric is not supported; only a smooth one")
            params.boolean("remaproughness", True)
            params.refuse_unused('"string type", "float eta" (a smooth dielectric)')
            return {"type": "dielectric", "ior": eta}
        if kind == "conductor":
            return self.conductor(params, where)
        where.fail(
            f'material {kind!r} not supported; supported: "diffuse", "conductor", "dielectric"'
        )

    def conductor(self, params: Parameters, where: Location) -> dict:
        roughness = params.number("roughness", 0.0)
        u = params.number("uroughness", roughness)
        v = params.number("vroughness", roughness)
        if u != v:
            params.fail("vroughness", f"anisotropic roughness ({u:g} vs {v:g}) not supported")
        remap = params.boolean("remaproughness", True)
        alpha = math.sqrt(u) if remap and u >= 0.0 else u  # pbrt-v4's RoughnessToAlpha
        eta = params.rgb("eta", None)
        k = params.rgb("k", None)
        for name, value in (("eta", eta), ("k", k)):
            if value is None:
                where.fail(
                    f'conductor needs "rgb {name}" (pbrt\'s default copper spectra are '
                    "not modelled)"
                )
        params.refuse_unused(
            '"string type", "rgb eta", "rgb k", "float roughness", "float uroughness", '
            '"float vroughness", "bool remaproughness"'
        )
        if not 1e-3 <= alpha <= 1.0:
            what = "a smooth conductor" if alpha == 0.0 else f"alpha {alpha:g}"
            where.fail(
                f"{what} not supported: clrender's roughconductor takes GGX alpha in "
                "[0.001, 1] (alpha = sqrt(roughness) with remaproughness, else roughness)"
            )
        return {"type": "roughconductor", "alpha": alpha, "eta": eta, "k": k}

    # -- lights
    def directive_AreaLightSource(self, cursor, where):
        self.require_world(where, True)
        kind = cursor.string(where, "an area light type in quotes")
        params = self.parameters(cursor, where, "light")
        if kind != "diffuse":
            where.fail(f'area light {kind!r} not supported; supported: "diffuse"')
        radiance = params.rgb("L", None)
        if radiance is None:
            where.fail('needs "rgb L" (pbrt\'s default illuminant spectrum is not modelled)')
        factor = params.number("scale", 1.0)
        if params.boolean("twosided", False):
            params.fail("twosided", "two-sided emitters are not supported")
        params.refuse_unused('"rgb L", "float scale", "bool twosided" false')
        emission = [value * factor for value in radiance]
        if min(emission) < 0.0:
            where.fail(f"expected emission >= 0, got {emission}")
        self.state.area_light = emission

    # -- shapes
    def directive_Shape(self, cursor, where):
        self.require_world(where, True)
        kind = cursor.string(where, "a shape type in quotes")
        params = self.parameters(cursor, where, "shape")
        matrix = self.state.transform
        if not is_affine(matrix):
            where.fail("a projective transform is not supported on shapes")
        name = f"{where.path.name}:{where.line} {kind}"
        if kind == "sphere":
            shapes = [self.sphere(params, where, matrix)]
        elif kind == "trianglemesh":
            shapes = self.triangle_mesh(params, where, matrix, name)
        elif kind == "bilinearmesh":
            shapes = self.bilinear_mesh(params, where, matrix, name)
        elif kind == "plymesh":
            shapes = [self.ply_mesh(params, where, matrix)]
        else:
            where.fail(
                f'shape {kind!r} not supported; supported: "trianglemesh", "plymesh", '
                '"sphere", "bilinearmesh" (parallelograms)'
            )
        for index, shape in enumerate(shapes):
            shape["name"] = name if len(shapes) == 1 else f"{name} {shape['type']} {index}"
            self.add_shape(shape)

    def add_shape(self, shape: dict) -> None:
        """The shape with the current material and area light."""
        material = self.state.material
        emission = self.state.area_light
        self.shapes.append(shape)
        if material is None:
            material = "pbrt default diffuse"
            self.materials.setdefault(material, {"type": "diffuse", "albedo": [0.5, 0.5, 0.5]})
        elif material not in self.named and material not in self.anonymous:
            self.unresolved.append((shape, material, emission, self.state.material_where))
            return
        self.attach_material(shape, material, emission)

    def attach_material(self, shape: dict, material: str, emission: list[float] | None) -> None:
        """The shape's material (a document name) and emission."""
        record = self.materials.get(material) or self.anonymous[material]
        if emission is not None:
            shape["emission"] = emission
            if record["type"] == "diffuse" and record["albedo"] == [0.0, 0.0, 0.0]:
                material = None  # pbrt's black "Null" material: the shape only emits
        if material is not None:
            self.materials.setdefault(material, record)
            shape["material"] = material

    def sphere(self, params: Parameters, where: Location, matrix: np.ndarray) -> dict:
        radius = params.number("radius", 1.0)
        params.refuse_unused('"float radius" (a whole sphere)')
        if not radius > 0.0:
            params.fail("radius", f"expected a radius > 0, got {radius:g}")
        s = similarity_scale(matrix[:3, :3])
        if s is None:
            where.fail(
                "a sphere's transform must be a translation, rotation and uniform positive "
                "scale (no ellipsoids, no mirroring)"
            )
        return {"type": "sphere", "center": [float(v) for v in matrix[:3, 3]], "radius": radius * s}

    def mesh_arrays(self, params: Parameters, where: Location, per_face: int):
        """(positions, faces, normals or None) of a mesh's P, indices and N, checked."""
        positions = params.array("P", "point3", 3)
        if positions is None or len(positions) == 0:
            where.fail('needs "point3 P"')
        faces = params.array("indices", "integer", per_face)
        if faces is None:
            if len(positions) != per_face:
                where.fail(f'needs "integer indices" (only {per_face} vertices may go without)')
            faces = np.arange(per_face, dtype=np.float64).reshape(1, per_face)
        faces = faces.astype(np.int64)
        if faces.size and (faces.min() < 0 or faces.max() >= len(positions)):
            params.fail("indices", f"an index outside 0..{len(positions) - 1}")
        normals = params.array("N", "normal3", 3)
        if normals is not None and len(normals) != len(positions):
            params.fail(
                "N", f"expected one normal per vertex ({len(positions)}), got {len(normals)}"
            )
        params.typed("uv", ("point2",), None)  # texture coordinates: nothing here uses them
        return positions, faces, normals

    def triangle_mesh(self, params, where, matrix, name) -> list[dict]:
        positions, triangles, normals = self.mesh_arrays(params, where, 3)
        params.typed("S", ("vector3",), None)  # tangents and face indices: unused here
        params.typed("faceIndices", ("integer",), None)
        params.refuse_unused('"point3 P", "integer indices", "normal N", "point2 uv"')
        return self.triangles(positions, triangles, normals, matrix, allow_quads=True)

    def triangles(
        self, positions, triangles, normals, matrix, allow_quads: bool, arrays: bool = False
    ) -> list[dict]:
        """The quads or the mesh of triangles under the transform, front sides as pbrt-v4
        turns them; a mesh's arrays as lists (as TOML writes them), or, with `arrays`, as the
        NumPy arrays (a PLY file's, kept fast: SceneBuilder takes both)."""
        world = transform_points(matrix, positions)
        world_normals = None if normals is None else transform_normals(matrix, normals)
        mirrored = bool(np.linalg.det(matrix[:3, :3]) < 0.0)
        triangles = orient_triangles(world, triangles, world_normals, mirrored)
        quads = pair_quads(world, triangles, world_normals) if allow_quads else None
        if quads is not None:
            return [
                {"type": "quad", "vertices": [[float(v) for v in world[i]] for i in quad]}
                for quad in quads
            ]
        listed = (lambda array: array) if arrays else (lambda array: array.tolist())
        shape = {"type": "mesh", "positions": listed(world), "indices": listed(triangles)}
        if world_normals is not None:
            shape["normals"] = listed(world_normals)
        return [shape]

    def bilinear_mesh(self, params, where, matrix, name) -> list[dict]:
        positions, patches, normals = self.mesh_arrays(params, where, 4)
        params.refuse_unused('"point3 P", "integer indices", "normal N", "point2 uv"')
        world = transform_points(matrix, positions)
        world_normals = None if normals is None else transform_normals(matrix, normals)
        mirrored = bool(np.linalg.det(matrix[:3, :3]) < 0.0)
        # pbrt's patch (p00, p10, p01, p11) is clrender's quad p00, p10, p11, p01, its front
        # side cross(p10 - p00, p01 - p00), turned toward N or by a mirroring transform
        quads = patches[:, [0, 1, 3, 2]]
        p00, p10, p01 = (world[patches[:, i]] for i in range(3))
        face = np.cross(p10 - p00, p01 - p00)
        if world_normals is not None:
            flip = np.einsum("ij,ij->i", face, world_normals[quads].sum(axis=1)) < 0.0
        else:
            flip = np.full(len(quads), mirrored)
        quads[flip] = quads[flip][:, [0, 3, 2, 1]]
        halves = np.stack([quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]], axis=1).reshape(-1, 3)
        if pair_quads(world, halves, world_normals) is None:
            for index in range(len(quads)):
                if pair_quads(world, halves[2 * index : 2 * index + 2], world_normals) is None:
                    where.fail(
                        f"patch {index} is not a flat parallelogram (p11 = p10 + p01 - p00, "
                        "normals N along its face): clrender has no curved bilinear patches"
                    )
        return [
            {"type": "quad", "vertices": [[float(v) for v in world[i]] for i in quad]}
            for quad in quads
        ]

    def ply_mesh(self, params, where, matrix) -> dict:
        filename = params.string("filename", None)
        if filename is None:
            where.fail('needs "string filename"')
        params.refuse_unused('"string filename"')
        path = self.find_file(filename, where, lambda message: params.fail("filename", message))
        # Read here, with or without a transform: the front side is pbrt-v4's (toward the
        # file's normals N where it has them), which the scene's `mesh.file` does not apply
        positions, triangles, normals = load_ply(where, path)
        if triangles.size and (triangles.min() < 0 or triangles.max() >= len(positions)):
            where.fail(f"{path.name}: a face index outside its {len(positions)} vertices")
        return self.triangles(positions, triangles, normals, matrix, False, arrays=True)[0]


SUPPORTED_SUMMARY = (
    "Camera, Film, LookAt, Transform, ConcatTransform, Translate, Scale, Rotate, Identity, "
    "WorldBegin, AttributeBegin, AttributeEnd, Attribute, MakeNamedMaterial, NamedMaterial, "
    "Material, AreaLightSource, Shape, Include (ignored: " + ", ".join(IGNORED_DIRECTIVES) + ")"
)


def read_pbrt(path: Path) -> tuple[dict, list[str]]:
    """(the scene document, the warnings) of a pbrt-v4 file."""
    reader = PbrtReader(Path(path))
    return reader.read(), reader.notes


def load_pbrt_scene(path: Path) -> Scene:
    """A pbrt-v4 file as a validated Scene; its warnings are SceneWarnings and listed first in
    `Scene.warnings`."""
    document, notes = read_pbrt(path)
    for note in notes:
        warnings.warn(note, SceneWarning, stacklevel=3)
    scene = SceneBuilder(Path(path)).build(document)
    scene.warnings[:0] = notes
    return scene
