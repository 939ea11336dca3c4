"""Scene file texts shared by the scene-loading and command-line tests."""

# A camera, a white material, an emitting quad and a sphere: the smallest valid scene that
# exercises every section of the format; tests derive bad scenes from it by replacing a line.
MINIMAL_SCENE = """
[camera]
look_from = [0.0, 0.0, 5.0]
look_at = [0.0, 0.0, 0.0]
fov = 40.0
resolution = [8, 8]

[materials.white]
type = "diffuse"
albedo = [0.5, 0.5, 0.5]

[[shapes]]
name = "lamp"
type = "quad"
corner = [-1.0, -1.0, 0.0]
edge1 = [2.0, 0.0, 0.0]
edge2 = [0.0, 2.0, 0.0]
emission = [1.0, 1.0, 1.0]

[[shapes]]
name = "ball"
type = "sphere"
center = [0.0, 0.0, -2.0]
radius = 1.0
material = "white"
"""


def lit_room(resolution: int = 8) -> str:
    """A camera on the z axis, a white material and a small emitting quad above the origin: the
    start of a scene file that tests add their shapes to."""
    return f"""
[camera]
look_from = [0.0, 0.0, 5.0]
look_at = [0.0, 0.0, 0.0]
fov = 40.0
resolution = [{resolution}, {resolution}]

[materials.white]
type = "diffuse"
albedo = [0.5, 0.5, 0.5]

[[shapes]]
type = "quad"
corner = [-0.5, 3.0, -0.5]
edge1 = [1.0, 0.0, 0.0]
edge2 = [0.0, 0.0, 1.0]
emission = [1.0, 1.0, 1.0]
"""


def _toml_rows(array) -> str:
    return (
        "[" + ", ".join("[" + ", ".join(repr(float(x)) for x in row) + "]" for row in array) + "]"
    )


def mesh_text(positions, indices, normals=None, material="white") -> str:
    """A `mesh` shape of inline arrays (rows of 3)."""
    text = f'\n[[shapes]]\ntype = "mesh"\nmaterial = "{material}"\n'
    text += f"positions = {_toml_rows(positions)}\n"
    text += "indices = [" + ", ".join(f"[{i}, {j}, {k}]" for i, j, k in indices) + "]\n"
    if normals is not None:
        text += f"normals = {_toml_rows(normals)}\n"
    return text


def random_shapes_text(
    rng,
    quads: int,
    spheres: int,
    triangles: int,
    quad_edge: float,
    sphere_radii: tuple[float, float],
    triangle_size: float,
    normals: bool = False,
) -> str:
    """Random white quads (corners in [-1, 1]^3, edges normal x quad_edge), spheres (centres in
    [-1, 1]^3, radii uniform in sphere_radii) and one mesh of scattered triangles (corners
    normal x triangle_size about centres in [-1, 1]^3; random vertex normals if `normals`)."""
    text = ""
    for _ in range(quads):
        corner = rng.uniform(-1, 1, 3)
        edge1, edge2 = rng.normal(size=(2, 3)) * quad_edge
        text += (
            f'\n[[shapes]]\ntype = "quad"\ncorner = {corner.tolist()}\n'
            f'edge1 = {edge1.tolist()}\nedge2 = {edge2.tolist()}\nmaterial = "white"\n'
        )
    for _ in range(spheres):
        center = rng.uniform(-1, 1, 3)
        text += (
            f'\n[[shapes]]\ntype = "sphere"\ncenter = {center.tolist()}\n'
            f'radius = {rng.uniform(*sphere_radii)}\nmaterial = "white"\n'
        )
    centres = rng.uniform(-1, 1, (triangles, 1, 3))
    positions = (centres + rng.normal(size=(triangles, 3, 3)) * triangle_size).reshape(-1, 3)
    indices = [(3 * k, 3 * k + 1, 3 * k + 2) for k in range(triangles)]
    vertex_normals = rng.normal(size=positions.shape) if normals else None
    return text + mesh_text(positions, indices, vertex_normals)
