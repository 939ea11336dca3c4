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
