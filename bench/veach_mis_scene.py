"""Write scenes/veach-mis.toml from Veach's MIS scene in pbrt-v4 format.

    python bench/veach_mis_scene.py [--pbrt tests/data/veach-mis.pbrt] [--output PATH]
                                    [--resolution 320 180] [--check]

Reads exactly the directives that file uses and refuses any other: the camera (a Transform,
world to camera, and a perspective Camera's fov), the Film resolution, named diffuse and
conductor materials, triangle meshes and spheres in AttributeBegin blocks with an
AreaLightSource "diffuse" and a translation-only Transform. Each mesh's triangles 2k and 2k+1
become one quad (`quad_from_triangles`, the rule the pbrt importer shares), every vertex
number copied as the pbrt file writes it. --check compares the output with the shipped file
instead of writing it (tests/test_veach_mis.py runs it).
"""

from __future__ import annotations

import argparse
import re
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
DEFAULT_PBRT = ROOT / "tests" / "data" / "veach-mis.pbrt"
DEFAULT_OUTPUT = ROOT / "scenes" / "veach-mis.toml"
DEFAULT_RESOLUTION = (320, 180)  # pbrt's 1280 x 720 divided by 4, for speed

TOKEN = re.compile(r'"[^"]*"|\[|\]|[^\s\[\]"]+')
TOML_NUMBER = re.compile(r"^[+-]?(0|[1-9][0-9]*)(\.[0-9]+)?([eE][+-]?[0-9]+)?$")
DIRECTIVES_WITHOUT_EFFECT = ("Integrator", "Sampler", "PixelFilter", "WorldBegin")


class ConversionError(ValueError):
    """The pbrt file uses something this converter does not model."""


def tokens(text: str) -> list[str]:
    lines = [line.split("#", 1)[0] for line in text.splitlines()]
    return TOKEN.findall("\n".join(lines))


def parse(text: str) -> list[tuple[str, list[str], dict[str, list[str]]]]:
    """(directive, positional arguments, {"type name": values}) in file order."""
    items = tokens(text)
    out = []
    i = 0
    while i < len(items):
        directive = items[i]
        if not directive[0].isalpha():
            raise ConversionError(f"expected a directive, got {directive!r}")
        i += 1
        positional: list[str] = []
        params: dict[str, list[str]] = {}
        while i < len(items) and not items[i][0].isalpha():
            item = items[i]
            if item == "[":  # a bare list (Transform)
                end = items.index("]", i)
                positional += items[i + 1 : end]
                i = end + 1
            elif item.startswith('"') and " " in item and i + 1 < len(items):
                i += 1
                if items[i] == "[":
                    end = items.index("]", i)
                    params[item.strip('"')] = items[i + 1 : end]
                    i = end + 1
                else:
                    params[item.strip('"')] = [items[i]]
                    i += 1
            else:
                positional.append(item)
                i += 1
        out.append((directive, positional, params))
    return out


def quad_from_triangles(tri1: list[int], tri2: list[int]) -> list[int]:
    """The quad of two triangles sharing an edge: tri1's cyclic order starting at its first
    index with tri2's other vertex inserted inside the shared edge x -> y of tri1's winding
    (0 2 1 / 0 3 2 give 0 3 2 1; 0 1 2 / 0 2 3 give 0 1 2 3). Front side: the winding."""
    shared = set(tri1) & set(tri2)
    others = [v for v in tri2 if v not in shared]
    if len(shared) != 2 or len(others) != 1:
        raise ConversionError(f"triangles {tri1} and {tri2} do not share exactly one edge")
    for k in range(3):
        x, y = tri1[k], tri1[(k + 1) % 3]
        if {x, y} == shared:
            return tri1[: k + 1] + others + tri1[k + 1 :]
    raise AssertionError("unreachable: two shared vertices always form an edge of tri1")


def number_text(token: str) -> str:
    """A pbrt number as a TOML number: the file's own text when TOML reads it as written."""
    return token if TOML_NUMBER.match(token) else repr(float(token))


def vector_text(values) -> str:
    return "[" + ", ".join(values) + "]"


def camera_from_world_to_camera(matrix16: list[float]) -> dict:
    """look_from, look_at, up and handedness of pbrt's world-to-camera Transform (given
    column-major). pbrt's camera space: image right = +x, up = +y, forward = +z."""
    world_to_camera = np.array(matrix16, np.float64).reshape(4, 4).T
    camera_to_world = np.linalg.inv(world_to_camera)
    origin = camera_to_world[:3, 3]
    right, up, forward = (camera_to_world[:3, k] for k in range(3))
    forward = forward / np.linalg.norm(forward)
    up = up / np.linalg.norm(up)
    right = right / np.linalg.norm(right)
    if np.dot(right, np.cross(forward, up)) > 0.999:
        handedness = "right"  # clrender's default: image right = cross(forward, up)
    elif np.dot(right, np.cross(up, forward)) > 0.999:
        handedness = "left"
    else:
        raise ConversionError("the camera Transform is not a rotation and translation")
    return {
        "look_from": origin,
        "look_at": origin + forward,
        "up": up,
        "handedness": handedness,
    }


def floats(values: list[str]) -> list[float]:
    return [float(v) for v in values]


def convert(text: str, source: str, resolution=DEFAULT_RESOLUTION) -> str:
    """The TOML text of the pbrt scene."""
    camera = None
    fov = None
    film = None
    materials: dict[str, dict] = {}
    material_order: list[str] = []
    shapes: list[str] = []
    current_material = None
    stack: list[tuple] = []
    light = None
    translate = None
    mesh_count = 0
    for directive, positional, params in parse(text):
        if directive in DIRECTIVES_WITHOUT_EFFECT:
            continue
        if directive == "Transform" and not stack:
            camera = camera_from_world_to_camera(floats(positional))
        elif directive == "Transform":
            matrix = np.array(floats(positional)).reshape(4, 4).T
            if not np.array_equal(matrix[:3, :3], np.eye(3)):
                raise ConversionError("only translations place the spheres")
            translate = [number_text(positional[k]) for k in (12, 13, 14)]
        elif directive == "Film":
            film = (int(params["integer xresolution"][0]), int(params["integer yresolution"][0]))
        elif directive == "Camera":
            if positional != ['"perspective"']:
                raise ConversionError(f"Camera {positional}: only perspective")
            fov = params["float fov"][0]
        elif directive == "MakeNamedMaterial":
            name = positional[0].strip('"')
            materials[name] = params
            material_order.append(name)
        elif directive == "NamedMaterial":
            current_material = positional[0].strip('"')
        elif directive == "AttributeBegin":
            stack.append((current_material, light, translate))
        elif directive == "AttributeEnd":
            current_material, light, translate = stack.pop()
        elif directive == "AreaLightSource":
            if positional != ['"diffuse"']:
                raise ConversionError(f"AreaLightSource {positional}: only diffuse")
            light = [number_text(v) for v in params["rgb L"]]
        elif directive == "Shape" and positional == ['"trianglemesh"']:
            mesh_count += 1
            shapes += mesh_quads(params, current_material, light, mesh_count)
        elif directive == "Shape" and positional == ['"sphere"']:
            shapes.append(sphere_shape(params, current_material, light, translate, materials))
        else:
            raise ConversionError(f"directive {directive} {positional}: not modelled")
    if camera is None or fov is None or film is None:
        raise ConversionError("the file needs a camera Transform, a Camera and a Film")
    used = [name for name in material_order if not is_null(materials[name])]
    return header(source, film, resolution) + "\n".join(
        [camera_text(camera, fov, resolution)]
        + [material_text(name, materials[name]) for name in used]
        + shapes
    )


def is_null(params: dict) -> bool:
    """pbrt's "Null" material of the lights: diffuse with reflectance 0 (a pure emitter)."""
    return params["string type"] == ['"diffuse"'] and floats(params["rgb reflectance"]) == [0] * 3


def mesh_quads(params: dict, material: str | None, light, mesh: int) -> list[str]:
    if light is not None:
        raise ConversionError("emitting triangle meshes are not modelled")
    points = params["point3 P"]
    indices = [int(v) for v in params["integer indices"]]
    if len(indices) % 6:
        raise ConversionError(f"mesh {mesh}: triangles do not pair into quads")
    out = []
    faces = len(indices) // 6
    for face in range(faces):
        tri1, tri2 = indices[6 * face : 6 * face + 3], indices[6 * face + 3 : 6 * face + 6]
        quad = quad_from_triangles(tri1, tri2)
        vertices = [vector_text([number_text(v) for v in points[3 * i : 3 * i + 3]]) for i in quad]
        name = f"mesh{mesh} {material}" + (f"/face{face}" if faces > 1 else "")
        out.append(
            f'[[shapes]]\nname = "{name}"\ntype = "quad"\nmaterial = "{material}"\n'
            f"vertices = [{', '.join(vertices)}]\n"
        )
    return out


def sphere_shape(params, material, light, translate, materials) -> str:
    radius = number_text(params["float radius"][0])
    center = vector_text(translate or ["0", "0", "0"])
    lines = [f'[[shapes]]\nname = "light r={radius}"\ntype = "sphere"']
    lines.append(f"center = {center}\nradius = {radius}")
    if light is not None:
        lines.append(f"emission = {vector_text(light)}")
    if material is not None and not is_null(materials[material]):
        lines.append(f'material = "{material}"')
    return "\n".join(lines) + "\n"


def material_text(name: str, params: dict) -> str:
    kind = params["string type"][0].strip('"')
    if kind == "diffuse":
        albedo = vector_text([number_text(v) for v in params["rgb reflectance"]])
        return f'[materials.{name}]\ntype = "diffuse"\nalbedo = {albedo}\n'
    if kind == "conductor":
        u, v = params["float uroughness"][0], params["float vroughness"][0]
        if u != v or params.get("bool remaproughness") != ["false"]:
            raise ConversionError(f"material {name}: only isotropic, unremapped roughness")
        eta = vector_text([number_text(x) for x in params["rgb eta"]])
        k = vector_text([number_text(x) for x in params["rgb k"]])
        return (
            f'[materials.{name}]\ntype = "roughconductor"\nalpha = {number_text(u)}\n'
            f"eta = {eta}\nk = {k}\n"
        )
    raise ConversionError(f"material {name}: type {kind} not modelled")


def camera_text(camera: dict, fov: str, resolution) -> str:
    def vec(v):
        return vector_text([repr(float(x)) for x in v])

    return (
        f"[camera]\nlook_from = {vec(camera['look_from'])}\nlook_at = {vec(camera['look_at'])}\n"
        f"up = {vec(camera['up'])}\nfov = {number_text(fov)}\n"
        f"resolution = [{resolution[0]}, {resolution[1]}]\n"
        f'handedness = "{camera["handedness"]}"\n'
    )


def header(source: str, film, resolution) -> str:
    return f'''# Veach's multiple importance sampling scene (E. Veach's thesis, figure 9.2, as
# converted to pbrt-v4 by B. Bitterli), written by bench/veach_mis_scene.py from
# {source}.
# Conversion: every pbrt triangle mesh's triangles 2k and 2k+1 become one quad, its vertices
# tri1's cyclic order from its first index with tri2's other vertex inserted inside the edge
# the two share (indices 0 2 1 / 0 3 2 give P0 P3 P2 P1; 0 1 2 / 0 2 3 give P0 P1 P2 P3), so
# the front side is the triangles' winding; vertex numbers as the pbrt file writes them.
# pbrt "diffuse" -> diffuse (reflectance = albedo); "conductor" with uroughness = vroughness,
# remaproughness false -> roughconductor, alpha = that roughness, eta/k verbatim; the lights'
# "Null" material (diffuse, reflectance 0) -> no material (pure emitters); "rgb L" ->
# emission. The camera: pbrt's Transform (world to camera) inverted; its camera x axis is
# cross(forward, up) in world space here (the matrix has determinant -1), so the image is
# clrender's usual right-handed one. fov 20.114 degrees of the shorter (vertical) axis.
# Resolution: pbrt's is {film[0]} x {film[1]}, here {resolution[0]} x {resolution[1]} for speed
# (render with --res {film[0]} {film[1]} for pbrt's). pbrt traces at maxdepth 3 (--max-depth 3).
description = """
Veach's MIS scene: four rough metal plates (GGX alpha 0.01, 0.05, 0.1, 0.25 from the top)
reflecting three spherical lights of equal power (radius 0.05, 0.5 and 1 from left to
right); a diffuse floor and back wall. pbrt renders it at max depth 3.
"""

'''


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--pbrt", type=Path, default=DEFAULT_PBRT)
    parser.add_argument("--output", type=Path, default=DEFAULT_OUTPUT)
    parser.add_argument("--resolution", type=int, nargs=2, default=DEFAULT_RESOLUTION)
    parser.add_argument("--check", action="store_true", help="compare with --output")
    args = parser.parse_args()
    source = args.pbrt.resolve()
    if source.is_relative_to(ROOT):
        source = source.relative_to(ROOT)
    text = convert(args.pbrt.read_text(), str(source), tuple(args.resolution))
    if args.check:
        same = args.output.read_text() == text
        print(f"{args.output}: {'up to date' if same else 'differs from the conversion'}")
        return 0 if same else 1
    args.output.write_text(text)
    print(f"wrote {args.output}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
