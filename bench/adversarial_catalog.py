"""The adversarial inputs of issue 12 (bench/adversarial_inputs.py runs them): a catalog of
cases, each a command a user would type (or a Python snippet) with a stable id, a one-line
description and the outcome a correct clrender gives. Built from this file and the shipped
scenes of this repository alone, with fixed seeds: the same cases whatever checkout is tested.
876 cases (CATALOG_COUNTS: 634 scene, 135 cli, 79 api, 21 signal, 7 disk):

- scene: renders at --res 8x8 --spp 1 --max-depth 2 --sampler independent --seed 1 of a mutated
  shipped scene. Every numeric field kind of the shipped scenes (22: camera look_from ... sphere
  radius, sphere emission) x 14 values (0, -1, 1e-40, 1e-30, 1e39, 1e308, 1e-300, nan, inf,
  -0.0, a string, a bool, an empty array, a wrong-length array): value k of a kind goes to the
  k-th scene (in turn) that has the kind, to a seeded instance and component (308 cases). Per
  scene: 24 deleted and 16 duplicated lines, 8 misspelled keys or types, 4 unknown sections, 5
  whole-scene scalings (x 1e-30, 1e-40, 1e36 and the controls 1e-3, 1e3) and 3 far shapes (a
  radius-1 black sphere at y = 1e6 and 1e8, a black ground quad 2e9 wide under the scene): the
  scalings and far shapes render at 16 x 16, 16 spp, depth 3 and must give the unchanged scene's
  image (or be refused). Then 12 encodings (UTF-16, UTF-32, BOM, Latin-1, binary junk, NUL,
  empty, CR line ends ...), 6 deep nestings (3000 levels of arrays, inline tables, dotted
  headers), the camera on the furnace back wall's plane (edge2 = [0, 2, 2]: a warning is due),
  two scenes that must warn, and each shipped scene unchanged (controls). A scene case (but the
  encodings and nestings) has its shipped scene as base: an image all black where the base's is
  not is wrong, unless the mutation moves the camera's aim or an emitter's geometry.
- cli: bad values of every render option, -o names (empty, a device, a directory, over 255
  bytes, a missing directory, a FIFO ...), scene arguments (FIFO, directory, /dev/stdin,
  missing, over 255 bytes ...), unknown commands and flags, valid renders as controls. A
  mode-000 scene and a mode-555 output directory are ANY: root reads and writes them.
- api: RenderSettings, make_sampler, SampleSets (PixelSamples before it), load_scene and
  render() misused, valid calls as controls; each snippet prints one line and exits 2 on a
  ClrenderError (ValueError or TypeError where the checkout has no such class), so anything
  else shows as a traceback.
- signal: SIGINT, SIGTERM and SIGHUP sent 0.2, 0.5, 1.0, 1.3, 1.6 and 2 s after the start of
  a ~10 s render (analytic 256 x 256, 64 spp, 39 tiles: while the libraries load and the
  kernels build, moments that move with the machine's load) and 0.3 s after its first tile is
  done (mid-render whatever the load).
- disk (run only where a tmpfs mounts): a render onto a full tmpfs holding a previous good
  full.exr (0, 4, 32, 80 KB free; the issue's 8 x 8 edge image at 0 free), onto a read-only
  mount, and SIGKILL in the middle of a 2048 x 2048 EXR write followed by a second write to
  that name (which must remove the killed writer's temporary file).

Expected outcomes (Case.expect): ANY (an error or a finite image are both right), ERROR (a
value no float32 holds, a wrong type or range, an unknown key, API misuse: exit 0 is a wrong
image), ERROR_OR_WARNING (an underflowing value: not silently), WARNING, SAME_IMAGE, PARTIAL
(a signal).
"""

from __future__ import annotations

import fnmatch
import json
import os
import random
import re
import shlex
import textwrap
import tomllib
import zlib
from collections import Counter
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
SCENES_DIR = REPO / "scenes"
KINDS = ("scene", "cli", "api", "signal", "disk")
# The number of cases of each kind (the smoke test holds the catalog to these).
CATALOG_COUNTS = {"scene": 634, "cli": 135, "api": 79, "signal": 21, "disk": 7}

# Expected outcomes: what a correct clrender does with the case.
ANY = "any"  # judged by the outcome alone (an error or a finite image are both right)
ERROR = "error"  # must fail (exit 0 is a wrong image)
ERROR_OR_WARNING = "error or warning"  # must not pass silently
WARNING = "warning"  # must render and warn
SAME_IMAGE = "same image"  # must render the unchanged scene's image, or refuse
PARTIAL = "partial"  # a signal: exit 128 + signal, the finished pixels written

FLOAT32_MAX = float(np.finfo(np.float32).max)
FLOAT32_TINY = float(np.finfo(np.float32).tiny)
SCENE_ARGS = ("--res", "8x8", "--spp", "1", "--max-depth", "2", "--sampler", "independent")
SCENE_SEED = 1
SCALE_ARGS = ("--res", "16x16", "--spp", "16", "--max-depth", "3", "--sampler", "independent")
FAST = ("--res", "8x8", "--spp", "1", "--sampler", "independent", "--max-depth", "2")
FAST_EDGE = ("analytic:edge", "--res", "8", "--spp", "1", "--sampler", "independent")


@dataclass
class Case:
    """One adversarial input. argv follows `python`; files are written into the case's
    directory and `setup(directory)` runs before the command; `output` is the image the run
    writes (relative to its directory) and `prior` places a previous good one there first."""

    id: str
    kind: str
    description: str
    argv: list[str]
    expect: str = ANY
    files: dict[str, bytes] = field(default_factory=dict)
    setup: Callable[[Path], None] | None = None
    output: str | None = "out.exr"
    prior: bool = True
    needs_image: bool = True
    black_ok: bool = False
    base: str | None = None  # the shipped scene whose unchanged image the case is held to
    env: dict[str, str | None] = field(default_factory=dict)
    timeout: float | None = None
    outside: tuple[str, ...] = ()  # paths outside its directory a run may create (removed)
    runner: str = "process"  # process | signal | disk
    params: dict = field(default_factory=dict)

    def command(self) -> str:
        return shlex.join(["python", *self.argv])


def render_case(kind: str, id_: str, description: str, args: Iterable[str], **kw) -> Case:
    return Case(id_, kind, description, ["-m", "clrender", "render", *args], **kw)


# --- scene text: numeric fields and their spans -------------------------------------------------


@dataclass(frozen=True)
class Field:
    kind: str  # "camera.fov", "materials.diffuse.albedo", "shapes.quad.corner"
    owner: str  # "[camera]", "[materials.red]", "shapes[2] ('light')"
    key: str
    start: int  # the value's span in the text
    end: int
    value: object
    emitter: bool  # a field of an emitting shape


@dataclass(frozen=True)
class SceneLine:
    number: int  # 0-based
    text: str
    role: str  # blank, comment, header, key, array (inside an array), string (inside a string)


def is_numeric(value: object) -> bool:
    if isinstance(value, bool):
        return False
    if isinstance(value, int | float):
        return True
    return isinstance(value, list) and bool(value) and all(is_numeric(v) for v in value)


def value_end(text: str, start: int) -> int:
    """End of the TOML value starting at `start` (one line, or a bracketed array or triple-quoted
    string over several lines), comments excluded."""
    if text.startswith('"""', start):
        return text.index('"""', start + 3) + 3
    if text.startswith("[", start):
        depth = 0
        for i in range(start, len(text)):
            depth += {"[": 1, "]": -1}.get(text[i], 0)
            if depth == 0:
                return i + 1
        return len(text)
    line_end = text.find("\n", start)
    line_end = len(text) if line_end < 0 else line_end
    quoted = False
    for i in range(start, line_end):
        if text[i] == '"':
            quoted = not quoted
        elif text[i] == "#" and not quoted:
            return start + len(text[start:i].rstrip())
    return start + len(text[start:line_end].rstrip())


KEY_LINE = re.compile(r"^\s*([A-Za-z_][\w-]*)\s*=\s*")


def scan_scene(text: str) -> tuple[list[SceneLine], list[Field]]:
    """Every line's role and every numeric field of a shipped scene's text."""
    document = tomllib.loads(text)
    starts = [0]
    for line in text.splitlines(keepends=True):
        starts.append(starts[-1] + len(line))
    raw = text.splitlines()
    lines: list[SceneLine] = []
    fields: list[Field] = []
    section: tuple = ()
    shape = -1
    i = 0
    while i < len(raw):
        stripped = raw[i].strip()
        if not stripped:
            lines.append(SceneLine(i, raw[i], "blank"))
        elif stripped.startswith("#"):
            lines.append(SceneLine(i, raw[i], "comment"))
        elif stripped.startswith("["):
            lines.append(SceneLine(i, raw[i], "header"))
            name = stripped.strip("[]").strip()
            if stripped.startswith("[["):
                shape += 1
                section = ("shapes", shape)
            elif name.startswith("materials."):
                section = ("materials", name.split(".", 1)[1])
            else:
                section = (name,)
        else:
            match = KEY_LINE.match(raw[i])
            start = starts[i] + match.end()
            end = value_end(text, start)
            last = i
            while last + 1 < len(starts) - 1 and starts[last + 1] < end:
                last += 1
            role = "string" if text.startswith('"""', start) else "array"
            lines.append(SceneLine(i, raw[i], "key"))
            lines += [SceneLine(j, raw[j], role) for j in range(i + 1, last + 1)]
            key = match.group(1)
            found = locate(document, section, key)
            if found is not None and is_numeric(found[1].get(key)):
                kind, table, owner = found
                emitter = section[:1] == ("shapes",) and max(table.get("emission", [0])) > 0
                fields.append(Field(kind, owner, key, start, end, table[key], emitter))
            i = last
        i += 1
    return lines, fields


def locate(document: dict, section: tuple, key: str) -> tuple[str, dict, str] | None:
    """(field kind, its table, owner label) of `key` in the section, None at the top level."""
    if section == ("camera",):
        return f"camera.{key}", document["camera"], "[camera]"
    if section[:1] == ("materials",):
        table = document["materials"][section[1]]
        return f"materials.{table['type']}.{key}", table, f"[materials.{section[1]}]"
    if section[:1] == ("shapes",):
        table = document["shapes"][section[1]]
        name = f" ({table['name']!r})" if "name" in table else ""
        return f"shapes.{table['type']}.{key}", table, f"shapes[{section[1]}]{name}"
    return None


class Raw(str):
    """Text inserted into a TOML value as it is (an adversarial token)."""


def toml_value(value: object) -> str:
    if isinstance(value, Raw):
        return str(value)
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        if np.isnan(value):
            return "nan"
        if np.isinf(value):
            return "inf" if value > 0 else "-inf"
        return repr(value)
    if isinstance(value, list):
        return "[" + ", ".join(toml_value(v) for v in value) + "]"
    return json.dumps(value)


def replace_span(text: str, start: int, end: int, new: str) -> str:
    return text[:start] + new + text[end:]


# --- scene cases ---------------------------------------------------------------------------------

# (name in ids, TOML text, the number it stands for or None for a wrong type)
VALUES = [
    ("zero", "0", 0.0),
    ("minus1", "-1", -1.0),
    ("1e-40", "1e-40", 1e-40),
    ("1e-30", "1e-30", 1e-30),
    ("1e39", "1e39", 1e39),
    ("1e308", "1e308", 1e308),
    ("1e-300", "1e-300", 1e-300),
    ("nan", "nan", None),
    ("inf", "inf", None),
    ("minus0", "-0.0", -0.0),
    ("string", '"x"', None),
    ("bool", "true", None),
    ("empty-array", "[]", None),
    ("wrong-length", None, None),  # the value less its last entry ([1.0, 2.0] for a number)
]
ARRAY_TOKENS = ("empty-array", "wrong-length")
# Where each field kind's numbers must lie (outside: the scene is wrong, an error is due).
FIELD_DOMAINS: dict[str, Callable[[float], bool]] = {
    "camera.fov": lambda x: 0.0 < x < 180.0,
    "camera.resolution": lambda x: x > 0 and float(x).is_integer(),
    "albedo": lambda x: 0.0 <= x <= 1.0,
    "ior": lambda x: x > 0.0,
    "alpha": lambda x: 0.0 < x <= 1.0,
    "eta": lambda x: x > 0.0,
    "k": lambda x: x >= 0.0,
    "emission": lambda x: x >= 0.0,
    "radius": lambda x: x > 0.0,
}
CAMERA_AIM = ("look_from", "look_at", "up", "fov")
EMITTER_GEOMETRY = ("corner", "edge1", "edge2", "vertices", "center", "radius")
SCALED_KEYS = {
    "camera.look_from",
    "camera.look_at",
    "shapes.quad.corner",
    "shapes.quad.edge1",
    "shapes.quad.edge2",
    "shapes.quad.vertices",
    "shapes.sphere.center",
    "shapes.sphere.radius",
    "shapes.box.min",
    "shapes.box.max",
    "shapes.box.translate",
}
SCALES = [("1e-30", 1e-30), ("1e-40", 1e-40), ("1e36", 1e36), ("1e-3", 1e-3), ("1e3", 1e3)]
DELETED_LINES = 24
DUPLICATED_LINES = 16
MISSPELLINGS = 8


def shipped_scenes() -> dict[str, str]:
    return {path.stem: path.read_text() for path in sorted(SCENES_DIR.glob("*.toml"))}


def seeded(*parts: object) -> random.Random:
    return random.Random(zlib.crc32("/".join(map(str, parts)).encode()))


def domain_of(kind: str) -> Callable[[float], bool] | None:
    return FIELD_DOMAINS.get(kind) or FIELD_DOMAINS.get(kind.rsplit(".", 1)[-1])


def value_expectation(kind: str, number: float | None) -> str:
    """What a correct loader does with `number` in a field of this kind (None: a wrong type)."""
    if number is None or abs(number) > FLOAT32_MAX:
        return ERROR
    domain = domain_of(kind)
    if domain is not None and not domain(number):
        return ERROR
    if 0.0 < abs(number) < FLOAT32_TINY:
        return ERROR_OR_WARNING  # underflows the device's float32
    return ANY


def mutate_field(item: Field, token: str, text_value: str | None, rng: random.Random) -> tuple:
    """(new value text, description of where) of a field with one value replaced."""
    value = item.value
    if not isinstance(value, list):
        if token == "wrong-length":
            return "[1.0, 2.0]", ""
        return text_value, ""
    nested = isinstance(value[0], list)
    outer = rng.randrange(len(value)) if nested else None
    target = list(value[outer]) if nested else list(value)
    if token in ARRAY_TOKENS:
        new = Raw("[]") if token == "empty-array" else target[:-1]
        if not nested:
            return toml_value(new), ""
        copy = list(value)
        copy[outer] = new
        return toml_value(copy), f"[{outer}]"
    inner = rng.randrange(len(target))
    target[inner] = Raw(text_value)
    if not nested:
        return toml_value(target), f"[{inner}]"
    copy = list(value)
    copy[outer] = target
    return toml_value(copy), f"[{outer}][{inner}]"


def scene_case(id_: str, description: str, text: str | bytes, expect=ANY, base=None, **kw):
    data = text.encode() if isinstance(text, str) else text
    args = SCALE_ARGS if expect == SAME_IMAGE else SCENE_ARGS
    return render_case(
        "scene",
        id_,
        description,
        ["scene.toml", *args, "--seed", str(SCENE_SEED), "-o", "out.exr"],
        expect=expect,
        files={"scene.toml": data},
        base=base,
        **kw,
    )


def value_cases(scenes: dict[str, str]) -> list[Case]:
    """Every numeric field kind x every value, the k-th value in the k-th scene having it."""
    fields = {name: scan_scene(text)[1] for name, text in scenes.items()}
    kinds = sorted({f.kind for found in fields.values() for f in found})
    cases = []
    for kind in kinds:
        owners = [name for name in scenes if any(f.kind == kind for f in fields[name])]
        for k, (token, text_value, number) in enumerate(VALUES):
            scene = owners[k % len(owners)]
            rng = seeded(kind, token)
            item = rng.choice([f for f in fields[scene] if f.kind == kind])
            new, where = mutate_field(item, token, text_value, rng)
            text = replace_span(scenes[scene], item.start, item.end, new)
            aim = kind.startswith("camera.") and item.key in CAMERA_AIM
            lights = item.emitter and item.key in EMITTER_GEOMETRY
            shown = new if len(new) <= 60 else new[:57] + "..."
            cases.append(
                scene_case(
                    f"scene-value-{scene}-{kind}-{token}",
                    f"{scene}: {item.owner} {item.key}{where} -> {token}: {item.key} = {shown}",
                    text,
                    value_expectation(kind, number if token not in ARRAY_TOKENS else None),
                    base=scene,
                    black_ok=aim or lights,
                )
            )
    return cases


def line_cases(name: str, text: str) -> list[Case]:
    """Deleted and duplicated lines, misspelled keys and types, unknown sections."""
    lines, _ = scan_scene(text)
    raw = text.splitlines()
    cases = []
    # every line that holds TOML (a description's prose only where it closes the string)
    content = [
        line
        for line in lines
        if line.role not in ("blank", "comment") and (line.role != "string" or '"""' in line.text)
    ]
    for line in sorted(seeded(name, "delete").sample(content, DELETED_LINES), key=_number):
        mutated = "\n".join(raw[: line.number] + raw[line.number + 1 :]) + "\n"
        cases.append(
            scene_case(
                f"scene-delete-{name}-L{line.number + 1}",
                f"{name}: line {line.number + 1} deleted: {line.text.strip()[:50]}",
                mutated,
                base=name,
            )
        )
    for line in sorted(seeded(name, "duplicate").sample(content, DUPLICATED_LINES), key=_number):
        mutated = "\n".join(raw[: line.number + 1] + raw[line.number :]) + "\n"
        # a key or header twice is a TOML error, an array entry twice a wrong length
        expect = ANY if line.role == "string" else ERROR
        cases.append(
            scene_case(
                f"scene-duplicate-{name}-L{line.number + 1}",
                f"{name}: line {line.number + 1} duplicated: {line.text.strip()[:50]}",
                mutated,
                expect,
                base=name,
            )
        )
    cases += misspelling_cases(name, raw, lines)
    for label, extra in UNKNOWN_SECTIONS:
        cases.append(
            scene_case(
                f"scene-unknown-{name}-{label}",
                f"{name}: unknown section appended: {extra.strip().splitlines()[0]}",
                text + extra,
                ERROR,
                base=name,
            )
        )
    return cases


def _number(line: SceneLine) -> int:
    return line.number


UNKNOWN_SECTIONS = [
    ("integrator", "\n[integrator]\nmax_depth = 4\n"),
    ("lights", '\n[[lights]]\ntype = "point"\nposition = [0.0, 1.0, 0.0]\n'),
    ("camera-lens", "\n[camera.lens]\nfocal = 50.0\n"),
    (
        "triangle",
        '\n[[shapes]]\ntype = "triangle"\nvertices = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]]\n',
    ),
]


def misspell(word: str, rng: random.Random) -> str:
    """One typo: a letter dropped, doubled, swapped with the next, or the first capitalised."""
    for _ in range(20):
        how = rng.randrange(4)
        i = rng.randrange(len(word))
        if how == 0 and len(word) > 1:
            typo = word[:i] + word[i + 1 :]
        elif how == 1:
            typo = word[: i + 1] + word[i:]
        elif how == 2 and i + 1 < len(word) and word[i] != word[i + 1]:
            typo = word[:i] + word[i + 1] + word[i] + word[i + 2 :]
        else:
            typo = word[:1].upper() + word[1:]
        if typo != word:
            return typo
    return word + "x"


def misspelling_cases(name: str, raw: list[str], lines: list[SceneLine]) -> list[Case]:
    rng = seeded(name, "misspell")
    spots = [line for line in lines if line.role in ("key", "header")]
    chosen = sorted(rng.sample(spots, MISSPELLINGS - 1), key=_number)
    types = [line for line in lines if re.match(r'^type = "\w+"', line.text.strip())]
    chosen.append(rng.choice([line for line in types if line not in chosen]))
    cases = []
    for line in chosen:
        if line in chosen[-1:]:  # a misspelled type value
            word = re.search(r'"(\w+)"', line.text).group(1)
            typo = misspell(word, rng)
            new = line.text.replace(f'"{word}"', f'"{typo}"')
            label = "type"
        else:
            match = re.search(r"[A-Za-z_][\w-]*", line.text)
            word, typo = match.group(0), misspell(match.group(0), rng)
            new = line.text[: match.start()] + typo + line.text[match.end() :]
            label = "key"
        mutated = "\n".join(raw[: line.number] + [new] + raw[line.number + 1 :]) + "\n"
        cases.append(
            scene_case(
                f"scene-misspell-{name}-L{line.number + 1}",
                f"{name}: line {line.number + 1} {label} misspelled: {word!r} -> {typo!r}",
                mutated,
                ERROR,
                base=name,
            )
        )
    return cases


def scaled_text(text: str, factor: float) -> str:
    """The scene with every position and length multiplied by `factor` (camera, corners,
    edges, vertices, centres, radii, box corners and translations; not up, angles, colours)."""
    _, fields = scan_scene(text)
    for item in sorted(fields, key=lambda f: -f.start):
        if item.kind in SCALED_KEYS:
            new = _scaled(item.value, factor)
            text = replace_span(text, item.start, item.end, toml_value(new))
    return text


def _scaled(value: object, factor: float) -> object:
    if isinstance(value, list):
        return [_scaled(v, factor) for v in value]
    return float(value) * factor


def scene_extent(text: str) -> tuple[np.ndarray, np.ndarray]:
    """(lowest, highest) corner of the shapes' bounding box (box rotations ignored: about y)."""
    points = []
    for shape in tomllib.loads(text)["shapes"]:
        if "vertices" in shape:
            points += shape["vertices"]
        elif "corner" in shape:
            c, e1, e2 = (np.array(shape[k], float) for k in ("corner", "edge1", "edge2"))
            points += [c, c + e1, c + e2, c + e1 + e2]
        elif "center" in shape:
            points += [np.array(shape["center"]) + s * shape["radius"] for s in (-1, 1)]
        else:
            move = np.array(shape.get("translate", [0.0, 0.0, 0.0]))
            size = np.abs(np.array(shape["max"]) - np.array(shape["min"])).max()
            points += [move + np.array(shape["min"]) - size, move + np.array(shape["max"]) + size]
    points = np.array(points, float)
    return points.min(axis=0), points.max(axis=0)


BLACK_MATERIAL = '\n[materials.adversarial_black]\ntype = "diffuse"\nalbedo = [0.0, 0.0, 0.0]\n'


def far_geometry(text: str, what: str) -> str:
    """The scene with a black far shape added: it is never in view and blocks no light to
    anything in view, so the image must not change."""
    low, high = scene_extent(text)
    middle = [float(v) for v in (low + high) / 2]
    if what.startswith("sphere"):
        height = float(what.removeprefix("sphere-y"))
        shape = (
            f'\n[[shapes]]\nname = "far sphere"\ntype = "sphere"\n'
            f"center = [{middle[0]!r}, {height!r}, {middle[2]!r}]\nradius = 1.0\n"
            'material = "adversarial_black"\n'
        )
    else:
        below = float(low[1] - 0.01 * (high - low).max())
        shape = (
            f'\n[[shapes]]\nname = "ground"\ntype = "quad"\n'
            f"corner = [{middle[0] - 1e9!r}, {below!r}, {middle[2] - 1e9!r}]\n"
            "edge1 = [0.0, 0.0, 2e9]\nedge2 = [2e9, 0.0, 0.0]\n"
            'material = "adversarial_black"\n'
        )
    return text + BLACK_MATERIAL + shape


FAR_SHAPES = [
    ("sphere-y1e6", "a radius-1 black sphere at y = 1e6"),
    ("sphere-y1e8", "a radius-1 black sphere at y = 1e8"),
    ("ground-2e9", "a black ground quad 2e9 wide just below the scene"),
]


def scale_cases(name: str, text: str) -> list[Case]:
    cases = [
        scene_case(
            f"scene-scale-{name}-x{label}",
            f"{name}: every coordinate and length x {label} (same image, or refused)",
            scaled_text(text, factor),
            SAME_IMAGE,
            base=name,
        )
        for label, factor in SCALES
    ]
    cases += [
        scene_case(
            f"scene-far-{name}-{label}",
            f"{name}: {what} added (same image)",
            far_geometry(text, label),
            SAME_IMAGE,
            base=name,
        )
        for label, what in FAR_SHAPES
    ]
    return cases


def encoding_cases(text: str) -> list[Case]:
    junk = bytes(seeded("junk").randrange(256) for _ in range(4096))
    tail = bytes(seeded("tail").randrange(128, 256) for _ in range(64))
    latin = ("# caf\u00e9 au lait\n" + text).encode("latin-1")
    variants = [
        ("utf16", "UTF-16 with BOM", text.encode("utf-16"), ERROR),
        ("utf16be", "UTF-16 big-endian, no BOM", text.encode("utf-16-be"), ERROR),
        ("utf32", "UTF-32", text.encode("utf-32"), ERROR),
        ("utf8-bom", "UTF-8 with a BOM", b"\xef\xbb\xbf" + text.encode(), ANY),
        ("latin1", "Latin-1 comment (not UTF-8)", latin, ERROR),
        ("junk", "4096 random bytes", junk, ERROR),
        ("junk-tail", "the scene and 64 bytes >= 0x80", text.encode() + tail, ERROR),
        ("nul", "a NUL byte in a comment", ("# a\0b\n" + text).encode(), ERROR),
        ("empty", "an empty file", b"", ERROR),
        ("blank", "blank lines only", b"\n\n   \n", ERROR),
        ("crlf", "CRLF line ends (valid TOML)", text.replace("\n", "\r\n").encode(), ANY),
        ("cr", "CR-only line ends", text.replace("\n", "\r").encode(), ERROR),
    ]
    return [
        scene_case(f"scene-encoding-{label}", f"cornell-box as {what}", data, expect, base=None)
        for label, what, data, expect in variants
    ]


def nesting_cases(text: str) -> list[Case]:
    _, fields = scan_scene(text)
    look = next(f for f in fields if f.key == "look_from")
    deep = 3000
    variants = [
        ("arrays-3000", "look_from nested 3000 arrays deep", look, "[" * deep + "]" * deep),
        ("arrays-100", "look_from nested 100 arrays deep", look, "[" * 100 + "]" * 100),
        (
            "long-array",
            "look_from an array of 100000 numbers",
            look,
            "[" + ", ".join(["1.0"] * 100000) + "]",
        ),
    ]
    cases = [
        scene_case(
            f"scene-nesting-{label}",
            f"cornell-box: {what}",
            replace_span(text, item.start, item.end, value),
            ERROR,
        )
        for label, what, item, value in variants
    ]
    prefixes = [
        ("inline-tables-3000", "a top-level key of inline tables 3000 deep",
         "x = " + "{a = " * deep + "1" + "}" * deep + "\n"),
        ("top-arrays-3000", "a top-level key of arrays 3000 deep",
         "x = " + "[" * deep + "]" * deep + "\n"),
        ("dotted-3000", "a table header of 3000 dotted parts",
         "[" + ".".join(["a"] * deep) + "]\nb = 1\n"),
    ]  # fmt: skip
    for label, what, prefix in prefixes:
        cases.append(
            scene_case(f"scene-nesting-{label}", f"cornell-box: {what}", prefix + text, ERROR)
        )
    return cases


def special_scene_cases(scenes: dict[str, str]) -> list[Case]:
    furnace = scenes["furnace"]
    _, fields = scan_scene(furnace)
    back = next(f for f in fields if "back" in f.owner and f.key == "edge2")
    plane = replace_span(furnace, back.start, back.end, "[0.0, 2.0, 2.0]")
    no_light = "\n".join(line for line in furnace.splitlines() if not line.startswith("emission"))
    cornell = scenes["cornell-box"]
    _, fields = scan_scene(cornell)
    eye = next(f for f in fields if f.key == "look_from")
    inside = replace_span(cornell, eye.start, eye.end, "[190.0, 90.0, 190.0]")
    cases = [
        scene_case(
            "scene-plane-furnace-back-wall",
            "furnace: back wall edge2 = [0, 2, 2]: the camera lies on a one-sided emitter's plane",
            plane,
            WARNING,
            base="furnace",
        ),
        scene_case(
            "scene-warn-furnace-no-emitter",
            "furnace with every emission removed (renders black: a warning is due)",
            no_light,
            WARNING,
            base="furnace",
        ),
        scene_case(
            "scene-warn-cornell-box-camera-in-ball",
            "cornell-box: look_from at the glass ball's centre (inside a solid: warn)",
            inside,
            WARNING,
            base="cornell-box",
            black_ok=True,
        ),
    ]
    cases += [
        scene_case(f"scene-control-{name}", f"{name} unchanged (control)", text, base=name)
        for name, text in scenes.items()
    ]
    return cases


def scene_catalog() -> list[Case]:
    scenes = shipped_scenes()
    cases = value_cases(scenes)
    for name, text in scenes.items():
        cases += line_cases(name, text)
    for name, text in scenes.items():
        cases += scale_cases(name, text)
    cases += encoding_cases(scenes["cornell-box"])
    cases += nesting_cases(scenes["cornell-box"])
    cases += special_scene_cases(scenes)
    return cases


# --- command-line cases --------------------------------------------------------------------------


def option_cases() -> list[Case]:
    """Each render option given bad (and a few valid edge) values; the rest a fast render."""
    e, a = ERROR, ANY
    table = {
        "--res": [
            ("0", e), ("-1", e), ("x", e), ("65536x65536", e), ("1x1e9", e), ("0x8", e),
            ("8x0", e), ("", e), ("8x8x8", e), ("8.5", e), ("1e3", e), ("-8x8", e),
            ("99999999999999999999", e), ("8X8", a), (" 8", a), ("+8", a),
            ("\uff18", a), ("scene", a), ("16x9", a),
        ],
        "--spp": [
            ("0", e), ("-1", e), ("2.5", e), ("x", e), ("", e), (str(2**31), e),
            (str(10**30), e), ("1e3", e), ("0x10", e), ("+4", a),
        ],
        "--seed": [
            ("-1", e), ("x", e), (str(2**32), e), (str(2**64), e), ("1.5", e), ("", e),
            (str(2**32 - 1), a), ("0", a),
        ],
        "--sampler": [
            ("bogus", e), ("", e), ("SPPP", e), ("uniform", e), ("sobol ", e),
            ("stratified", a), ("zsobol", a),
        ],
        "--estimator": [
            ("bogus", e), ("", a), ("MC", e), ("vor", e), ("ivor", e), ("pvor", a),
            ("vor_sn ", e),
        ],
        "--max-depth": [
            ("-1", e), ("x", e), ("0", a), ("100000", a), (str(2**31), a), (str(2**63), a),
            ("2.5", e),
        ],
        "--tile-samples": [("0", e), ("-1", e), ("x", e), ("1", a), (str(10**12), a)],
        "--voronoi-backend": [("gpu", e), ("", e), ("QHULL", e), ("qhull", a)],
        "--device": [("no-such-device", e), ("99", e), ("-1", e), ("", a)],
    }  # fmt: skip
    cases = []
    for option, values in table.items():
        for value, expect in values:
            cases.append(
                render_case(
                    "cli",
                    f"cli-option-{option.removeprefix('--')}-{slug(value)}",
                    f"render cornell-box {option} {value!r}",
                    ["cornell-box", *FAST, option, value, "-o", "out.exr"],
                    expect=expect,
                )
            )
    # sampler counts the sampler cannot take
    for sampler, spp in [("stratified", "2"), ("zsobol", "3"), ("stratified", "1000001")]:
        cases.append(
            render_case(
                "cli",
                f"cli-sampler-count-{sampler}-{spp}",
                f"render --sampler {sampler} --spp {spp} (a count it cannot take)",
                ["cornell-box", *FAST, "--sampler", sampler, "--spp", spp, "-o", "out.exr"],
                expect=ERROR,
            )
        )
    return cases


def slug(value: str) -> str:
    """A value as a piece of a case id: ASCII letters, digits and . + - kept, other ASCII as _,
    the rest as uXXXX."""
    if not value:
        return "empty"
    keep = re.compile(r"[A-Za-z0-9.+-]")
    return "".join(c if keep.match(c) else "_" if ord(c) < 128 else f"u{ord(c):x}" for c in value)


def mkfifo(name: str) -> Callable[[Path], None]:
    return lambda where: os.mkfifo(where / name)


def mkdirs(*names: str, mode: int | None = None) -> Callable[[Path], None]:
    def make(where: Path) -> None:
        for name in names:
            (where / name).mkdir(parents=True)
            if mode is not None:
                (where / name).chmod(mode)

    return make


def symlink(name: str, target: str) -> Callable[[Path], None]:
    return lambda where: (where / name).symlink_to(target)


def chain(*steps: Callable[[Path], None]) -> Callable[[Path], None]:
    def run(where: Path) -> None:
        for step in steps:
            step(where)

    return run


def write_file(name: str, data: bytes, mode: int | None = None) -> Callable[[Path], None]:
    def write(where: Path) -> None:
        (where / name).write_bytes(data)
        if mode is not None:
            (where / name).chmod(mode)

    return write


def output_cases() -> list[Case]:
    """-o names that cannot be written, or are not what they look like."""
    e, a = ERROR, ANY
    long_name = "y" * 300 + ".exr"
    deep = "/".join(["d" * 200] * 25) + "/out.exr"  # over PATH_MAX, short segments
    rows = [
        ("empty", "", e, None, ()),
        ("dev-null", "/dev/null", e, None, ("/dev/null.exr", "/dev/null.png")),
        ("dev-full", "/dev/full", e, None, ("/dev/full.exr", "/dev/full.png")),
        ("no-stem", "d/.exr", e, mkdirs("d"), ()),
        ("bare-dot-exr", ".exr", e, None, ()),
        ("segment-300", long_name, e, None, ()),
        ("segment-255", "z" * 251 + ".exr", a, None, ()),
        ("segment-256", "z" * 252 + ".exr", e, None, ()),
        ("path-max", deep, e, None, ()),
        ("missing-dir", "missing/out.exr", a, None, ()),  # folders created (was an error)
        ("existing-dir", "d", e, mkdirs("d"), ()),
        ("existing-dir-exr", "d.exr", e, mkdirs("d.exr"), ()),
        ("read-only-dir", "ro/out.exr", a, mkdirs("ro", mode=0o555), ()),
        ("read-only-file", "rofile.exr", a, write_file("rofile.exr", b"x", 0o444), ()),
        ("file-as-dir", "file.txt/out.exr", e, write_file("file.txt", b"x"), ()),
        ("png-suffix", "out.png", e, None, ()),
        ("upper-suffix", "upper.EXR", a, None, ()),
        ("no-suffix", "plain", a, None, ()),
        ("double-suffix", "out.tar.exr", a, None, ()),
        ("root", "/", e, None, ()),
        ("dot", ".", e, None, ()),
        ("dotdot", "..", e, None, ()),
        ("fifo", "fifo.exr", e, mkfifo("fifo.exr"), ()),
        ("proc", "/proc/self/out.exr", e, None, ()),
        ("newline", "new\nline.exr", a, None, ()),
        ("dash", "-", a, None, ()),
        ("symlink", "link.exr", a, chain(write_file("t.exr", b"x"),
                                         symlink("link.exr", "t.exr")), ()),
        ("dangling-link", "dangling.exr", a, symlink("dangling.exr", "gone/x.exr"), ()),
    ]  # fmt: skip
    return [
        render_case(
            "cli",
            f"cli-output-{label}",
            f"render -o {output!r}"[:100],
            ["cornell-box", *FAST, "-o", output],
            expect=expect,
            setup=setup,
            output=None,
            prior=False,
            outside=outside,
        )
        for label, output, expect, setup, outside in rows
    ]


def scene_argument_cases() -> list[Case]:
    cornell = (SCENES_DIR / "cornell-box.toml").read_bytes()
    e, a = ERROR, ANY
    rows = [
        ("fifo", "pipe.toml", e, mkfifo("pipe.toml")),
        ("directory", "folder.toml", e, mkdirs("folder.toml")),
        ("directory-plain", "folder", e, mkdirs("folder")),
        ("dev-stdin", "/dev/stdin", e, None),
        ("dev-null", "/dev/null", e, None),
        ("missing-file", "missing.toml", e, None),
        ("missing-path", "no/such/scene.toml", e, None),
        ("misspelled-name", "cornel-box", e, None),
        ("empty", "", e, None),
        ("name-300", "x" * 300 + ".toml", e, None),
        ("path-300", "x" * 300 + "/scene.toml", e, None),
        ("analytic-bogus", "analytic:bogus", e, None),
        ("dangling-link", "dangling.toml", e, symlink("dangling.toml", "gone.toml")),
        ("link-loop", "loop.toml", e, chain(symlink("loop.toml", "loop2.toml"),
                                             symlink("loop2.toml", "loop.toml"))),
        ("unreadable", "locked.toml", a, write_file("locked.toml", cornell, 0o000)),
        ("txt-suffix", "scene.txt", a, write_file("scene.txt", cornell)),
        ("spaces", "my scene.toml", a, write_file("my scene.toml", cornell)),
        ("proc-file", "/proc/self/status", e, None),
        ("shipped-suffix", "cornell-box.toml", a, None),
    ]  # fmt: skip
    return [
        render_case(
            "cli",
            f"cli-scene-{label}",
            f"render SCENE = {scene!r}"[:100],
            [scene, *FAST, "-o", "out.exr"],
            expect=expect,
            setup=setup,
        )
        for label, scene, expect, setup in rows
    ]


def command_cases() -> list[Case]:
    def cli(label, description, argv, expect=ANY, **kw):
        kw.setdefault("output", None)
        kw.setdefault("prior", False)
        kw.setdefault("needs_image", False)
        return Case(f"cli-{label}", "cli", description, ["-m", "clrender", *argv], expect, **kw)

    render = ["render", "cornell-box", *FAST, "-o", "out.exr"]
    image = {"output": "out.exr", "prior": True, "needs_image": True}
    return [
        cli("help", "--help", ["--help"]),
        cli("render-help", "render --help", ["render", "--help"]),
        cli("no-command", "no command (lists devices, self-check)", []),
        cli("devices", "devices", ["devices"]),
        cli("devices-bad", "devices --device no-such-device", ["devices", "--device", "zz"], ERROR),
        cli("bogus-command", "an unknown command", ["bogus"], ERROR),
        cli("unknown-flag", "render --foo", [*render, "--foo"], ERROR),
        cli("missing-value", "render ... --spp (no value)", [*render, "--spp"], ERROR),
        cli("two-scenes", "render with two scene arguments", [*render, "furnace"], ERROR),
        cli("o-no-value", "render ... -o (no value)", [*render[:-1]], ERROR),
        cli("repeated", "options given twice (the last wins)", [*render, "--spp", "1"], **image),
        cli(
            "pyopencl-ctx",
            "PYOPENCL_CTX naming a missing platform",
            render,
            ERROR,
            env={"PYOPENCL_CTX": "no-such-platform"},
            **image,
        ),
        cli("valid", "a valid fast render (control)", render, **image),
        cli(
            "valid-analytic",
            "analytic:edge at 8 x 8 (control)",
            ["render", "analytic:edge", "--res", "8", "--spp", "1", "-o", "out.exr"],
            **image,
        ),
    ]  # fmt: skip


def cli_catalog() -> list[Case]:
    return option_cases() + output_cases() + scene_argument_cases() + command_cases()


# --- Python API cases ----------------------------------------------------------------------------

# A snippet runs as main(); ClrenderError (ValueError/TypeError where the checkout has no such
# class) with a one-line message prints one line and exits 2; anything else is a traceback.
API_WRAPPER = """\
import sys

try:
    from clrender.errors import ClrenderError as CleanError
except ImportError:
    CleanError = (ValueError, TypeError)


def main():
{body}


try:
    main()
except CleanError as err:
    message = str(err).strip()
    if not message or "\\n" in message:
        raise
    print(f"clrender: error: {{message}}", file=sys.stderr)
    sys.exit(2)
"""
SETTINGS = """\
from clrender.pipeline import RenderSettings
from clrender.sampling import make_sampler
"""
SAMPLE_SETS = """\
try:
    from clrender.samples import SampleSets
except ImportError:
    from clrender.estimators import PixelSamples as SampleSets
from clrender.estimators import estimate
"""
SAVE_IMAGE = """\
import numpy as np
np.save("image.npy", np.asarray(result.image))
"""


def api_case(label, description, body, expect=ERROR, image=False) -> Case:
    snippet = API_WRAPPER.format(body=textwrap.indent(body.strip() + "\n", "    "))
    return Case(
        f"api-{label}",
        "api",
        description,
        ["-c", snippet],
        expect,
        output="image.npy" if image else None,
        prior=False,
        needs_image=image,
        params={"snippet": body.strip()},
    )


def api_catalog() -> list[Case]:
    cases = []
    good = 'RenderSettings(8, 8, make_sampler("independent", 4), "mc"{})'
    settings = [
        ("valid", "", ANY),
        ("width-minus1", "width=-1", ERROR),
        ("width-zero", "width=0", ERROR),
        ("width-string", 'width="8"', ERROR),
        ("width-float", "width=8.5", ERROR),
        ("width-bool", "width=True", ERROR),
        ("height-none", "height=None", ERROR),
        ("width-huge", "width=2**40", ERROR),
        ("sampler-string", 'sampler="sobol"', ERROR),
        ("sampler-none", "sampler=None", ERROR),
        ("estimator-unknown", 'estimator="vornoi"', ERROR),
        ("estimator-int", "estimator=5", ERROR),
        ("estimator-none", "estimator=None", ERROR),
        ("estimator-mismatch", 'estimator="vor"', ERROR),
        ("seed-minus1", "seed=-1", ERROR),
        ("seed-2-32", "seed=2**32", ERROR),
        ("seed-string", 'seed="0"', ERROR),
        ("seed-float", "seed=1.5", ERROR),
        ("tile-samples-zero", "tile_samples=0", ERROR),
        ("tile-samples-negative", "tile_samples=-5", ERROR),
        ("backend-unknown", 'voronoi_backend="gpu"', ERROR),
    ]
    for label, change, expect in settings:
        keyword = change.split("=")[0]
        if keyword in ("width", "height", "sampler", "estimator"):
            positional = ["8", "8", 'make_sampler("independent", 4)', '"mc"']
            index = ("width", "height", "sampler", "estimator").index(keyword)
            positional[index] = change.split("=", 1)[1]
            call = f"RenderSettings({', '.join(positional)})"
        else:
            call = good.format(f", {change}" if change else "")
        cases.append(api_case(f"settings-{label}", call, SETTINGS + f"print({call})", expect))
    samplers = [
        ("valid-sppp", 'make_sampler("sppp", 16)', ANY),
        ("eps-1e6", 'make_sampler("sppp", 16, eps=1e6)', ERROR),
        ("eps-zero", 'make_sampler("sppp", 16, eps=0.0)', ERROR),
        ("eps-negative", 'make_sampler("sppp", 16, eps=-1.0)', ERROR),
        ("eps-nan", 'make_sampler("sppp", 16, eps=float("nan"))', ERROR),
        ("n-zero", 'make_sampler("independent", 0)', ERROR),
        ("n-negative", 'make_sampler("independent", -4)', ERROR),
        ("n-float", 'make_sampler("independent", 2.5)', ERROR),
        ("n-string", 'make_sampler("independent", "16")', ERROR),
        ("n-huge", 'make_sampler("independent", 2**40)', ERROR),
        ("name-unknown", 'make_sampler("bogus", 16)', ERROR),
        ("alpha-zero", 'make_sampler("sppp", 16, alpha=0.0)', ERROR),
        ("alpha-two", 'make_sampler("sppp", 16, alpha=2.0)', ERROR),
        ("alpha-nan", 'make_sampler("sppp", 16, alpha=float("nan"))', ERROR),
        ("stratified-10", 'make_sampler("stratified", 10)', ERROR),
        ("zsobol-3", 'make_sampler("zsobol", 3)', ERROR),
    ]
    for label, call, expect in samplers:
        body = SETTINGS + f"config = {call}\nprint(config, config.n_aux)"
        cases.append(api_case(f"sampler-{label}", call, body, expect))
    sets = [
        ("lists-mc", "estimate('mc') of SampleSets built from lists", ANY,
         "s = SampleSets([[0.0, 0.0]], [0, 1], 1.0)\nprint(estimate('mc', s, [1.0]).estimates)"),
        ("lists-pvor", "estimate('pvor') of SampleSets built from lists", ANY,
         "s = SampleSets([[0.1, 0.2], [-0.3, 0.1]], [0, 2], 2.0)\n"
         "print(estimate('pvor', s, [1.0, 2.0]).estimates)"),
        ("lists-counts", "SampleSets from lists: .counts", ANY,
         "print(SampleSets([[0.0, 0.0]], [0, 1], 1.0).counts)"),
        ("lists-subset", "SampleSets from lists: .subset([0])", ANY,
         "print(SampleSets([[0.0, 0.0]], [0, 1], 1.0).subset([0]))"),
        ("offsets-mismatch", "estimate('mc') with offsets [0, 5] over one sample", ERROR,
         "import numpy as np\n"
         "s = SampleSets(np.zeros((1, 2)), np.array([0, 5]), 1.0)\n"
         "print(estimate('mc', s, np.ones(1)).estimates)"),
        ("outside-pixel", "estimate('mc') with a sample outside W", ERROR,
         "import numpy as np\n"
         "s = SampleSets(np.array([[2.0, 0.0]]), np.array([0, 1]), 1.0)\n"
         "print(estimate('mc', s, np.ones(1)).estimates)"),
        ("n-zero", "estimate('mc') with intensity n = 0", ERROR,
         "import numpy as np\n"
         "s = SampleSets(np.zeros((1, 2)), np.array([0, 1]), 0.0)\n"
         "print(estimate('mc', s, np.ones(1)).estimates)"),
        ("vor-without-aux", "estimate('vor') without auxiliary nuclei", ERROR,
         "import numpy as np\n"
         "s = SampleSets(np.zeros((1, 2)), np.array([0, 1]), 1.0)\n"
         "print(estimate('vor', s, np.ones(1)).estimates)"),
    ]  # fmt: skip
    for label, description, expect, body in sets:
        cases.append(api_case(f"samplesets-{label}", description, SAMPLE_SETS + body, expect))
    loads = [
        ("none", "None", ERROR),
        ("int", "42", ERROR),
        ("empty", '""', ERROR),
        ("missing", '"no-such-scene"', ERROR),
        ("bytes", 'b"cornell-box"', ERROR),
        ("root", '__import__("pathlib").Path("/")', ERROR),
        ("list", '["cornell-box"]', ERROR),
        ("shipped", '"cornell-box"', ANY),
        ("analytic", '"analytic"', ANY),
    ]
    for label, argument, expect in loads:
        body = f"import clrender\nprint(type(clrender.load_scene({argument})).__name__)"
        cases.append(api_case(f"load-scene-{label}", f"load_scene({argument})", body, expect))
    fast = 'spp=1, sampler="independent", resolution=4'
    renders = [
        ("valid-analytic", f'render("analytic", {fast})', ANY),
        ("valid-cornell", f'render("cornell-box", {fast}, max_depth=2)', ANY),
        ("spp-zero", 'render("analytic", spp=0, sampler="independent", resolution=4)', ERROR),
        ("spp-string", 'render("analytic", spp="4", sampler="independent", resolution=4)', ERROR),
        ("spp-float", 'render("analytic", spp=2.5, sampler="independent", resolution=4)', ERROR),
        ("sampler-bogus", 'render("analytic", spp=1, sampler="bogus", resolution=4)', ERROR),
        ("estimator-mismatch", f'render("analytic", {fast}, estimator="vor")', ERROR),
        ("estimator-unknown", f'render("analytic", {fast}, estimator="vornoi")', ERROR),
        ("resolution-negative", 'render("analytic", spp=1, sampler="independent", '
                                "resolution=-1)", ERROR),
        ("resolution-1-tuple", 'render("analytic", spp=1, sampler="independent", '
                               "resolution=(8,))", ERROR),
        ("resolution-string", 'render("analytic", spp=1, sampler="independent", '
                              'resolution="8x8")', ERROR),
        ("resolution-float", 'render("analytic", spp=1, sampler="independent", '
                             "resolution=(8, 8.0))", ERROR),
        ("resolution-huge", 'render("analytic", spp=1, sampler="independent", '
                            "resolution=(65536, 65536))", ERROR),
        ("seed-minus1", f'render("analytic", {fast}, seed=-1)', ERROR),
        ("device-bogus", f'render("analytic", {fast}, device="no-such-device")', ERROR),
        ("max-depth-minus1", f'render("cornell-box", {fast}, max_depth=-1)', ERROR),
        ("max-depth-string", f'render("cornell-box", {fast}, max_depth="2")', ERROR),
        ("tile-samples-zero", f'render("analytic", {fast}, tile_samples=0)', ERROR),
        ("backend-bogus", f'render("analytic", {fast}, voronoi_backend="x")', ERROR),
        ("scene-none", f"render(None, {fast})", ERROR),
        ("scene-int", f"render(42, {fast})", ERROR),
        ("scene-missing-file", f'render("missing.toml", {fast})', ERROR),
        ("positional-spp", 'render("analytic", 16)', ERROR),
        ("no-scene", "render()", ERROR),
        ("unknown-keyword", f'render("analytic", {fast}, bogus=1)', ERROR),
    ]  # fmt: skip
    for label, call, expect in renders:
        body = f"import clrender\nresult = clrender.{call}\n" + SAVE_IMAGE
        cases.append(api_case(f"render-{label}", call, body, expect, image=expect == ANY))
    return cases


# --- signals and disks ---------------------------------------------------------------------------

# Seconds after the start (the libraries load until about 1-2 s on a loaded 2-core machine,
# then the kernels build and the first tile starts), and "tile": 0.3 s after the first tile.
SIGNAL_MOMENTS = ("0.2s", "0.5s", "1.0s", "1.3s", "1.6s", "2s", "tile")
SIGNAL_RENDER = ["analytic", "--res", "256", "--spp", "64", "--tile-samples", "262144"]


def signal_catalog() -> list[Case]:
    cases = []
    for moment in SIGNAL_MOMENTS:
        for name in ("SIGINT", "SIGTERM", "SIGHUP"):
            when = "after the first tile (+0.3 s)" if moment == "tile" else f"at {moment}"
            cases.append(
                render_case(
                    "signal",
                    f"signal-{name.lower()}-{moment}",
                    f"{name} {when} to a ~10 s render (analytic 256x256, 64 spp)",
                    [*SIGNAL_RENDER, "-o", "out.exr"],
                    expect=PARTIAL,
                    prior=False,
                    runner="signal",
                    params={"signal": name, "moment": moment},
                )
            )
    return cases


DISK_RENDER = ["analytic", "--res", "128", "--spp", "1", "--sampler", "independent"]


def disk_catalog() -> list[Case]:
    def disk(label, description, args, expect, **params):
        return render_case(
            "disk",
            f"disk-{label}",
            description,
            [*args, "-o", "full.exr"],
            expect=expect,
            prior=False,
            output="full.exr",
            runner="disk",
            params=params,
        )

    edge = ["analytic:edge", "--res", "8", "--spp", "1", "--sampler", "independent"]
    big = ["analytic:edge", "--res", "2048", "--spp", "1", "--sampler", "independent"]
    return [
        disk("full-edge-0k", "the issue's case: 8x8 edge onto a full tmpfs over a good full.exr",
             edge, ERROR, free_kb=0),
        disk("full-0k", "128x128 render onto a full tmpfs over a good full.exr", DISK_RENDER,
             ERROR, free_kb=0),
        disk("full-4k", "... with 4 KB free (the temporary file opens, its data does not fit)",
             DISK_RENDER, ERROR, free_kb=4),
        disk("full-32k", "... with 32 KB free (half of the 70 KB EXR fits)", DISK_RENDER,
             ERROR, free_kb=32),
        disk("full-80k", "... with 80 KB free (the EXR fits, its PNG preview does not)",
             DISK_RENDER, ERROR, free_kb=80),
        disk("read-only", "a render onto a read-only mount holding a good full.exr",
             DISK_RENDER, ERROR, read_only=True),
        disk("kill9-write", "SIGKILL during a 2048x2048 EXR write over a good full.exr, then a "
             "second write to that name (must remove the killed writer's temporary file)",
             big, ANY, kill_during_write=True),
    ]  # fmt: skip


def catalog(kinds: Iterable[str] = KINDS) -> list[Case]:
    builders = {
        "scene": scene_catalog,
        "cli": cli_catalog,
        "api": api_catalog,
        "signal": signal_catalog,
        "disk": disk_catalog,
    }
    cases = [case for kind in kinds for case in builders[kind]()]
    ids = Counter(case.id for case in cases)
    repeated = [name for name, count in ids.items() if count > 1]
    if repeated:
        raise ValueError(f"case ids repeated: {repeated[:5]}")
    return cases


def select(cases: list[Case], limit: int | None, patterns: list[str] | None) -> list[Case]:
    """The cases whose id matches a pattern (all without patterns), at most `limit` of each
    kind: the first of a fixed shuffle of the kind's cases (a larger limit adds cases, never
    swaps them), run in catalog order."""
    if patterns:
        cases = [c for c in cases if any(fnmatch.fnmatch(c.id, p) for p in patterns)]
    if limit is None:
        return cases
    chosen = set()
    for kind in KINDS:
        of_kind = [c.id for c in cases if c.kind == kind]
        seeded("select", kind).shuffle(of_kind)
        chosen.update(of_kind[:limit])
    return [c for c in cases if c.id in chosen]
